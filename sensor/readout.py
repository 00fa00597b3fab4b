"""The calibrated joint torque sensor in the control loop: flexure twist and board temperature to N·m.

The factory calibration is what the paper does once per sensor (Sec. III-A): the loading and moment
protocols of :mod:`sensor.protocol` at the reference temperature, fitted by the QP (gamma chosen by the
paper's criterion, :func:`sensor.evaluation.calibrate`) or by least squares. The readout then reads the
photo-reflector array once per control tick with the plant's twist and the TMP117 temperature, so noise,
quantisation, hysteresis, bandwidth and thermal drift reach the controller.
"""

from __future__ import annotations

import math
from functools import lru_cache
from typing import Literal

import numpy as np

from sensor.calibration import Calibration
from sensor.evaluation import calibrate
from sensor.photoreflector import CHANNELS, PhotoReflectorArray, PhotoReflectorStack
from sensor.protocol import calibration_schedule, check_params, crosstalk_schedule, record
from sim.params import TestbedParams
from sim.runlog import STANDARD_UNITS, VOLTAGE_COLUMNS

# The factory calibration's run seed: the noise of the calibration record, not of later runs.
FACTORY_CALIBRATION_SEED = 0


@lru_cache(maxsize=8)
def factory_calibration(params: TestbedParams | None = None, method: Literal["ls", "qp"] = "qp",
                        seed: int = FACTORY_CALIBRATION_SEED) -> Calibration:
    """Calibrate the sensor unit of ``params`` on the simulated rig (cached per arguments).

    Parameters
    ----------
    params : TestbedParams, optional
        Parameter set (defaults if None); ``photoreflector.unit_seed`` selects the unit.
    method : {'qp', 'ls'}
        The paper's QP (Eq. 17, gamma by its criterion) or least squares (Eq. 11).
    seed : int
        Seed of the calibration record's noise (channels and reference).

    Returns
    -------
    Calibration
        Eq. 10's coefficients: channel voltages [V] to joint torque [N·m].

    Raises
    ------
    sim.params.ParameterError
        If the sensor parameters cannot work together (:func:`sensor.protocol.check_params`).
    sensor.calibration.InfeasibleCalibrationError
        If the QP finds no calibration within the paper's error bound.
    """
    if method not in ("ls", "qp"):
        raise ValueError(f"method = {method!r}: valid values are 'ls', 'qp'")
    params = params or TestbedParams()
    check_params(params)
    streams = np.random.SeedSequence(seed).spawn(3)

    def run(stream, schedule):
        array = PhotoReflectorArray(params, seed=stream.generate_state(1)[0])
        return record(schedule, array, np.random.default_rng(stream))

    dt = params.simulation.control_period_s
    rig = calibrate(run(streams[0], calibration_schedule(dt)),
                    [run(s, crosstalk_schedule(dt, axis)) for s, axis in zip(streams[1:], "xy", strict=True)],
                    fs_nm=params.photoreflector.full_scale_nm)
    return rig.ls if method == "ls" else rig.qp


def calibration_term(c3, c2, c1, v):
    """One channel's share of Eq. 10, ((c3·v + c2)·v + c1)·v [N·m] for its voltage [V] (Horner): floats, or
    (channels, sensors) arrays."""
    return ((c3 * v + c2) * v + c1) * v


class TorqueSensorReadout:
    """The photo-reflector sensor and its calibration, read once per control tick: the measurement
    ``tau_sensor`` [N·m] of a control loop (:class:`sim.run.Measurement`), with the eight channel voltages
    ``v1`` ... ``v8`` [V] it was computed from as extra columns.

    Parameters
    ----------
    params : TestbedParams, optional
        Parameter set (defaults if None).
    calibration : Calibration, optional
        Map from channel voltages to torque; :func:`factory_calibration` (QP) if None.
    seed : int
        Seed of this run's channel noise.
    """

    def __init__(self, params: TestbedParams | None = None, calibration: Calibration | None = None,
                 seed: int = 0) -> None:
        self.params = params or TestbedParams()
        self.calibration = calibration or factory_calibration(self.params)
        self.seed = seed
        th = self.calibration.theta  # [V^3, V^2, V] coefficients per channel, then the offset
        # (c3_k, c2_k, c1_k) per channel and c0, as Python floats: the per-tick path (see read)
        self._rows = tuple(zip(th[0:8].tolist(), th[8:16].tolist(), th[16:24].tolist(), strict=True))
        self._offset = float(th[24])
        self.reset()

    def reset(self) -> None:
        """Restart the noise sequence, the hysteresis and the sensing chain (same seed, same run)."""
        self._array = PhotoReflectorArray(self.params, seed=self.seed)
        self._voltages: list[float] = [math.nan] * CHANNELS

    @property
    def voltages_v(self) -> np.ndarray:
        """The eight channel voltages [V] of the last read, (8,) (NaN before the first)."""
        return np.array(self._voltages)

    name, unit = "tau_sensor", "N·m"
    extra_units = {name: STANDARD_UNITS[name] for name in VOLTAGE_COLUMNS}

    def extra_values(self) -> list[float]:
        """The eight channel voltages [V] of the last read."""
        return self._voltages

    def read_sample(self, twist_rad, temperature_c, tx_nm: float = 0.0, ty_nm: float = 0.0):
        """Sensor torque [N·m] for one sample of flexure twist [rad], board temperature [°C], moments [N·m].

        Eq. 10 by Horner per channel, summed in channel order from 0.0 then plus the offset: the order of
        ``np.dot`` (OpenBLAS's ddot adds an 8-vector sequentially), in Python floats for speed (floats; (N,)
        arrays for :class:`TorqueSensorStack`).
        """
        v = self._array.read_sample_list(twist_rad, tx_nm, ty_nm, temperature_c)
        self._voltages = v
        torque = 0.0
        for term in self._terms(v):
            torque += term
        return torque + self._offset

    def _terms(self, v):
        """Eq. 10's cubic of each channel's voltage [N·m] (:func:`calibration_term`), in channel order."""
        return [calibration_term(c3, c2, c1, vk) for (c3, c2, c1), vk in zip(self._rows, v, strict=True)]

    def read(self, plant) -> float:
        """Sensor torque [N·m] for the plant's current tick (its flexure twist and TMP117 reading)."""
        return self.read_sample(plant.flexure_angle_rad, plant.tmp117_temperature_c)


class TorqueSensorStack(TorqueSensorReadout):
    """N optical sensors of one calibration read together: :meth:`read` of a batched plant
    (:class:`sim.batched.BatchedPlant`) gives the (N,) torques [N·m] each sensor's own
    :class:`TorqueSensorReadout` would give, by the same per-tick path on (N,) arrays.

    Parameters
    ----------
    n : int
        Number of sensors; each is set by :meth:`set_unit` before the first read.
    calibration : Calibration
        The map every unit is read through (e.g. the nominal unit's factory calibration).
    """

    def __init__(self, n: int, calibration: Calibration) -> None:
        self.n = n
        self.calibration = calibration
        th = calibration.theta
        self._coefficients = th[0:8, None], th[8:16, None], th[16:24, None]  # (c3, c2, c1), channels x 1
        self._offset = float(th[24])
        self._array = PhotoReflectorStack(n)
        self._voltages = np.full((CHANNELS, n), math.nan)

    def reset(self) -> None:
        """Units are reset one by one (:meth:`set_unit`)."""

    def set_unit(self, i: int, params: TestbedParams, seed: int) -> None:
        """Sensor i becomes the unit of ``params`` with the channel noise of ``seed``, from rest."""
        self._array.set_unit(i, PhotoReflectorArray(params, seed=seed))

    @property
    def voltages_v(self) -> np.ndarray:
        """The channel voltages [V] of the last read, (N, 8)."""
        return self._voltages.T.copy()

    def _terms(self, v: np.ndarray) -> np.ndarray:
        """(8, N): summed row by row, in channel order, as the single readout sums its channels."""
        return calibration_term(*self._coefficients, v)
