"""The photo-reflector array against the paper's numbers and its own definitions."""

import numpy as np
import pytest

from models.gim8108_testbed.derived import derive
from sensor.photoreflector import (
    CHANNELS,
    PhotoReflectorArray,
    draw_unit,
    maxwell_slip,
    play_operator,
    reference_torque,
    slip_half_widths,
)
from sim.params import TestbedParams

P = TestbedParams()
K_T = derive(P).flexure_stiffness_nm_per_rad


def twist(tau_nm):
    return np.asarray(tau_nm, dtype=float) / K_T


@pytest.mark.parametrize("unit_seed", [0, 1, 2, 3])
def test_channel_sensitivities_are_the_papers_at_the_operating_point(unit_seed):
    """dV/dT_z at zero load lies in 0.024-0.04 V/(N·m) for every channel (paper Sec. III-B)."""
    p = P.replace(photoreflector={"unit_seed": unit_seed})
    sensor = PhotoReflectorArray(p)
    dtau = 1e-3
    slope = (sensor.ideal_voltages(twist([dtau]))[0] - sensor.ideal_voltages(twist([-dtau]))[0]) / (2 * dtau)
    assert np.all(np.abs(slope) >= 0.024 * (1 - 1e-3)) and np.all(np.abs(slope) <= 0.040 * (1 + 1e-3))


def test_a_positive_twist_raises_one_channel_of_each_pair_and_lowers_the_other():
    """Signs as the geometry gives them: the two channels of a direction move in opposite senses."""
    v = PhotoReflectorArray(P).ideal_voltages(twist([0.0, 10.0]))
    change = v[1] - v[0]
    assert np.all(change[0::2] > 0) and np.all(change[1::2] < 0)


@pytest.mark.parametrize("unit_seed", [0, 1, 7])
def test_every_curvature_term_has_the_linear_terms_sign_as_a_closing_gap_gives(unit_seed):
    """1/(d - x)² = (1/d²)(1 + 2x/d + 3(x/d)² + 4(x/d)³ + ...): closing the gap raises every term."""
    u = draw_unit(TestbedParams().replace(photoreflector={"unit_seed": unit_seed}))
    for term in (u.quadratic_v_per_m2, u.cubic_v_per_m3, u.quartic_v_per_m4):
        assert np.all(term * u.sensitivity_v_per_m > 0.0)


def test_the_voltage_swing_at_25_nm_is_the_papers_and_visibly_nonlinear():
    """|ΔV| at ±25 N·m is about 0.6-1 V per channel (paper) and the two sides differ (x², x³ terms)."""
    v = PhotoReflectorArray(P).ideal_voltages(twist([-25.0, 0.0, 25.0]))
    up, down = np.abs(v[2] - v[1]), np.abs(v[1] - v[0])
    pr = P.photoreflector
    slack = 1 + pr.quadratic_fraction_max + pr.cubic_fraction_max
    assert np.all(up > 0.6 / slack) and np.all(up < 1.0 * slack)
    assert np.max(np.abs(up - down) / (up + down)) > 0.005


def test_a_two_volt_swing_is_the_papers_39718_counts():
    """2 V on a 16-bit, 3.3 V-referenced ADC is 39,718 counts (paper Sec. III-B)."""
    assert 2.0 / PhotoReflectorArray(P).lsb_v == pytest.approx(39718, abs=1)


def test_readings_are_adc_quantised_and_noise_has_each_channels_level():
    """A static 20 s record: every sample is a whole number of LSBs; each channel's std is its noise level."""
    sensor = PhotoReflectorArray(P, seed=3)
    v = sensor.read(np.full(20_000, twist(5.0)))
    counts = v / sensor.lsb_v
    assert np.allclose(counts, np.rint(counts), atol=1e-6)
    expected = np.sqrt(sensor.unit.noise_v**2 + sensor.lsb_v**2 / 12)  # white noise plus quantisation
    assert v.std(axis=0) == pytest.approx(expected, rel=0.05)
    assert sensor.unit.noise_v.max() / sensor.unit.noise_v.min() == pytest.approx(
        P.photoreflector.noise_max_v / P.photoreflector.noise_min_v)


def test_hysteresis_loop_matches_the_maxwell_slip_closed_form_and_closes_at_the_turning_point():
    """0 -> 25 -> 0 N·m: element i lags by min(A - r_i, x + r_i) - max(0, x - r_i) between the branches; the
    channels differ by S_k l_s f_k times the mean lag (small-signal), closing at the turning point."""
    p = P.replace(photoreflector={"noise_min_v": 0.0, "noise_max_v": 0.0, "quadratic_fraction_max": 0.0,
                                  "cubic_fraction_max": 0.0, "quartic_fraction_max": 0.0})
    sensor = PhotoReflectorArray(p)
    n = 2001
    path = np.concatenate([np.linspace(0, 25, n), np.linspace(25, 0, n)[1:]])
    v = sensor.read(twist(path))
    k_t = derive(p).flexure_stiffness_nm_per_rad
    r = slip_half_widths(p.photoreflector.slip_twist_max_rad)
    scale = p.flexure.sensing_radius_m * sensor.unit.sensitivity_v_per_m * sensor.unit.slip_fraction
    lags = {}
    for tau in (5.0, 12.5, 24.5):
        x = tau / k_t
        lags[tau] = np.mean(np.minimum(25.0 / k_t - r, x + r) - np.maximum(0.0, x - r))
        i = round(tau / 25.0 * (n - 1))
        up, down = v[i], v[2 * (n - 1) - i]  # the same torque on both branches
        assert np.abs(down - up) == pytest.approx(scale * lags[tau], rel=0.02, abs=2 * sensor.lsb_v)
    assert lags[24.5] < 0.1 * lags[12.5]  # the loop closes at the turning point


def test_maxwell_slip_equals_a_plain_loop_over_elements_and_samples():
    """The run-compressed operator gives the per-sample, per-element loop's output exactly."""
    rng = np.random.default_rng(1)
    x = np.repeat(np.cumsum(rng.standard_normal(300)), rng.integers(1, 4, 300))
    widths = np.array([0.1, 0.5, 2.0])
    y, state = maxwell_slip(x, widths, np.zeros(3))
    s, ref = np.zeros(3), []
    for xi in x:
        s = np.array([min(max(sj, xi - w), xi + w) for sj, w in zip(s, widths, strict=True)])
        ref.append(s.mean())
    np.testing.assert_allclose(y, ref, rtol=0, atol=1e-15)
    np.testing.assert_allclose(state, s, rtol=0, atol=1e-15)


def test_play_operator_follows_only_past_its_half_width():
    """The play operator holds within ±r of the input and tracks it beyond."""
    y = play_operator(np.array([0.0, 0.5, 2.0, 1.5, 0.0]), 1.0)
    assert y.tolist() == [0.0, 0.0, 1.0, 1.0, 1.0]


def test_off_axis_moments_move_the_channels_by_about_60_mv_at_25_nm():
    """T_x = 25 N·m changes the channels that see the tilt by about 0.06 V (paper Sec. III-B)."""
    sensor = PhotoReflectorArray(P)
    v0 = sensor.ideal_voltages(twist([0.0]))[0]
    vx = sensor.ideal_voltages(twist([0.0]), tx_nm=25.0)[0]
    change = np.abs(vx - v0)
    seen = change > 1e-9  # channels on the x axis do not see a tilt about x
    assert seen.sum() == CHANNELS // 2
    spread = P.photoreflector.crosstalk_spread
    assert np.all((change[seen] > 0.06 * (1 - spread)) & (change[seen] < 0.06 * (1 + spread)))


def test_temperature_scales_each_channel_by_its_coefficient():
    """A 10 K warmer board changes V0 by exp(γ_k·10 K), channel by channel."""
    sensor = PhotoReflectorArray(P)
    t0 = P.photoreflector.reference_temperature_c
    v = sensor.ideal_voltages(twist([0.0, 0.0]), temperature_c=np.array([t0, t0 + 10.0]))
    assert v[1] / v[0] == pytest.approx(np.exp(sensor.unit.tempco_per_k * 10.0), rel=1e-12)


@pytest.mark.parametrize("delta_t_k", [1.0, -10.0, 25.0])
def test_a_common_coefficient_gives_a_linear_calibration_a_zero_and_a_gain_drift_in_closed_form(delta_t_k):
    """Straight channels, one coefficient γ for all: every channel's output, its operating point included,
    scales by g = exp(γ·ΔT), so a linear calibration τ̂ = Σ c_k V_k + c0, exact at the reference temperature,
    reads τ̂ − τ = (g − 1)·(τ − c0): a zero drift −(g − 1)·c0 and a gain drift (g − 1)·τ."""
    p = P.replace(photoreflector={"noise_min_v": 0.0, "noise_max_v": 0.0, "quadratic_fraction_max": 0.0,
                                  "cubic_fraction_max": 0.0, "quartic_fraction_max": 0.0, "slip_fraction_min": 0.0,
                                  "slip_fraction_max": 0.0, "optical_tempco_min_per_k": -1.6e-3,
                                  "optical_tempco_max_per_k": -1.6e-3})
    sensor = PhotoReflectorArray(p)
    tau = np.linspace(-25.0, 25.0, 51)
    v = sensor.ideal_voltages(twist(tau))
    # each channel's own straight line τ = a_k V_k + b_k, averaged: c_k = a_k / 8, c0 = mean b_k
    a, b = np.array([np.polyfit(v[:, k], tau, 1) for k in range(CHANNELS)]).T
    coef, c0 = a / CHANNELS, float(np.mean(b))
    assert v @ coef + c0 == pytest.approx(tau, abs=1e-9)  # exact at the reference temperature
    t = np.full(tau.size, p.photoreflector.reference_temperature_c + delta_t_k)
    warm = sensor.ideal_voltages(twist(tau), temperature_c=t) @ coef + c0
    g = np.exp(-1.6e-3 * delta_t_k)
    assert abs(c0) > 1.0  # the operating points reach the output: the zero drift is not trivially nil
    assert warm - tau == pytest.approx((g - 1.0) * (tau - c0), abs=1e-9)


def test_same_seeds_same_readings_and_unit_seed_picks_the_unit():
    """Noise is reproducible from the run seed; a different unit seed is a different sensor."""
    path = twist(np.linspace(-5, 5, 500))
    a = PhotoReflectorArray(P, seed=1).read(path)
    b = PhotoReflectorArray(P, seed=1).read(path)
    assert np.array_equal(a, b)
    other = draw_unit(P.replace(photoreflector={"unit_seed": 9}))
    assert not np.allclose(other.sensitivity_v_per_m, draw_unit(P).sensitivity_v_per_m)


def test_reading_in_chunks_equals_reading_at_once():
    """Hysteresis and noise state carry over between calls, so a run can be read tick by tick."""
    path = twist(np.concatenate([np.linspace(0, 8, 300), np.linspace(8, -3, 300)]))
    whole = PhotoReflectorArray(P, seed=4).read(path)
    sensor = PhotoReflectorArray(P, seed=4)
    chunks = np.vstack([sensor.read(path[i:i + 100]) for i in range(0, 600, 100)])
    assert np.array_equal(chunks, whole)


def test_bad_inputs_name_the_argument():
    """A moment series of the wrong length or a NaN temperature is refused by name."""
    sensor = PhotoReflectorArray(P)
    with pytest.raises(ValueError, match="tx_nm has shape"):
        sensor.read(np.zeros(10), tx_nm=np.zeros(9))
    with pytest.raises(ValueError, match="temperature_c has non-finite values at samples \\[2\\]"):
        sensor.read(np.zeros(4), temperature_c=np.array([20.0, 20.0, np.nan, 20.0]))


def test_reference_torque_is_quantised_to_the_mini85_resolution():
    """MINI85 readings are whole multiples of 7/748 N·m and unbiased."""
    rng = np.random.default_rng(0)
    ref = reference_torque(np.full(20_000, 3.0), P, rng)
    res = 7 / 748
    assert np.allclose(ref / res, np.rint(ref / res))
    assert ref.mean() == pytest.approx(3.0, abs=0.001)


@pytest.mark.parametrize("read_path", ["read", "read_sample_list"])
def test_sensing_chain_step_response_is_the_first_order_closed_form_at_the_samples(read_path):
    """At 50 Hz bandwidth a voltage step passes through the chain as V_b + (V_a - V_b) exp(-(t - t_step)/τ),
    τ = 1/(2π f_c), at every sample (the input held over each sample period, as the chain's discretisation
    assumes; noise off, 32-bit ADC, no slip so the analog levels are the ideal voltages)."""
    f_c, dt = 50.0, 1e-3
    p = P.replace(photoreflector={"bandwidth_hz": f_c, "noise_min_v": 0.0, "noise_max_v": 0.0, "adc_bits": 32,
                                  "slip_fraction_min": 0.0, "slip_fraction_max": 0.0})
    sensor = PhotoReflectorArray(p, sample_period_s=dt)
    n_before, n_after = 20, 200
    tw = np.concatenate([np.zeros(n_before), np.full(n_after, twist(10.0))])
    v = sensor.read(tw) if read_path == "read" else np.array([sensor.read_sample_list(x) for x in tw])
    v_a, v_b = sensor.ideal_voltages(twist([0.0, 10.0]))
    # the step is applied over the period that ends at sample n_before: t - t_step = (k - n_before + 1) dt
    k = np.arange(n_after)
    expected = v_b + (v_a - v_b) * np.exp(-2 * np.pi * f_c * (k + 1) * dt)[:, None]
    np.testing.assert_allclose(v[:n_before], np.broadcast_to(v_a, (n_before, CHANNELS)), rtol=0, atol=2 * sensor.lsb_v)
    np.testing.assert_allclose(v[n_before:], expected, rtol=0, atol=2 * sensor.lsb_v)
    assert np.all(np.abs(v[n_before] - v_b) > 0.5 * np.abs(v_a - v_b))     # the chain visibly lags


def test_the_default_5_khz_chain_settles_within_one_1_khz_sample():
    """At the paper's ~5 kHz (Table II) the chain's exp(-2π f_c dt) = 2e-14: a step shows in full at once."""
    p = P.replace(photoreflector={"noise_min_v": 0.0, "noise_max_v": 0.0, "adc_bits": 32,
                                  "slip_fraction_min": 0.0, "slip_fraction_max": 0.0})
    sensor = PhotoReflectorArray(p)
    v = sensor.read(np.array([0.0, twist(10.0)]))
    np.testing.assert_allclose(v[1], sensor.ideal_voltages(twist([10.0]))[0], rtol=0, atol=2 * sensor.lsb_v)


def test_a_noiseless_unit_is_the_same_unit_without_its_noise():
    """Channel noise set to zero changes the noise levels and nothing else the unit seed draws."""
    noisy = draw_unit(P)
    quiet = draw_unit(P.replace(photoreflector={"noise_min_v": 0.0, "noise_max_v": 0.0}))
    assert np.all(quiet.noise_v == 0.0) and np.all(noisy.noise_v > 0.0)
    for name in ("sensitivity_v_per_m", "crosstalk_v_per_nm", "tempco_per_k"):
        np.testing.assert_array_equal(getattr(quiet, name), getattr(noisy, name))
