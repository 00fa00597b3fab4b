"""The simulated testbed: parameters, the plant, runs and their logs, and the discrepancy analysis.

Importing it registers no Gymnasium environment; ``import torquebed`` does.
"""
