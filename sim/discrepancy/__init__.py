"""Discrepancy analysis: measured run logs + a rig description -> what the simulation gets wrong.

Modules, one job each:

``rig``          the rig description (TOML): testbed or rigid joint, free parameters, added effects
``checks``       a log against its rig before any analysis (units, wrapped encoders, fixture, timing)
``signals``      a run log prepared for the analysis: filtered derivatives on the analysis grid, the load on
                 the lever, the fit/held-out split
``effects``      the library of named effects, one module each (parameters, bounds, model term, MuJoCo
                 realisation, diagnostics, synthetic range)
``model``        the fast inverse-dynamics surrogate: residual channels (effort, sensor, kinematic) of a
                 parameter vector
``fit``          bounded least squares of chosen parameters
``selection``    forward selection against the current model, with the significance rule (parallel fits)
``structure``    what the final residual still holds: the "unexplained" verdict and its signature
``null``         the model's own log under the log's command (the estimator's bias)
``simulate``     MuJoCo runs of a rig with its effects (test logs, replay, the model's own log)
``replay``       windowed replay of the held-out part through MuJoCo
``analysis``     the whole analysis, ``analyse(log, rig) -> DiscrepancyResult``
``report``       text and figures of a result
"""
