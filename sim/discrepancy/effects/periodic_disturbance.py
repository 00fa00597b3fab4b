"""Periodic disturbance: an effort at a fixed frequency, not locked to position, ``A·sin(2π·f·t + φ)`` (an
unbalance, a pump, mains hum in a current sensor), t from the log's first sample.

The fit starts from the strongest lines of the effort residual's spectrum on the fit part (for each, amplitude and
phase are a linear sub-problem) and refines frequency, amplitude and phase together.
"""

from __future__ import annotations

import math

import numpy as np

from sim.discrepancy.effects.base import TWO_PI, Effect, Param, Realisation, canonical_sine

MAX_OF_EFFORT = 1.0  # fit bound: A up to the largest effort in the log
MIN_PERIODS = 5  # the lowest frequency: five periods in the fit part, and in the samples a line is looked for in
MAX_OF_BAND = 0.9  # the highest frequency: 90 % of the analysis band
SPECTRAL_STARTS = 4  # strongest spectral lines tried
AMPLITUDE_OF_COULOMB = (0.5, 1.5)  # synthetic draws: x the rig's Coulomb level
FREQUENCY_HZ = (2.0, 10.0)  # synthetic draws


def frequency_range(model) -> tuple[float, float]:
    """Frequencies the log can place a line at [Hz]."""
    fit_time = float(model.data.fit.sum()) * model.data.dt * model.data.grid_step
    return MIN_PERIODS / max(fit_time, 1e-9), MAX_OF_BAND * model.config.filter_cutoff_hz


class PeriodicDisturbance(Effect):
    name = "periodic_disturbance"
    revealing_experiment = "free"
    description = "effort at a fixed frequency, not locked to position (unbalance, a pump)"
    params = (Param("disturbance_amplitude", "N·m", "N", "amplitude A"),
              Param("disturbance_frequency", "Hz", "Hz", "frequency f", neutral=None, default=1.0,
                    valid=(0.0, math.inf), firm=True),
              Param("disturbance_phase", "rad", "rad", "phase φ at the log's first sample", neutral=None, cyclic=True))
    signature = "a spectral line not locked to position"
    order = 52
    refined_starts = 2

    def bounds(self, key, scale, theta):
        if key == "disturbance_amplitude":
            return 0.0, MAX_OF_EFFORT * scale.effort
        if key == "disturbance_frequency":
            return 1e-3, MAX_OF_BAND * scale.band_hz
        return -2 * math.pi, 2 * math.pi

    def canonical(self, theta, joint):
        return canonical_sine(theta, "disturbance_amplitude", "disturbance_phase")

    def _basis(self, model, frequency: float) -> tuple[np.ndarray, np.ndarray]:
        t = model.data.t - model.data.t_full[0]
        gain = model.data.sine_gain(frequency)  # the filter's (zero-phase) gain on the line
        return gain * np.sin(TWO_PI * frequency * t), gain * np.cos(TWO_PI * frequency * t)

    def load(self, model, theta):
        amplitude = theta["disturbance_amplitude"]
        if amplitude == 0.0:
            return 0.0
        s, c = self._basis(model, theta["disturbance_frequency"])
        phi = theta["disturbance_phase"]
        return -amplitude * (math.cos(phi) * s + math.sin(phi) * c)  # it pushes the joint: the joint needs less

    def starts(self, model, theta):
        r = model.residuals(theta)["effort"]
        ok = model.data.fit & np.isfinite(r)
        if ok.sum() < 16:
            return [], ()
        starts = []
        for frequency in spectral_lines(model, r, ok, SPECTRAL_STARTS):
            s, c = self._basis(model, frequency)
            a = np.column_stack([s[ok], c[ok]])
            coef, *_ = np.linalg.lstsq(a, -r[ok], rcond=None)
            starts.append({"disturbance_amplitude": float(math.hypot(*coef)), "disturbance_frequency": frequency,
                           "disturbance_phase": float(math.atan2(coef[1], coef[0]))})
        return starts, ()

    def identifiable(self, model, theta):
        low, high = frequency_range(model)
        if low >= high:
            return f"the fit part is too short to place a line below {high:.3g} Hz ({MIN_PERIODS} periods)"
        return None

    def evidence(self, model, theta, residual, mask):
        ok = mask & np.isfinite(residual)
        if ok.sum() < 16:
            return None
        lines = spectral_lines(model, residual, ok, 1)
        if not lines:
            return None
        s, c = self._basis(model, lines[0])
        a = np.column_stack([s[ok], c[ok]])
        coef, *_ = np.linalg.lstsq(a, residual[ok], rcond=None)
        total = float(residual[ok] @ residual[ok])
        left = float(np.sum((residual[ok] - a @ coef) ** 2))
        return math.sqrt(max(0.0, 1.0 - left / total)) if total > 0 else 0.0

    def realise(self, values, rig):
        amplitude, frequency, phase = (values["disturbance_amplitude"], values["disturbance_frequency"],
                                       values["disturbance_phase"])
        return Realisation(load=lambda q, qd, t: -amplitude * math.sin(TWO_PI * frequency * t + phase))

    def draw(self, rig, rng):
        level = rig.params.friction.coulomb_torque_nm if rig.model == "testbed" else rig.rigid["coulomb"]
        return {"disturbance_amplitude": level * float(rng.uniform(*AMPLITUDE_OF_COULOMB)),
                "disturbance_frequency": float(rng.uniform(*FREQUENCY_HZ)),
                "disturbance_phase": float(rng.uniform(-math.pi, math.pi))}


def spectral_lines(model, residual: np.ndarray, mask: np.ndarray, count: int) -> list[float]:
    """Frequencies of the ``count`` strongest local maxima of the residual's periodogram on ``mask``, within
    :func:`frequency_range` and with at least MIN_PERIODS periods in the samples of ``mask`` [Hz]. Samples outside
    ``mask`` (the guards around stick-slip transitions, the other part) count as zero on the grid's own time axis,
    so a line keeps its phase across the gaps."""
    index = np.flatnonzero(mask & np.isfinite(residual))
    if len(index) < 16:
        return []
    span = slice(index[0], index[-1] + 1)
    inside = mask[span] & np.isfinite(residual[span])
    x = np.where(inside, residual[span] - residual[index].mean(), 0.0)
    step = model.data.dt * model.data.grid_step
    pad = 8 * len(x)  # zero padding: a frequency grid 8 x finer than 1/T
    power = np.abs(np.fft.rfft(x * np.hanning(len(x)), pad)) ** 2
    freqs = np.fft.rfftfreq(pad, step)
    low, high = frequency_range(model)
    low = max(low, MIN_PERIODS / (int(inside.sum()) * step))
    inside_band = (freqs >= low) & (freqs <= high)
    peaks = np.flatnonzero(inside_band[1:-1] & (power[1:-1] >= power[:-2]) & (power[1:-1] >= power[2:])) + 1
    peaks = peaks[np.argsort(power[peaks])[::-1]][:count]
    return [float(freqs[i]) for i in peaks]


EFFECT = PeriodicDisturbance()
