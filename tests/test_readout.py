"""The calibrated sensor in the control loop reads the flexure torque through the channel model."""

import dataclasses

import numpy as np
import pytest

from models.gim8108_testbed.derived import derive
from sensor.photoreflector import PhotoReflectorArray
from sensor.readout import TorqueSensorReadout, factory_calibration, tare_offset
from sim.params import ParameterError, TestbedParams


def test_scalar_read_equals_the_array_read_sample_by_sample():
    """read_sample carries the same hysteresis, noise and ADC state as read: bit-identical voltages."""
    twist = 0.02 * np.sin(np.linspace(0.0, 12.0, 200))
    batch = PhotoReflectorArray(seed=3).read(twist, 1.0, -2.0, 31.0)
    one = PhotoReflectorArray(seed=3)
    scalar = np.array([one.read_sample(x, 1.0, -2.0, 31.0) for x in twist])
    np.testing.assert_array_equal(scalar, batch)


def test_readout_returns_the_static_torque_within_the_calibration_bound():
    """At the calibration temperature a held torque T twists the flexure T/K_t; the mean reading is T
    within the QP's error bound (0.2 % FS = 0.16 N·m)."""
    params = TestbedParams()
    k_t = derive(params).flexure_stiffness_nm_per_rad
    readout = TorqueSensorReadout(params, seed=5)
    for tau in (-20.0, -1.0, 0.0, 2.0, 15.0):
        readings = [readout.read_sample(tau / k_t, params.photoreflector.reference_temperature_c) for _ in range(200)]
        assert np.mean(readings) == pytest.approx(tau, abs=factory_calibration(params).e_max_nm)


def test_same_seed_gives_the_same_readings_and_reset_restarts_them():
    """Two readouts with one seed agree; reset() replays the sequence."""
    a, b = TorqueSensorReadout(seed=7), TorqueSensorReadout(seed=7)
    first = [a.read_sample(1e-3, 25.0) for _ in range(20)]
    assert first == [b.read_sample(1e-3, 25.0) for _ in range(20)]
    a.reset()
    assert first == [a.read_sample(1e-3, 25.0) for _ in range(20)]
    assert first != [TorqueSensorReadout(seed=8).read_sample(1e-3, 25.0) for _ in range(20)]


def test_factory_calibration_rejects_an_unknown_method():
    """The error names the argument and its valid values."""
    with pytest.raises(ValueError, match="method"):
        factory_calibration(TestbedParams(), method="svd")


def test_scalar_and_batch_reads_interleaved_on_one_array_equal_one_batch_read():
    """Noise (drawn in blocks for the scalar path), hysteresis and sensing-chain state pass between the two
    paths in order: any mix of per-sample and batch reads gives one batch read's voltages, bit for bit, with
    moments and a board temperature that change from sample to sample."""
    rng = np.random.default_rng(4)
    n = 1500  # more than one block of buffered noise
    twist = 0.01 * np.sin(np.linspace(0.0, 30.0, n)) + 1e-4 * rng.standard_normal(n)
    tx, ty = rng.normal(0.0, 3.0, n), np.where(rng.random(n) < 0.5, 0.0, rng.normal(0.0, 3.0, n))
    temperature = 25.0 + 0.0078125 * np.floor(np.linspace(0.0, 40.0, n))
    whole = PhotoReflectorArray(seed=6).read(twist, tx, ty, temperature)
    mixed, parts, k = PhotoReflectorArray(seed=6), [], 0
    for size in rng.integers(1, 60, n):
        if k >= n:
            break
        if size % 3:  # sample by sample
            for i in range(k, min(k + size, n)):
                parts.append(mixed.read_sample(twist[i], tx[i], ty[i], temperature[i])[None, :])
        else:
            parts.append(mixed.read(twist[k:k + size], tx[k:k + size], ty[k:k + size], temperature[k:k + size]))
        k += size
    np.testing.assert_array_equal(np.vstack(parts), whole)


def test_readout_torque_is_the_calibrations_prediction_of_its_voltages_minus_the_tare():
    """The per-tick Eq. 10 (Horner per channel in Python floats) agrees with Calibration.predict, less the run's
    tare."""
    params = TestbedParams()
    k_t = derive(params).flexure_stiffness_nm_per_rad
    readout = TorqueSensorReadout(params, seed=2)
    for tau in (-18.0, -0.3, 0.0, 0.05, 7.0, 24.0):
        torque = readout.read_sample(tau / k_t, 27.5)
        predicted = readout.calibration.predict(readout.voltages_v[None, :])[0]
        assert torque == pytest.approx(predicted - readout.tare_nm, rel=1e-12, abs=1e-12)


def _held(readout, twist_rad: float, temperature_c: float, n: int) -> np.ndarray:
    return np.array([readout.read_sample(twist_rad, temperature_c) for _ in range(n)])


def test_a_tare_removes_a_calibration_offset_exactly():
    """Adding 0.3 N·m to the calibration's offset c0 moves an untared reading by 0.3 N·m and a tared one by
    nothing (to rounding): the tare is of the reading the calibration gives."""
    params = TestbedParams()
    k_t = derive(params).flexure_stiffness_nm_per_rad
    calibration = factory_calibration(params)
    theta = calibration.theta.copy()
    theta[24] += 0.3
    shifted = dataclasses.replace(calibration, theta=theta)
    twist = 2.0 / k_t
    for tare_s, moved in ((0.0, 0.3), (params.photoreflector.tare_s, 0.0)):
        base = _held(TorqueSensorReadout(params, calibration, seed=4, tare_s=tare_s), twist, 26.0, 50)
        other = _held(TorqueSensorReadout(params, shifted, seed=4, tare_s=tare_s), twist, 26.0, 50)
        np.testing.assert_allclose(other - base, moved, rtol=0.0, atol=1e-12)


def test_after_a_tare_the_unloaded_sensor_reads_zero_within_the_noise_of_the_means():
    """Off the calibration temperature the untared zero is off by the zero drift; tared at that temperature,
    the mean of 5000 unloaded readings is zero within 4 standard errors of the two means (the tare's n = 1000
    samples and these), and the raw offset is larger than that bound."""
    params = TestbedParams()
    dt = params.simulation.control_period_s
    n_tare, n = round(params.photoreflector.tare_s / dt), 5000
    for temperature in (25.0, 30.0):
        tared = _held(TorqueSensorReadout(params, seed=11), 0.0, temperature, n)
        bound = 4.0 * tared.std() * np.sqrt(1.0 / n_tare + 1.0 / n)
        assert abs(tared.mean()) < bound
    raw = _held(TorqueSensorReadout(params, seed=11, tare_s=0.0), 0.0, 30.0, n)
    assert abs(raw.mean()) > 3.0 * bound


def test_the_tare_leaves_the_runs_noise_unchanged_and_is_taken_at_the_first_reads_temperature():
    """The tare's hold draws its own noise: a tared run reads the untared run of the same seed less one
    constant, the tare taken at the first read's board temperature (not at later ones), also after reset()."""
    params = TestbedParams()
    twist = 0.01 * np.sin(np.linspace(0.0, 6.0, 300))
    temperature = 26.0 + 0.0078125 * np.arange(300)
    tared, raw = TorqueSensorReadout(params, seed=3), TorqueSensorReadout(params, seed=3, tare_s=0.0)
    for _ in range(2):
        got = np.array([tared.read_sample(x, t) for x, t in zip(twist, temperature, strict=True)])
        want = np.array([raw.read_sample(x, t) for x, t in zip(twist, temperature, strict=True)])
        assert tared.tare_nm == tare_offset(params, tared.calibration, 3, 26.0)
        np.testing.assert_allclose(want - got, tared.tare_nm, rtol=0.0, atol=1e-14)
        tared.reset()
        raw.reset()


def test_tare_s_outside_its_valid_values_is_refused_naming_them():
    """0 (no tare) or at least one control period."""
    for bad in (-1.0, 1e-4, float("nan"), float("inf")):
        with pytest.raises(ValueError, match=r"tare_s = .*valid values are 0 \(no tare\) or \[0.001, inf\) s"):
            TorqueSensorReadout(tare_s=bad)


def test_the_tare_is_a_parameter_every_run_reads_and_its_invalid_values_name_the_field():
    """``photoreflector.tare_s = 0`` (e.g. from a --params file) reads as the readout's ``tare_s=0``; a hold
    shorter than one control period is refused by the parameters, naming the field and its valid values."""
    untared = TestbedParams().replace(photoreflector={"tare_s": 0.0})
    by_param = _held(TorqueSensorReadout(untared, seed=5), 0.0, 30.0, 20)
    by_argument = _held(TorqueSensorReadout(TestbedParams(), seed=5, tare_s=0.0), 0.0, 30.0, 20)
    np.testing.assert_array_equal(by_param, by_argument)
    with pytest.raises(ParameterError, match=r"photoreflector.tare_s = 0.0005 s: valid values are 0 \(no tare\)"):
        TestbedParams().replace(photoreflector={"tare_s": 5e-4})
