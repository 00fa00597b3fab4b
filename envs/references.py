"""Torque reference profiles of the tracking environment: the paper's step, sine and square tasks and random
ones, one value per 1 ms control tick.

The paper's shapes are its protocols, shared with the experiments that reproduce it (:mod:`sim.protocols`):
the step sizes and their zero lead-in, the sine and square waveforms.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from sim.protocols import PRE_STEP_S, STEPS_NM, WAVEFORMS, Waveform

TASKS = ("step", "sine", "square", "random")
TASK_CHOICES = TASKS + ("any",)  # 'any': one of TASKS drawn per episode
PAPER_SINES = tuple(w for w in WAVEFORMS if w.shape == "sine")  # 0.05 and 10 N·m at 0.2 Hz
PAPER_SQUARES = tuple(w for w in WAVEFORMS if w.shape == "square")  # 0.1 N·m at 1 Hz
# [N·m] log-uniform: the paper's smallest to largest reference (0.05 and 10 N·m)
RANDOM_AMPLITUDE_RANGE_NM = (min(STEPS_NM), max(w.amplitude_nm for w in WAVEFORMS))
MAX_LEAD_IN_FRACTION = 0.25  # [1] a step's zero lead-in is at most this share of the episode
RANDOM_HOLD_RANGE_S = (0.05, 0.5)  # [s] hold time of each random level
RANDOM_SMOOTHING_S = 0.02  # [s] first-order filter on the random levels (a commanded, not a jumping, torque)
MIN_REWARD_SCALE_NM = 0.01  # [N·m] floor of the reward's normalisation (a zero reference)


@dataclass(frozen=True)
class Reference:
    """One episode's torque reference.

    Attributes
    ----------
    task : str
        One of :data:`TASKS`.
    values_nm : (N,) ndarray
        Reference of control tick k [N·m], applied from the start of tick k.
    amplitude_nm : float
        The task's amplitude (step size) [N·m].
    frequency_hz : float
        Waveform frequency [Hz] (0 for step and random).
    """

    task: str
    values_nm: np.ndarray
    amplitude_nm: float
    frequency_hz: float

    @property
    def scale_nm(self) -> float:
        """Normalisation of the reward [N·m]: the largest |reference|, at least MIN_REWARD_SCALE_NM."""
        return max(float(np.abs(self.values_nm).max(initial=0.0)), MIN_REWARD_SCALE_NM)

    @property
    def first_sign(self) -> int:
        """Sign of the first non-zero reference (0 if none): the side the backlash is taken up on."""
        nonzero = np.flatnonzero(self.values_nm)
        return int(np.sign(self.values_nm[nonzero[0]])) if len(nonzero) else 0


def make_reference(task: str, n_ticks: int, dt_s: float, rng: np.random.Generator,
                   amplitude_nm: float | None = None, frequency_hz: float | None = None) -> Reference:
    """The reference of ``task`` over ``n_ticks`` control ticks of ``dt_s`` [s].

    Parameters
    ----------
    task : {'step', 'sine', 'square', 'random'}
        'step': zero for min(PRE_STEP_S, a quarter of the episode), then the step (size drawn from the
        paper's 0.05, 0.1, 0.2 N·m unless given). 'sine' / 'square': the paper's waveforms from zero phase
        (one drawn unless amplitude / frequency are given). 'random': levels log-uniform in
        RANDOM_AMPLITUDE_RANGE_NM with random sign, held RANDOM_HOLD_RANGE_S each, smoothed by a
        RANDOM_SMOOTHING_S first-order filter (amplitude = the largest |level|).
    rng : numpy.random.Generator
        Draws what is not given.
    amplitude_nm, frequency_hz : float, optional
        Override the drawn amplitude [N·m] / frequency [Hz] (frequency ignored by 'step' and 'random').
    """
    t = np.arange(n_ticks) * dt_s
    if task == "step":
        size = float(rng.choice(STEPS_NM)) if amplitude_nm is None else amplitude_nm
        values = np.where(t >= min(PRE_STEP_S, MAX_LEAD_IN_FRACTION * n_ticks * dt_s) - 0.5 * dt_s, size, 0.0)
        return Reference(task, values, size, 0.0)
    if task in ("sine", "square"):
        paper = PAPER_SINES if task == "sine" else PAPER_SQUARES
        base = paper[int(rng.integers(len(paper)))]
        wave = Waveform(base.name, task, base.amplitude_nm if amplitude_nm is None else amplitude_nm,
                        base.frequency_hz if frequency_hz is None else frequency_hz)
        return Reference(task, wave.reference(t), wave.amplitude_nm, wave.frequency_hz)
    if task == "random":
        values = np.empty(n_ticks)
        k = 0
        low, high = RANDOM_AMPLITUDE_RANGE_NM
        while k < n_ticks:
            level = math.exp(rng.uniform(math.log(low), math.log(high))) * rng.choice((-1.0, 1.0))
            if amplitude_nm is not None:
                level *= amplitude_nm / high
            hold = max(1, round(rng.uniform(*RANDOM_HOLD_RANGE_S) / dt_s))
            values[k:k + hold] = level
            k += hold
        alpha = dt_s / (RANDOM_SMOOTHING_S + dt_s)
        smoothed = np.empty(n_ticks)
        state = 0.0
        for i, v in enumerate(values):
            state += alpha * (v - state)
            smoothed[i] = state
        return Reference(task, smoothed, float(np.abs(smoothed).max(initial=0.0)), 0.0)
    raise ValueError(f"task = {task!r}: valid values are {', '.join(TASKS)}")
