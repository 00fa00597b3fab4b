"""Domain randomisation of the testbed's plant and sensor parameters within their documented ranges.

Each field of :data:`RANDOMIZED_FIELDS` is multiplied by a factor drawn uniformly in [1 - s, 1 + s]
(``s`` = ``scale``) and clipped to the field's valid range in :mod:`sim.params`. The photo-reflectors' noise
limits share one factor, as do their temperature coefficients' limits (their order is kept); the Coulomb friction
is clipped to the breakaway torque (the parameter set's cross-check).

Chosen subset, and why: the quantities that vary from one actuator or sensor to the next and that a torque
controller has to be robust to (gear friction levels, efficiency, current-to-torque droop, current-loop lag,
command delay, backlash; the sensor's channel noise, thermal coefficient and bandwidth). Stiffnesses and
inertias are left alone: they set the physics step (and a different step changes the cost of a tick), and
the flexure stiffness is what the sensor's factory calibration converts twist with. The sensor keeps the
nominal unit's factory calibration, as a real sensor does when its unit drifts from the day it was calibrated.
"""

from __future__ import annotations

import numpy as np

from sim.params import TestbedParams, field_range

MAX_SCALE = 0.5  # [-] largest relative spread accepted

RANDOMIZED_FIELDS: tuple[tuple[str, str], ...] = (
    ("friction", "breakaway_torque_nm"),
    ("friction", "coulomb_torque_nm"),
    ("friction", "viscous_nms_per_rad"),
    ("friction", "load_friction_coefficient"),
    ("motor", "torque_saturation_per_nm"),
    ("motor", "current_loop_time_constant_s"),
    ("motor", "command_delay_s"),
    ("backlash", "width_rad"),
    ("photoreflector", "noise_min_v"),  # with noise_max_v: one factor for both
    ("photoreflector", "optical_tempco_min_per_k"),  # with optical_tempco_max_per_k: one factor for both
    ("photoreflector", "bandwidth_hz"),
)
_SHARED_FACTOR = {("photoreflector", "noise_max_v"): ("photoreflector", "noise_min_v"),
                  ("photoreflector", "optical_tempco_max_per_k"): ("photoreflector", "optical_tempco_min_per_k")}


def check_scale(scale: float) -> None:
    """Raise ValueError naming ``randomization_scale`` unless it is in [0, MAX_SCALE]."""
    if not (0.0 <= scale <= MAX_SCALE):
        raise ValueError(f"randomization_scale = {scale!r}: valid range [0, {MAX_SCALE}]")


def randomize_params(params: TestbedParams, rng: np.random.Generator, scale: float) -> TestbedParams:
    """``params`` with every field of :data:`RANDOMIZED_FIELDS` scaled by U(1 - scale, 1 + scale), clipped to
    its valid range.

    Parameters
    ----------
    params : TestbedParams
        The nominal set.
    rng : numpy.random.Generator
        Draws the factors (in the order of RANDOMIZED_FIELDS).
    scale : float
        Relative spread s in [0, MAX_SCALE].
    """
    check_scale(scale)
    factors = {key: rng.uniform(1.0 - scale, 1.0 + scale) for key in RANDOMIZED_FIELDS}
    factors.update({key: factors[src] for key, src in _SHARED_FACTOR.items()})
    groups: dict[str, dict[str, float]] = {}
    for (group, name), factor in factors.items():
        low, high = field_range(params, group, name)
        value = float(np.clip(getattr(getattr(params, group), name) * factor, low, high))
        groups.setdefault(group, {})[name] = value
    friction = groups["friction"]
    friction["coulomb_torque_nm"] = min(friction["coulomb_torque_nm"], friction["breakaway_torque_nm"])
    return params.replace(**groups)
