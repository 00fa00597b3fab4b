"""Lumped thermal network of the sensor board and the motor winding.

Not modelled by MuJoCo (its dcmotor thermal state covers the winding only, and would tie the slow thermal
dynamics to the 1 kHz mechanical step), so it is written here as a linear two-node network integrated
exactly (matrix exponential) over any step: mechanics-free runs advance it by minutes in one call.

    C_b dT_b/dt = (T_amb - T_b)/R_ba + (T_m - T_b)/R_mb + P_mcu
    C_m dT_m/dt = (T_amb - T_m)/R_ma + (T_b - T_m)/R_mb + P_cu
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import lru_cache

import numpy as np
import scipy.linalg

from sim.params import ThermalParams


@lru_cache(maxsize=64)
def _discrete(tp: ThermalParams, dt_s: float) -> tuple[np.ndarray, np.ndarray]:
    """Exact zero-order-hold discretisation (Ad, Bd) of the network for inputs [T_amb, P_mcu, P_cu]."""
    cb, cm = tp.board_heat_capacity_j_per_k, tp.motor_heat_capacity_j_per_k
    gba, gma, gmb = 1 / tp.board_to_ambient_k_per_w, 1 / tp.motor_to_ambient_k_per_w, 1 / tp.motor_to_board_k_per_w
    a = np.array([[-(gba + gmb) / cb, gmb / cb], [gmb / cm, -(gma + gmb) / cm]])
    b = np.array([[gba / cb, 1 / cb, 0.0], [gma / cm, 0.0, 1 / cm]])
    aug = np.zeros((5, 5))
    aug[:2, :2], aug[:2, 2:] = a, b
    e = scipy.linalg.expm(aug * dt_s)
    return e[:2, :2], e[:2, 2:]


@dataclass
class ThermalState:
    """Board and winding temperatures [°C]; start at the steady state of an idle motor (MCU on)."""

    params: ThermalParams
    ambient_c: float | None = None
    temperatures_c: np.ndarray = field(init=False)

    def __post_init__(self) -> None:
        if self.ambient_c is None:
            self.ambient_c = self.params.ambient_c
        self.temperatures_c = self.steady_state(copper_loss_w=0.0)

    def steady_state(self, copper_loss_w: float) -> np.ndarray:
        """[T_board, T_motor] at equilibrium for the current ambient and a constant copper loss [W]."""
        tp = self.params
        gba, gma, gmb = (1 / tp.board_to_ambient_k_per_w, 1 / tp.motor_to_ambient_k_per_w,
                         1 / tp.motor_to_board_k_per_w)
        g = np.array([[gba + gmb, -gmb], [-gmb, gma + gmb]])
        rhs = np.array([gba * self.ambient_c + tp.mcu_power_w, gma * self.ambient_c + copper_loss_w])
        return np.linalg.solve(g, rhs)

    def advance(self, dt_s: float, copper_loss_w: float) -> None:
        """Advance by ``dt_s`` [s] with a constant copper loss [W] (exact for piecewise-constant inputs)."""
        ad, bd = _discrete(self.params, float(dt_s))
        u = np.array([self.ambient_c, self.params.mcu_power_w, copper_loss_w])
        self.temperatures_c = ad @ self.temperatures_c + bd @ u

    @property
    def board_c(self) -> float:
        return float(self.temperatures_c[0])

    @property
    def motor_c(self) -> float:
        return float(self.temperatures_c[1])

    def tmp117_reading_c(self) -> float:
        """The board temperature as the TMP117 reports it, quantised to its LSB [°C]."""
        lsb = self.params.tmp117_resolution_c
        return round(self.board_c / lsb) * lsb
