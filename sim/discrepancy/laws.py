"""Friction laws the analysis writes once: the surrogate, the low-speed windows' forward model and the replay use
them."""

from __future__ import annotations

import numpy as np


def stribeck_level(velocity: np.ndarray, coulomb: float, breakaway: float, stribeck_velocity: float) -> np.ndarray:
    """Sliding friction level g(v) = F_c + (F_s - F_c)·exp(-(v/v_s)²) [N·m | N] (the plant's LuGre curve)."""
    return coulomb + (breakaway - coulomb) * np.exp(-(velocity / stribeck_velocity) ** 2)
