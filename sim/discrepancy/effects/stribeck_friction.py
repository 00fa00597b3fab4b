"""Stribeck friction: a static (breakaway) level above the sliding one, falling with velocity.

The sliding friction is ``F_c + (F_s - F_c)·exp(-(v/v_s)²)``: the breakaway level ``F_s`` at rest, the Coulomb
level ``F_c`` well above the Stribeck velocity ``v_s``. A rig without the effect has ``F_s = F_c`` (its Stribeck
velocity is then irrelevant).

On the testbed the surrogate's LuGre balance shows it; its fit starts from a grid of velocities scaled to the
log's. A rigid joint passes its low speeds at breakaways and reversals, inside the guards its effort balance leaves
out: there F_s and v_s are fitted by the output error of short windows simulated around those events
(:mod:`sim.discrepancy.windows`), every other parameter re-fitted on the balance with them, and the candidate is
scored on the held-out windows' position error beside the balance. Where the windows do not bound v_s from below
(the joint never slides slowly enough to show it), the breakaway is named and the bound they put on v_s stated.
"""

from __future__ import annotations

import math

import numpy as np

from sim.discrepancy.effects.base import Effect, OwnFit, Param, needs_sliding
from sim.discrepancy.windows import MIN_WINDOWS, fit_stribeck, window_counts

BREAKAWAY_UP = (1.308, 1.923)  # synthetic draws: x F_s (the testbed), x F_c (a rigid joint)
STRIBECK_VELOCITY_SPAN = (0.4, 2.0)  # the testbed: x v_s
RIGID_STRIBECK_VELOCITY = {"hinge": (0.05, 0.2), "slide": (0.005, 0.02)}  # a rigid joint: v_s [rad/s | m/s]
MIN_LOW_SPEED_FRACTION = 0.02  # the testbed: >= 2 % of the samples sliding between v_s/3 and 3·v_s (or in the
# low-speed range)
NO_DROP = 1e-3  # a breakaway within this fraction of the Coulomb level is no Stribeck drop (rule 'simpler')
LOW_SPEED_RANGE = (1e-3, 0.3)  # without a stated v_s: the Stribeck velocity is looked for in this x |v|_max
MAX_LEVEL_OF_EFFORT = 2.0
VELOCITY_GRID = (0.3, 1.0, 3.0)  # starts around a stated v_s
VELOCITY_STARTS = 5  # without one: log-spaced over LOW_SPEED_RANGE
LEVEL_GRID = (1.0, 1.5, 2.0)  # starts: x the current breakaway level
PROBE_LEVEL = 1.5  # identifiability: a breakaway this many times the sliding level must show in the log ...
PROBE_VELOCITY = 0.03  # ... at a Stribeck velocity up to this x the log's top speed (a drop at low speed)


def stated(theta: dict[str, float]) -> bool:
    """Whether ``theta`` carries a Stribeck drop (breakaway above Coulomb)."""
    return theta["breakaway"] > theta["coulomb"]


class StribeckFriction(Effect):
    name = "stribeck_friction"
    revealing_experiment = "free"
    description = "friction falling from the static to the Coulomb level with velocity"
    params = (
        Param("breakaway", "N·m", "N", "static (breakaway) friction level F_s", neutral=None,
              fields={"testbed": "friction.breakaway_torque_nm", "hinge": "friction.breakaway",
                      "slide": "friction.breakaway"}, valid=(0.0, 1e4)),
        Param("stribeck_velocity", "rad/s", "m/s", "Stribeck velocity v_s", neutral=None, default=1.0,
              fields={"testbed": "friction.stribeck_velocity_rad_s", "hinge": "friction.stribeck_velocity",
                      "slide": "friction.stribeck_velocity"}, valid=(0.0, 1e3), firm=True))
    signature = "low-speed sign (Stribeck)"
    order = 12
    refined_starts = VELOCITY_STARTS
    low_speed_evidence = True

    def present(self, theta):
        return stated(theta)

    def bounds(self, key, scale, theta):
        if key == "breakaway":
            return theta["coulomb"], MAX_LEVEL_OF_EFFORT * scale.effort
        low, high = LOW_SPEED_RANGE  # a drop across the whole speed range is not a Stribeck drop
        return low * scale.velocity, high * scale.velocity

    def starts(self, model, theta):
        """For each Stribeck velocity of a grid, the breakaway level of LEVEL_GRID that fits best: the cost has
        a minimum per velocity decade, and a fit refines each (``refined_starts``)."""
        if stated(model.scale.baseline):
            velocities = [theta["stribeck_velocity"] * f for f in VELOCITY_GRID]
        else:
            low, high = LOW_SPEED_RANGE
            velocities = list(model.scale.velocity * np.geomspace(3 * low, high, VELOCITY_STARTS))
        level = max(theta["breakaway"], theta["coulomb"], 1e-12)
        starts = []
        for v in velocities:
            options = [{"stribeck_velocity": float(v), "breakaway": level * g} for g in LEVEL_GRID]
            starts.append(min(options, key=lambda start: model.cost({**theta, **start})))
        return starts, ()

    def fit(self, model, theta, mask=None):
        """A rigid joint with enough low-speed windows (:meth:`windowed`): F_s and v_s by the windows of the part
        ``mask`` selects (the fit part, default, or the held-out part); otherwise None (least squares of the
        balance: the testbed's LuGre, a rigid joint's low speeds away from its transitions)."""
        if mask is not None and mask is not model.data.fit and mask is not model.data.held:
            raise ValueError("the Stribeck windows are fitted on the fit part or the held-out part")
        if not self.windowed(model, theta):
            return None
        windows = fit_stribeck(model, theta, self.bounds("stribeck_velocity", model.scale, theta),
                               self.bounds("breakaway", model.scale, theta)[1],
                               part="held" if mask is model.data.held else "fit")
        return OwnFit({"breakaway": windows.breakaway, "stribeck_velocity": windows.stribeck_velocity},
                      {"breakaway": windows.breakaway_se, "stribeck_velocity": windows.stribeck_velocity_se},
                      {k: v for k, v in windows.to_dict().items() if k != "profile"},
                      () if windows.resolved else ("stribeck_velocity",))

    def windowed(self, model, theta) -> bool:
        """Whether a rigid joint's log has at least MIN_WINDOWS low-speed windows in each of its fit and held-out
        parts (:func:`sim.discrepancy.windows.window_counts`); the testbed never."""
        return not model.testbed and min(window_counts(model, theta).values()) >= MIN_WINDOWS

    def simpler(self, model, theta):
        if theta["breakaway"] <= (1.0 + NO_DROP) * theta["coulomb"]:
            return "coulomb_friction", "its breakaway level is its Coulomb level (no drop)"
        return None

    def identifiable(self, model, theta):
        why = needs_sliding(model)
        if why:
            return why
        if not model.testbed:
            if not theta["coulomb"] > 0.0:
                return "the model has no sliding friction level yet to refer a breakaway to"
            if self.windowed(model, theta):
                return None
        v = np.abs(model.data.velocity)
        if stated(model.scale.baseline):
            vs = theta["stribeck_velocity"]
            low, high = vs / 3, 3 * vs
        else:
            low, high = model.stick_velocity, LOW_SPEED_RANGE[1] * model.scale.velocity
        counted = ~model.near_transition  # a rigid joint's samples next to a stick-slip transition do not count
        fraction = float(((v > low) & (v < high) & counted).mean())
        if fraction < MIN_LOW_SPEED_FRACTION:
            windows = "" if model.testbed else (
                "; and {fit} and {held} low-speed windows (breakaways from rest, reversals after sliding) in the fit "
                "and held-out parts, where {need} in each show it".format(**window_counts(model, theta),
                                                                        need=MIN_WINDOWS))
            return (f"only {100 * fraction:.1f} % of the samples that count slide between {low:.3g} and {high:.3g} "
                    f"(needs {100 * MIN_LOW_SPEED_FRACTION:g} %){windows}")
        if not stated(model.scale.baseline):
            return self._too_small(model, theta)
        return None

    def _too_small(self, model, theta):
        """Why a breakaway PROBE_LEVEL x the sliding level, at a Stribeck velocity up to PROBE_VELOCITY x the log's
        top speed, would not change the effort the log can show by the smallest reportable change (or None)."""
        if not theta["coulomb"] > 0.0:
            return "the model has no sliding friction level yet to refer a breakaway to"
        base = model.residuals(theta)["effort"]
        counted = (model.data.fit | model.data.held) & np.isfinite(base)
        level = theta["coulomb"]
        largest = 0.0
        low, _ = LOW_SPEED_RANGE
        for vs in model.scale.velocity * np.geomspace(3 * low, PROBE_VELOCITY, 4):
            probe = model.residuals({**theta, "stribeck_velocity": vs, "breakaway": PROBE_LEVEL * level})["effort"]
            ok = counted & np.isfinite(probe)
            largest = max(largest, float(np.sqrt(np.mean((probe[ok] - base[ok]) ** 2))) if ok.any() else 0.0)
        floor = model.config.min_effort_change * model.command_rms
        if largest < floor:
            return (f"a breakaway {PROBE_LEVEL:g} x the sliding level ({level:.4g}) with a Stribeck velocity up to "
                    f"{100 * PROBE_VELOCITY:g} % of the top speed would change the effort of the samples that count "
                    f"by {largest:.3g} RMS at most, below the smallest reportable change {floor:.3g}")
        return None

    def signature_signal(self, model, theta):
        v = model.data.velocity
        vs = theta["stribeck_velocity"] if stated(model.scale.baseline) else 0.1 * model.scale.velocity
        return np.sign(v) * np.exp(-(v / vs) ** 2)

    def draw(self, rig, rng):
        if rig.model != "testbed":
            coulomb = rig.rigid["coulomb"]
            low, high = RIGID_STRIBECK_VELOCITY[rig.joint]
            return {"breakaway": coulomb * float(rng.uniform(*BREAKAWAY_UP)),
                    "stribeck_velocity": float(math.exp(rng.uniform(math.log(low), math.log(high))))}
        fr = rig.params.friction
        return {"breakaway": fr.breakaway_torque_nm * float(rng.uniform(*BREAKAWAY_UP)),
                "stribeck_velocity": fr.stribeck_velocity_rad_s * float(rng.uniform(*STRIBECK_VELOCITY_SPAN))}


EFFECT = StribeckFriction()
