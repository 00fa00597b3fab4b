"""Discrepancy analysis (issue 6): a measured run log + a rig description -> what the simulation gets wrong.

Modules, one job each:

``rig``          the rig description (TOML): testbed or rigid joint, free parameters, added effects
``signals``      a run log prepared for the analysis: delayed command, filtered velocity and acceleration,
                 transmitted torque, stick/slide classification, fit/held-out split
``model``        the fast inverse-dynamics surrogate: residual channels (effort, sensor, kinematic) of a
                 parameter vector
``effects``      the library of named physical effects with parameters, units, bounds and identifiability
``fit``          bounded least squares of chosen parameters on the fit part
``diagnostics``  residual autocorrelation and cross-correlation with candidate signatures
``selection``    forward selection with the significance rule (parallel candidate fits)
``simulate``     MuJoCo runs of a rig with its effects (test logs, replay)
``replay``       windowed replay of the held-out part through MuJoCo
``synth``        excitation and hidden-effect logs for tests and the benchmark
``analysis``     the whole analysis, ``analyse(log, rig) -> DiscrepancyResult``
``report``       text, JSON and figures of a result
"""
