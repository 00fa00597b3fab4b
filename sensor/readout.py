"""The calibrated joint torque sensor in the control loop: flexure twist and board temperature to N·m.

The factory calibration is what the paper does once per sensor (Sec. III-A): the loading and moment
protocols of :mod:`sensor.protocol` at the reference temperature, fitted by the QP (gamma chosen by the
paper's criterion, :func:`sensor.evaluation.calibrate`) or by least squares. The readout then reads the
photo-reflector array once per control tick with the plant's twist and the TMP117 temperature, so noise,
quantisation, hysteresis, bandwidth and thermal drift reach the controller.

Each run starts with a tare, as a rig zeroes its torque sensor before an experiment: the mean reading of the
unloaded sensor (zero twist) over a hold of ``photoreflector.tare_s`` (1 s; 0 reads without a tare) at the
board temperature of the run's first read is subtracted from every reading of the run (:func:`tare_offset`).
It removes the calibration's own zero error and the zero drift between the calibration temperature and the
rig's; the Eq. 20 compensation is not applied in the loop (the board warms by under 0.05 K over a motor
experiment, docs/fidelity.md).
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
# The tare hold's channel noise: a stream of its own, spawned from the run's seed (the run's noise is unchanged)
TARE_NOISE_STREAM = 1


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


def channel_coefficients(theta: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Eq. 10's (c3, c2, c1) of the eight channels as (8, 1) columns, for :func:`calibration_term` on
    (channels, readings) arrays; ``theta`` is :attr:`Calibration.theta`."""
    return theta[0:8, None], theta[8:16, None], theta[16:24, None]


def summed_torque(terms, offset: float):
    """Eq. 10 from its channel terms (:func:`calibration_term`) [N·m]: summed in channel order from 0.0, then
    plus the offset c0; the order of ``np.dot`` (OpenBLAS's ddot adds an 8-vector sequentially). Eight floats
    give a float; the eight rows of a (channels, readings) array give (readings,), each bit-identical to its
    reading alone."""
    torque = 0.0
    for term in terms:
        torque += term
    return torque + offset


def check_tare_s(tare_s: float, control_period_s: float) -> float:
    """``tare_s`` [s] if it is 0 (no tare) or at least one control period [s], else ValueError naming the
    valid values."""
    if not (tare_s == 0.0 or control_period_s <= tare_s < math.inf):
        raise ValueError(f"tare_s = {tare_s!r}: valid values are 0 (no tare) or [{control_period_s:g}, inf) s")
    return float(tare_s)


def tare_offset(params: TestbedParams, calibration: Calibration, seed: int, temperature_c: float,
                tare_s: float | None = None) -> float:
    """The tare of a run [N·m]: the mean calibrated reading of the unloaded sensor (zero twist, no moments)
    over ``tare_s`` [s] (``photoreflector.tare_s`` if None) of samples at the control rate, at the board
    temperature ``temperature_c`` [°C].

    The sensor of ``params`` starts from rest, with the channel noise of its own stream of the run's ``seed``
    (:data:`TARE_NOISE_STREAM`); each sample is the reading :class:`TorqueSensorReadout` gives for it. 0.0 if
    ``tare_s`` is 0. Raises ValueError for a ``tare_s`` that is neither 0 nor at least one control period.
    """
    dt = params.simulation.control_period_s
    n = round(check_tare_s(params.photoreflector.tare_s if tare_s is None else tare_s, dt) / dt)
    if n == 0:
        return 0.0
    stream = int(np.random.SeedSequence([seed, TARE_NOISE_STREAM]).generate_state(1)[0])
    voltages = PhotoReflectorArray(params, seed=stream).read(np.zeros(n), temperature_c=temperature_c)
    terms = calibration_term(*channel_coefficients(calibration.theta), voltages.T)
    return float(np.mean(summed_torque(terms, float(calibration.theta[24]))))


class TorqueSensorReadout:
    """The photo-reflector sensor and its calibration, read once per control tick: the measurement
    ``tau_sensor`` [N·m] of a control loop (:class:`sim.run.Measurement`), with the eight channel voltages
    ``v1`` ... ``v8`` [V] it was computed from as extra columns.

    The first read after :meth:`reset` takes the run's tare at that read's board temperature
    (:func:`tare_offset`); every reading of the run is the calibration's torque minus it.

    Parameters
    ----------
    params : TestbedParams, optional
        Parameter set (defaults if None).
    calibration : Calibration, optional
        Map from channel voltages to torque; :func:`factory_calibration` (QP) if None.
    seed : int
        Seed of this run's channel noise (and of its tare's, a stream of its own).
    tare_s : float, optional
        Unloaded hold averaged for the tare [s]: 0 (no tare) or at least one control period;
        ``photoreflector.tare_s`` of ``params`` if None.

    Attributes
    ----------
    tare_nm : float or None
        The run's tare [N·m] (None before the first read).
    """

    def __init__(self, params: TestbedParams | None = None, calibration: Calibration | None = None,
                 seed: int = 0, tare_s: float | None = None) -> None:
        self.params = params or TestbedParams()
        self.calibration = calibration or factory_calibration(self.params)
        self.seed = seed
        self.tare_s = check_tare_s(self.params.photoreflector.tare_s if tare_s is None else tare_s,
                                   self.params.simulation.control_period_s)
        th = self.calibration.theta  # [V^3, V^2, V] coefficients per channel, then the offset
        # (c3_k, c2_k, c1_k) per channel and c0, as Python floats: the per-tick path (see read)
        self._rows = tuple(zip(th[0:8].tolist(), th[8:16].tolist(), th[16:24].tolist(), strict=True))
        self._offset = float(th[24])
        self.reset()

    def reset(self) -> None:
        """Restart the noise sequence, the hysteresis and the sensing chain (same seed, same run); the next read
        takes the tare again."""
        self._array = PhotoReflectorArray(self.params, seed=self.seed)
        self._voltages: list[float] = [math.nan] * CHANNELS
        self.tare_nm: float | None = None

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
        """Sensor torque [N·m] for one sample of flexure twist [rad], board temperature [°C], moments [N·m]:
        Eq. 10 of the channel voltages (:func:`summed_torque`, in Python floats for speed) minus the run's tare
        (taken at the first read's temperature). Floats; (N,) arrays for :class:`TorqueSensorStack`."""
        self._take_tare(temperature_c)
        v = self._array.read_sample_list(twist_rad, tx_nm, ty_nm, temperature_c)
        self._voltages = v
        return summed_torque(self._terms(v), self._offset) - self.tare_nm

    def _take_tare(self, temperature_c: float) -> None:
        """The run's tare [N·m] (:func:`tare_offset`), once per run, before its first reading."""
        if self.tare_nm is None:
            self.tare_nm = tare_offset(self.params, self.calibration, self.seed, temperature_c, self.tare_s)

    def _terms(self, v):
        """Eq. 10's cubic of each channel's voltage [N·m] (:func:`calibration_term`), in channel order."""
        return [calibration_term(c3, c2, c1, vk) for (c3, c2, c1), vk in zip(self._rows, v, strict=True)]

    def read(self, plant) -> float:
        """Sensor torque [N·m] for the plant's current tick (its flexure twist and TMP117 reading)."""
        return self.read_sample(plant.flexure_angle_rad, plant.tmp117_temperature_c)


class TorqueSensorStack(TorqueSensorReadout):
    """N optical sensors of one calibration read together: :meth:`read` of a batched plant
    (:class:`sim.batched.BatchedPlant`) gives the (N,) torques [N·m] each sensor's own
    :class:`TorqueSensorReadout` would give, by the same per-tick path on (N,) arrays, each unit's tare taken at
    its first read after :meth:`set_unit`.

    Parameters
    ----------
    n : int
        Number of sensors; each is set by :meth:`set_unit` before the first read.
    calibration : Calibration
        The map every unit is read through (e.g. the nominal unit's factory calibration).
    tare_s : float, optional
        Unloaded hold averaged for each unit's tare [s] (as :class:`TorqueSensorReadout`); each unit's
        ``photoreflector.tare_s`` if None.

    Attributes
    ----------
    tare_nm : numpy.ndarray
        Each unit's tare [N·m], (N,) (NaN before a unit's first read).
    """

    def __init__(self, n: int, calibration: Calibration, tare_s: float | None = None) -> None:
        self.n = n
        self.calibration = calibration
        self.tare_s = None if tare_s is None else float(tare_s)  # checked against each unit's params in set_unit
        self._coefficients = channel_coefficients(calibration.theta)
        self._offset = float(calibration.theta[24])
        self._array = PhotoReflectorStack(n)
        self._voltages = np.full((CHANNELS, n), math.nan)
        self.tare_nm = np.full(n, math.nan)
        self._tare_pending: dict[int, tuple[TestbedParams, int]] = {}

    def reset(self) -> None:
        """Units are reset one by one (:meth:`set_unit`)."""

    def set_unit(self, i: int, params: TestbedParams, seed: int) -> None:
        """Sensor i becomes the unit of ``params`` with the channel noise of ``seed``, from rest; its tare is
        taken at its next read."""
        if self.tare_s is not None:
            check_tare_s(self.tare_s, params.simulation.control_period_s)
        self._array.set_unit(i, PhotoReflectorArray(params, seed=seed))
        self._tare_pending[i] = (params, seed)

    def _take_tare(self, temperature_c: np.ndarray) -> None:
        for i, (params, seed) in self._tare_pending.items():
            self.tare_nm[i] = tare_offset(params, self.calibration, seed, float(temperature_c[i]), self.tare_s)
        self._tare_pending.clear()

    @property
    def voltages_v(self) -> np.ndarray:
        """The channel voltages [V] of the last read, (N, 8)."""
        return self._voltages.T.copy()

    def _terms(self, v: np.ndarray) -> np.ndarray:
        """(8, N): summed row by row, in channel order, as the single readout sums its channels."""
        return calibration_term(*self._coefficients, v)
