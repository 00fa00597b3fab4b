"""Cogging: a position-periodic effort of the motor's magnets, ``A·sin(2π·x/P + φ)`` (x the motor-side position).

On the testbed the candidate periods are those of a motor with an integer number of poles, ``2π/(N·poles)`` of the
output angle (N the gear ratio), and the period is held at the screened one; on a rigid joint a log-spaced grid
from 20 encoder steps to a third of the position span, and the fit refines the period too. The screen solves
amplitude and phase (a linear sub-problem) for every period: on the testbed with the filtered term, on a rigid
joint (hundreds of periods) with the term of the analysis grid's filtered position, unfiltered (exact while the
term stays below the analysis band); the fit itself uses the filtered term.
"""

from __future__ import annotations

import math

import numpy as np

from sim.discrepancy.effects.base import TWO_PI, Effect, Param, Realisation, canonical_sine

MIN_PERIODS_IN_RANGE = 5  # a period must fit at least 5 times in the position range (the library's periodicity
# rule: fewer periods do not tell a periodic effort from a smooth one)
MAX_POLES = 60  # the testbed: pole counts tried, 1..60
RIGID_PERIOD_GRID = 600  # a rigid joint: log-spaced periods screened
SCREENED = 3  # a rigid joint: the best screened periods each start a fit
MIN_PERIOD_STEPS = 20  # a rigid joint: the shortest period tried, in encoder steps
TESTBED_AMPLITUDE_NM, TESTBED_POLES = (0.02, 0.05), (10, 30)  # synthetic draws (8:1 gear)
RIGID_AMPLITUDE_OF_COULOMB = (0.3, 0.6)  # synthetic draws: x the rig's Coulomb level
RIGID_PERIOD = {"hinge": (0.1, 0.3), "slide": (0.02, 0.04)}  # synthetic draws [rad | m]


def candidate_periods(model, position_span: float) -> np.ndarray:
    """Cogging periods the log can reveal [rad | m]."""
    if model.testbed:
        periods = TWO_PI / (model.const["gear_ratio"] * np.arange(1, MAX_POLES + 1))
    else:
        resolution = max(model.data.position_resolution, 1e-9)
        periods = np.geomspace(max(MIN_PERIOD_STEPS * resolution, 1e-6),
                               max(position_span / MIN_PERIODS_IN_RANGE, 1e-6), RIGID_PERIOD_GRID)
    return periods[periods * MIN_PERIODS_IN_RANGE <= position_span]


class Cogging(Effect):
    name = "cogging"
    revealing_experiment = "free"
    description = "position-periodic torque of the magnets"
    params = (Param("cogging_amplitude", "N·m", "N", "cogging amplitude A"),
              Param("cogging_period", "rad", "m", "period P in joint position", neutral=None, default=1.0),
              Param("cogging_phase", "rad", "rad", "phase φ at position 0", neutral=None, cyclic=True))
    signature = "position modulo candidate periods"
    order = 30
    refined_starts = 3

    def bounds(self, key, scale, theta):
        if key == "cogging_amplitude":
            return 0.0, scale.effort
        if key == "cogging_period":
            return 1e-9, max(scale.position_span, 1e-9)
        return -2 * math.pi, 2 * math.pi

    def canonical(self, theta, joint):
        return canonical_sine(theta, "cogging_amplitude", "cogging_phase")

    def basis(self, model, period: float) -> tuple[np.ndarray, np.ndarray]:
        """filt(sin(2π·x/P)), filt(cos(2π·x/P)) on the grid."""
        def compute():
            phase = TWO_PI * model.data.position_full / period
            return model.data.filt(np.sin(phase)), model.data.filt(np.cos(phase))
        return model.memo("cogging", (period,), compute)

    def load(self, model, theta):
        amplitude = theta["cogging_amplitude"]
        if amplitude == 0.0:
            return 0.0
        s, c = self.basis(model, theta["cogging_period"])
        phi = theta["cogging_phase"]
        return -amplitude * (math.cos(phi) * s + math.sin(phi) * c)  # the magnets push: the joint needs less

    def screen(self, model, residual: np.ndarray, mask: np.ndarray) -> list[tuple[float, dict[str, float]]]:
        """(share of the residual's variance explained, start) for every candidate period, best first: the
        linear fit of amplitude and phase on the grid's position (unfiltered term)."""
        ok = mask & np.isfinite(residual)
        if ok.sum() < 8:
            return []
        span = float(np.ptp(model.data.position[ok]))
        x, r = model.data.position[ok], residual[ok]
        total = float(r @ r)
        out = []
        for period in candidate_periods(model, span):
            if model.testbed:  # a few integer pole counts: the filtered term itself
                a = np.column_stack([b[ok] for b in self.basis(model, float(period))])
            else:
                phase = TWO_PI * x / period
                a = np.column_stack([np.sin(phase), np.cos(phase)])
            coef, *_ = np.linalg.lstsq(a, -r, rcond=None)  # residual - load = 0
            explained = 1.0 - float(np.sum((-r - a @ coef) ** 2)) / total if total > 0 else 0.0
            out.append((explained, {"cogging_amplitude": float(math.hypot(*coef)), "cogging_period": float(period),
                                    "cogging_phase": float(math.atan2(coef[1], coef[0]))}))
        return sorted(out, key=lambda e: -e[0])

    def starts(self, model, theta):
        screened = self.screen(model, model.residuals(theta)["effort"], model.data.fit)
        if model.testbed:
            return [s for _, s in screened[:1]], ("cogging_period",)
        return [s for _, s in screened[:SCREENED]], ()

    def identifiable(self, model, theta):
        span = float(np.ptp(model.data.position))
        if not len(candidate_periods(model, span)):
            return f"the position spans {span:.3g}, less than {MIN_PERIODS_IN_RANGE} of any candidate period"
        return None

    def evidence(self, model, theta, residual, mask):
        screened = self.screen(model, residual, mask)
        return math.sqrt(screened[0][0]) if screened else None

    def realise(self, values, rig):
        amplitude, period, phase = values["cogging_amplitude"], values["cogging_period"], values["cogging_phase"]
        if rig.model == "testbed":
            n = rig.params.motor.gear_ratio
            poles = TWO_PI / (n * period)
            if abs(poles - round(poles)) > 1e-6 * poles or round(poles) < 1:
                raise ValueError(f"cogging_period = {period} rad is not 2π/(N·poles) for an integer pole count "
                                 f"(N = {n:g}); MuJoCo's dcmotor cogging needs one")
            return Realisation(dcmotor_cogging=(amplitude / n, round(poles), phase))
        return Realisation(load=lambda q, qd, t: -amplitude * math.sin(TWO_PI * q / period + phase))

    def draw(self, rig, rng):
        phase = float(rng.uniform(-math.pi, math.pi))
        if rig.model == "testbed":
            poles = int(rng.integers(*TESTBED_POLES))
            return {"cogging_amplitude": float(rng.uniform(*TESTBED_AMPLITUDE_NM)),
                    "cogging_period": TWO_PI / (rig.params.motor.gear_ratio * poles), "cogging_phase": phase}
        low, high = RIGID_AMPLITUDE_OF_COULOMB
        return {"cogging_amplitude": rig.rigid["coulomb"] * float(rng.uniform(low, high)),
                "cogging_period": float(rng.uniform(*RIGID_PERIOD[rig.joint])), "cogging_phase": phase}


EFFECT = Cogging()
