"""Drivetrain compliance: a second mass behind a spring-damper (a belt, a long shaft, a harmonic drive).

Of the joint's inertia m, the driven part ``m1 = (1 - φ)·m`` carries the measured position x and the friction;
the compliant part ``m2 = φ·m`` follows it through a spring k and a damper c. Parameters: the compliant fraction
φ, the resonance frequency ``f_r = sqrt(k·(1/m1 + 1/m2))/2π`` of the two masses against each other, and the
damping ratio ``ζ = c/(2·sqrt(k·μ))`` of that mode, μ = m1·m2/m.

The driven mass needs ``m1·ẍ + m2·ẍ2`` where ``x2 = H(s)·x``, ``H = (c·s + k)/(m2·s² + c·s + k)``; so the effort
is ``m·ẍ + m·φ·G(s)·ẍ`` with ``G = H - 1 = -s²/(s² + 2ζ(1-φ)ω_r·s + (1-φ)ω_r²)``, ω_r = 2π·f_r, a linear filter of
the measured acceleration (discretised by the bilinear transform). A resonance above the analysis band
(``filter_cutoff_hz``) cannot be seen: below it the masses move as one, an inertia (rule 'simpler').
"""

from __future__ import annotations

import math

import numpy as np
from scipy.signal import bilinear, lfilter

from sim.discrepancy.effects.base import RIGID_RIGS, TWO_PI, Effect, Param, Realisation, needs_acceleration

FRACTION_RANGE = (0.01, 0.95)
DAMPING_RANGE = (0.005, 1.0)
MAX_OF_BAND = 0.9  # the highest resonance fitted: 90 % of the analysis band
RIGID_OF_TOP = 0.95  # a resonance fitted within 5 % of that top is a rigid inertia over the band ('simpler')
MIN_FREQUENCY_HZ = 1.0
FREQUENCY_STARTS = 8  # log-spaced resonance frequencies screened
FRACTION_STARTS = (0.2, 0.5)
DAMPING_START = 0.05
SYNTHETIC = {"compliant_fraction": (0.2, 0.5), "resonance_frequency": (8.0, 20.0), "damping_ratio": (0.02, 0.1)}


def compliance_filter(fraction: float, frequency_hz: float, damping: float, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """Discrete (b, a) of G(s) = -s²/(s² + 2ζ(1-φ)ω_r·s + (1-φ)ω_r²) at sampling step ``dt`` [s]."""
    w = TWO_PI * frequency_hz
    return bilinear([-1.0, 0.0, 0.0], [1.0, 2.0 * damping * (1.0 - fraction) * w, (1.0 - fraction) * w * w], 1.0 / dt)


def spring_and_damper(mass: float, fraction: float, frequency_hz: float, damping: float) -> tuple[float, float]:
    """(k, c) of the compliant part [N/m | N·m/rad, N·s/m | N·m·s/rad] for a joint of inertia ``mass``."""
    reduced = fraction * (1.0 - fraction) * mass
    w = TWO_PI * frequency_hz
    return reduced * w * w, 2.0 * damping * reduced * w


class DrivetrainCompliance(Effect):
    name = "drivetrain_compliance"
    revealing_experiment = "hinge"
    description = "a second mass behind a spring-damper (belt, long shaft, harmonic drive)"
    params = (Param("compliant_fraction", "1", "1", "compliant part of the inertia φ = m2/m", valid=(0.0, 1.0),
                    firm=True),
              Param("resonance_frequency", "Hz", "Hz", "frequency of the two masses' mode f_r", neutral=None,
                    default=10.0, valid=(0.0, math.inf), firm=True),
              Param("damping_ratio", "1", "1", "damping ratio of that mode ζ", neutral=None, default=DAMPING_START,
                    valid=(0.0, math.inf), firm=True))
    rigs = RIGID_RIGS
    signature = "a resonance in the acceleration"
    order = 53
    refined_starts = 3

    def bounds(self, key, scale, theta):
        if key == "compliant_fraction":
            return FRACTION_RANGE
        if key == "damping_ratio":
            return DAMPING_RANGE
        return MIN_FREQUENCY_HZ, MAX_OF_BAND * scale.band_hz

    def _filtered(self, model, fraction: float, frequency: float, damping: float) -> np.ndarray:
        def compute():
            b, a = compliance_filter(fraction, frequency, damping, model.data.dt)
            return lfilter(b, a, model.data.acceleration_full)[model.data.grid]
        return model.memo("compliance", (fraction, frequency, damping), compute)

    def load(self, model, theta):
        fraction = theta["compliant_fraction"]
        if fraction == 0.0:
            return 0.0
        g = self._filtered(model, fraction, theta["resonance_frequency"], theta["damping_ratio"])
        return theta["inertia"] * fraction * g

    def starts(self, model, theta):
        low, high = self.bounds("resonance_frequency", model.scale, theta)
        return [{"compliant_fraction": phi, "resonance_frequency": float(f), "damping_ratio": DAMPING_START}
                for f in np.geomspace(low, high, FREQUENCY_STARTS) for phi in FRACTION_STARTS], ()

    def identifiable(self, model, theta):
        return needs_acceleration(model, theta)

    def simpler(self, model, theta):
        top = self.bounds("resonance_frequency", model.scale, theta)[1]
        if theta["compliant_fraction"] > 0.0 and theta["resonance_frequency"] >= RIGID_OF_TOP * top:
            return "inertia", (f"its resonance {theta['resonance_frequency']:.3g} Hz lies at the top of the analysis "
                               f"band ({model.config.filter_cutoff_hz:g} Hz): below it the two masses move as one")
        return None

    def signature_signal(self, model, theta):
        return self._filtered(model, 0.3, 0.5 * model.config.filter_cutoff_hz, 0.1)

    def realise(self, values, rig):
        k, c = spring_and_damper(rig.rigid["inertia"], values["compliant_fraction"], values["resonance_frequency"],
                                 values["damping_ratio"])
        return Realisation(compliant_body=(values["compliant_fraction"], k, c))

    def draw(self, rig, rng):
        return {key: float(rng.uniform(*span)) for key, span in SYNTHETIC.items()}


EFFECT = DrivetrainCompliance()
