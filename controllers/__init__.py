"""Torque and admittance controllers, their feedback sources, closed-loop runners and tracking figures."""
