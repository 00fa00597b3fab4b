"""The paper's torque-control protocols (Sec. V), defined once for the experiments and the environment.

* Steps (Sec. V-A, Table VI): the reference zero for :data:`PRE_STEP_S`, then one of :data:`STEPS_NM`.
* Sine and square references (Sec. V-B, Table VII): :data:`WAVEFORMS`, each from zero phase.

``experiments.step``, ``experiments.sinusoid`` and ``experiments.open_loop_step`` run them on the testbed;
``envs.references`` draws the environment's paper tasks from them.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

STEPS_NM = (0.05, 0.1, 0.2)  # [N·m] paper Sec. V-A, Table VI
PRE_STEP_S = 0.5  # [s] reference zero before the step


@dataclass(frozen=True)
class Waveform:
    """A reference: 'sine' or 'square' of amplitude [N·m] and frequency [Hz]."""

    name: str
    shape: str
    amplitude_nm: float
    frequency_hz: float

    def reference(self, t_s: np.ndarray) -> np.ndarray:
        s = np.sin(2.0 * np.pi * self.frequency_hz * t_s)
        return self.amplitude_nm * (s if self.shape == "sine" else np.where(s >= 0.0, 1.0, -1.0))


# Paper Sec. V-B, Table VII
WAVEFORMS = (Waveform("0.05 N·m sine 0.2 Hz", "sine", 0.05, 0.2),
             Waveform("0.1 N·m square 1 Hz", "square", 0.1, 1.0),
             Waveform("10 N·m sine 0.2 Hz", "sine", 10.0, 0.2))
