"""The first-order low-pass of sim.lowpass against the closed-form responses of a continuous first-order lag."""

import math

import numpy as np
import pytest

from sim.lowpass import lowpass_gain, lowpass_step

T = 1e-3  # control period [s]


def _filter(samples: np.ndarray, gain: float, initial: float) -> np.ndarray:
    out, state = np.empty(len(samples)), initial
    for k, x in enumerate(samples):
        state = lowpass_step(state, x, gain)
        out[k] = state
    return out


@pytest.mark.parametrize("bandwidth_hz", [10.0, 1000.0, 5000.0])
def test_a_held_step_matches_the_continuous_lag_exactly_at_the_samples(bandwidth_hz):
    """A step A held from t = 0 gives A·(1 − exp(−t/τ)), τ = 1/(2π f_c), at every sample t = kT."""
    tau, n, amplitude = 1.0 / (2.0 * math.pi * bandwidth_hz), 300, 0.7
    y = _filter(np.full(n, amplitude), lowpass_gain(bandwidth_hz, T), 0.0)
    t = np.arange(1, n + 1) * T
    np.testing.assert_allclose(y, amplitude * (1.0 - np.exp(-t / tau)), rtol=1e-12, atol=1e-15)


def _sine_error(bandwidth_hz: float, signal_hz: float, period_s: float, amplitude: float = 1.0) -> float:
    """Largest difference between the filter fed the sine at each held interval's midpoint and the continuous
    lag's response to the sine from rest: A·|H|·(sin(ωt − φ) + sin φ·exp(−t/τ)), |H| = 1/sqrt(1 + (ωτ)²),
    φ = atan(ωτ)."""
    tau, w = 1.0 / (2.0 * math.pi * bandwidth_hz), 2.0 * math.pi * signal_hz
    k = np.arange(1, int(round(1.0 / period_s)) + 1)
    y = _filter(amplitude * np.sin(w * (k - 0.5) * period_s), lowpass_gain(bandwidth_hz, period_s), 0.0)
    t = k * period_s
    gain, phase = 1.0 / math.hypot(1.0, w * tau), math.atan(w * tau)
    expected = amplitude * gain * (np.sin(w * t - phase) + math.sin(phase) * np.exp(-t / tau))
    return float(np.abs(y - expected).max())


@pytest.mark.parametrize("bandwidth_hz, signal_hz", [(20.0, 10.0), (10.0, 0.2), (5.0, 30.0)])
def test_a_sine_follows_the_continuous_lag_to_second_order_in_the_period(bandwidth_hz, signal_hz):
    """The held midpoint samples differ from the sine by O(ωT); through the exact lag the output's error is
    second order, ≈ A·ω·ω_c·T²/12 (measured): below A·ω·ω_c·T²/10 and quartered when T halves."""
    w, wc = 2.0 * math.pi * signal_hz, 2.0 * math.pi * bandwidth_hz
    coarse, fine = _sine_error(bandwidth_hz, signal_hz, T), _sine_error(bandwidth_hz, signal_hz, T / 2)
    assert coarse < w * wc * T**2 / 10
    assert 3.8 < coarse / fine < 4.2


def test_the_bandwidth_is_the_minus_3_db_frequency():
    """In steady state a sine at f_c comes out at 1/√2 of its amplitude, lagging 45° (to O((2π f_c T)²) ≈ 2e-4,
    the held samples' error, at f_c = 2 Hz)."""
    fc, n = 2.0, 20000
    t = np.arange(1, n + 1) * T
    y = _filter(np.sin(2.0 * math.pi * fc * (t - T / 2)), lowpass_gain(fc, T), 0.0)[n // 2:]
    ts = t[n // 2:]
    basis = np.column_stack([np.sin(2.0 * math.pi * fc * ts), np.cos(2.0 * math.pi * fc * ts)])
    (a, b), *_ = np.linalg.lstsq(basis, y, rcond=None)
    assert math.hypot(a, b) == pytest.approx(1.0 / math.sqrt(2.0), abs=5e-5)
    assert math.degrees(math.atan2(-b, a)) == pytest.approx(45.0, abs=0.01)


def test_arrays_filter_n_channels_at_once_as_the_scalars_do():
    """One call with (N,) states, samples and gains equals N scalar calls, bit for bit."""
    rng = np.random.default_rng(3)
    bandwidths, states, samples = rng.uniform(10.0, 5000.0, 6), rng.normal(size=6), rng.normal(size=6)
    gains = lowpass_gain(bandwidths, T)
    batched = lowpass_step(states, samples, gains)
    scalar = [lowpass_step(float(s), float(x), lowpass_gain(float(f), T))
              for s, x, f in zip(states, samples, bandwidths, strict=True)]
    np.testing.assert_array_equal(batched, scalar)
    assert isinstance(lowpass_gain(1000.0, T), float)


@pytest.mark.parametrize("bandwidth_hz, period_s, fragment", [
    (0.0, T, "bandwidth_hz = 0.0: valid range (0, inf) Hz"),
    (math.inf, T, "bandwidth_hz = inf"),
    (np.array([10.0, -1.0]), T, "bandwidth_hz"),
    (10.0, 0.0, "period_s = 0.0: valid range (0, inf) s"),
])
def test_a_non_positive_bandwidth_or_period_is_refused_naming_it(bandwidth_hz, period_s, fragment):
    with pytest.raises(ValueError, match=fragment.replace("(", r"\(").replace(")", r"\)")):
        lowpass_gain(bandwidth_hz, period_s)
