"""The eight-channel photo-reflector array (paper Secs. II-III): twist, moments and temperature to ADC volts.

Written in Python because MuJoCo has no optical sensor. Channel k sits in direction φ_j = j·π/2
(j = k // 2: +x, +y, -x, -y) at the sensing radius l_s. The two channels of a direction face the reflective
surface on opposite sides of its tooth, so a positive twist closes one gap and opens the other (signs +1, -1).
With δ = l_s · play(θ) the surface displacement [m] under the flexure twist θ:

    V_k = g_k(T) · (V0_k + S_k x + Q_k x² + C_k x³ + P_k x⁴) + X_k·(T_x sin φ_j - T_y cos φ_j) + n_k,
    x = s_k l_s θ_k,   θ_k = (1 - f_k) θ + f_k M(θ)
    g_k(T) = exp(γ_k (T - T_ref))     (the coupled emitter-detector device's temperature coefficient γ_k)

g_k scales the operating point V0_k too (the channel's offset drift, γ_k·V0_k per kelvin); every channel is read
at the board temperature the caller gives (the TMP117's). Then a first-order sensing chain of the rated
bandwidth and the ADC (``adc_bits`` over ``adc_reference_v``).
Hysteresis: the reflective target is bolted to the hub, and its joint micro-slips. ``M`` is a Maxwell-slip
(Prandtl-Ishlinskii) operator, the mean of :data:`SLIP_ELEMENTS` play operators with half-widths spread
uniformly up to ``slip_twist_max_rad``: its loops close at the turning points (a play operator's do not). Each
channel sees a fraction f_k of the twist through that joint (the slip is not a pure rotation, so it differs
from reflector to reflector), which is what lets a least-squares fit trade hysteresis against noise.
Per-channel constants of one unit are drawn from the parameter ranges with ``unit_seed``; noise is drawn
from the run's seed.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from models.gim8108_testbed.derived import derive
from sim.params import TestbedParams

CHANNELS = 8
CALIBRATION_SPAN_NM = 25.0  # paper Sec. III-B: calibration range ±25 N·m; the nonlinearity fractions refer to it
SLIP_ELEMENTS = 8  # discretisation of the Maxwell-slip operator: loops within 1/8 of their width of the limit


@dataclass(frozen=True)
class SensorUnit:
    """Per-channel constants of one manufactured sensor (arrays of shape (8,))."""

    signs: np.ndarray  # ±1: a positive twist closes (+1) or opens (-1) the channel's gap
    angles_rad: np.ndarray  # direction of the channel, φ
    sensitivity_v_per_m: np.ndarray  # S_k
    quadratic_v_per_m2: np.ndarray  # Q_k
    cubic_v_per_m3: np.ndarray  # C_k
    quartic_v_per_m4: np.ndarray  # P_k
    slip_fraction: np.ndarray  # f_k
    operating_point_v: np.ndarray  # V0_k
    noise_v: np.ndarray  # white-noise std
    crosstalk_v_per_nm: np.ndarray  # X_k
    tempco_per_k: np.ndarray  # γ_k


def draw_unit(params: TestbedParams) -> SensorUnit:
    """The sensor unit selected by ``photoreflector.unit_seed``."""
    pr = params.photoreflector
    rng = np.random.default_rng(pr.unit_seed)
    span_m = params.flexure.sensing_radius_m * CALIBRATION_SPAN_NM / derive(params).flexure_stiffness_nm_per_rad
    sens = rng.uniform(pr.sensitivity_min_v_per_m, pr.sensitivity_max_v_per_m, CHANNELS)
    # one sign for every term and channel: a reflector's 1/d²-like response to its gap closing by x expands as
    # 1 + 2x/d + 3(x/d)² + 4(x/d)³ + 5(x/d)⁴ ..., every coefficient of the linear one's sign
    quad = rng.uniform(0.0, 1.0, CHANNELS) * pr.quadratic_fraction_max * sens / span_m
    cubic = rng.uniform(0.0, 1.0, CHANNELS) * pr.cubic_fraction_max * sens / span_m**2
    quartic = rng.uniform(0.0, 1.0, CHANNELS) * pr.quartic_fraction_max * sens / span_m**3
    slip = rng.uniform(pr.slip_fraction_min, pr.slip_fraction_max, CHANNELS)
    v0 = pr.operating_point_v + rng.uniform(-1.0, 1.0, CHANNELS) * pr.operating_point_spread_v
    # noise levels log-uniformly between the quietest and the noisiest channel, both ends present
    levels = np.exp(np.linspace(math.log(pr.noise_min_v or 1e-12), math.log(pr.noise_max_v or 1e-12), CHANNELS))
    order = rng.permutation(CHANNELS)  # drawn whatever the levels, so noiseless units keep every other draw
    noise = levels[order] if pr.noise_max_v > 0 else np.zeros(CHANNELS)
    cross = pr.crosstalk_v_per_nm * (1.0 + pr.crosstalk_spread * rng.uniform(-1.0, 1.0, CHANNELS))
    tempco = rng.uniform(pr.optical_tempco_min_per_k, pr.optical_tempco_max_per_k, CHANNELS)
    return SensorUnit(
        signs=np.tile([1.0, -1.0], CHANNELS // 2),
        angles_rad=np.repeat(np.arange(CHANNELS // 2) * (math.pi / 2), 2),
        sensitivity_v_per_m=sens, quadratic_v_per_m2=quad, cubic_v_per_m3=cubic, quartic_v_per_m4=quartic,
        slip_fraction=slip, operating_point_v=v0,
        noise_v=noise, crosstalk_v_per_nm=cross, tempco_per_k=tempco)


def play_operator(x: np.ndarray, half_width: float, initial: float = 0.0) -> np.ndarray:
    """Backlash (play) hysteresis: y follows x but only once x has moved half_width past it."""
    y, _ = maxwell_slip(x, np.array([half_width]), np.array([initial]))
    return y


def slip_half_widths(slip_twist_max_rad: float) -> np.ndarray:
    """Half-widths of the Maxwell-slip elements [rad]: midpoints of SLIP_ELEMENTS equal slices of (0, max]."""
    return slip_twist_max_rad * (np.arange(SLIP_ELEMENTS) + 0.5) / SLIP_ELEMENTS


def maxwell_slip(x: np.ndarray, half_widths: np.ndarray, state: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Mean of play operators of the given half-widths driven by x: (output (N,), final element states)."""
    s = np.array(state, dtype=float)
    x = np.asarray(x, dtype=float)
    if len(x) == 0:
        return np.empty(0), s
    # the state only moves when the input does: step once per run of equal inputs (holds are most of a rig run)
    starts = np.flatnonzero(np.concatenate(([True], x[1:] != x[:-1])))
    y_runs = np.empty(len(starts))
    for j, xi in enumerate(x[starts].tolist()):
        np.clip(s, xi - half_widths, xi + half_widths, out=s)
        y_runs[j] = s.mean()
    return np.repeat(y_runs, np.diff(np.append(starts, len(x)))), s


def clip_nan(x, low, high):
    """numpy's clip of x to [low, high] (the lower bound first, NaN kept): on floats by comparisons, on arrays
    by :func:`numpy.clip`."""
    if isinstance(x, float):
        x = x if x > low or x != x else low
        return x if x < high or x != x else high
    return np.clip(x, low, high)


def _same(a, b) -> bool:
    """Whether two temperatures [°C] are equal: floats, or (N,) arrays element by element (NaN differs)."""
    return a == b if isinstance(a, float) else bool(np.array_equal(a, b))


# The per-tick formulas, elementwise: on one channel's Python floats (PhotoReflectorArray, per channel) or on
# (channels, units) arrays (PhotoReflectorStack, at once). IEEE arithmetic rounds alike in both.

def slip_mean(s):
    """Mean of the SLIP_ELEMENTS = 8 element states s[0] ... s[7] [rad]: numpy's reduction of eight (its +0.0
    identity plus the pairwise sum), over 8, so signed zeros, NaN and ties come out as in :func:`maxwell_slip`
    (floats, or rows of arrays)."""
    return (0.0 + (((s[0] + s[1]) + (s[2] + s[3])) + ((s[4] + s[5]) + (s[6] + s[7])))) / SLIP_ELEMENTS


def optical_voltage(twist_rad, slipped_rad, keep, f, sign, v0, s1, s2, s3, s4, gain, radius_m):
    """g·(V0 + S x + Q x² + C x³ + P x⁴) [V], x = r·(θ·(1 - f) + M(θ)·f)·s, of a channel for the twist and the
    slip operator's output [rad] (``keep`` = 1 - f)."""
    x = radius_m * (twist_rad * keep + slipped_rad * f) * sign
    return gain * (v0 + x * (s1 + x * (s2 + x * (s3 + x * s4))))


def sensing_chain(state_v, noisy_v, alpha, one_minus_alpha):
    """One sample of the first-order sensing chain [V]: α·state + (1 - α)·input."""
    return alpha * state_v + one_minus_alpha * noisy_v


def _as_series(name: str, value: np.ndarray | float, n: int) -> np.ndarray:
    arr = np.broadcast_to(np.asarray(value, dtype=float), (n,)) if np.ndim(value) == 0 else np.asarray(value, float)
    if arr.shape != (n,):
        raise ValueError(f"{name} has shape {arr.shape}; expected ({n},) like twist_rad, or a scalar")
    if not np.isfinite(arr).all():
        raise ValueError(f"{name} has non-finite values at samples {np.flatnonzero(~np.isfinite(arr))[:5].tolist()}")
    return arr


class PhotoReflectorArray:
    """One sensor unit read at a fixed sample period.

    Parameters
    ----------
    params : TestbedParams
        ``photoreflector`` and ``flexure`` groups are used.
    seed : int
        Seed of the noise of this run (the unit itself is ``photoreflector.unit_seed``).
    sample_period_s : float, optional
        ADC sample period [s] (the control period by default).
    """

    def __init__(self, params: TestbedParams | None = None, seed: int = 0,
                 sample_period_s: float | None = None) -> None:
        self.params = params or TestbedParams()
        self.unit = draw_unit(self.params)
        self.sample_period_s = sample_period_s or self.params.simulation.control_period_s
        pr = self.params.photoreflector
        self._rng = np.random.default_rng(seed)
        self._alpha = math.exp(-2.0 * math.pi * pr.bandwidth_hz * self.sample_period_s)
        self._lsb_v = pr.adc_reference_v / (2**pr.adc_bits - 1)
        self._half_widths = slip_half_widths(pr.slip_twist_max_rad)
        self._noise = NormalStream(self._rng)
        self._init_sample_path()
        # State carried from sample to sample, as lists of Python floats (read() converts at its ends).
        self._gain_temperature_c, self._gain = math.nan, [1.0] * CHANNELS
        self._slip_state = [0.0] * SLIP_ELEMENTS
        self._filter_state: list[float] | None = None

    def _init_sample_path(self) -> None:
        """Constants of the per-tick path (read_sample) as Python floats, per channel.

        Chosen for speed: for eight channels a loop over Python floats costs a fraction of numpy's per-call
        overhead on (8,) temporaries. Every expression of the sample path keeps the operation order of the
        array form (IEEE arithmetic rounds alike in both), so the voltages are bit-identical to read()'s.
        """
        if SLIP_ELEMENTS != 8:
            raise NotImplementedError("_slip_sample's pairwise mean is written out for SLIP_ELEMENTS = 8")
        u, pr = self.unit, self.params.photoreflector
        self._sensing_radius_m = self.params.flexure.sensing_radius_m
        self._reference_c = pr.reference_temperature_c
        self._max_count = 2**pr.adc_bits - 1
        self._one_minus_alpha = 1.0 - self._alpha
        self._filtering = self._alpha >= 1e-12
        self._half_widths_list = self._half_widths.tolist()
        f = u.slip_fraction
        # (1 - f_k, f_k, s_k, V0_k, S_k, Q_k, C_k, P_k) of channel k
        self._channel_rows = tuple(zip(
            (1.0 - f).tolist(), f.tolist(), u.signs.tolist(), u.operating_point_v.tolist(),
            u.sensitivity_v_per_m.tolist(), u.quadratic_v_per_m2.tolist(), u.cubic_v_per_m3.tolist(),
            u.quartic_v_per_m4.tolist(), strict=True))
        # (X_k, sin φ_k, cos φ_k) of channel k
        self._tilt_rows = tuple(zip(u.crosstalk_v_per_nm.tolist(), np.sin(u.angles_rad).tolist(),
                                    np.cos(u.angles_rad).tolist(), strict=True))
        self._noise_v = u.noise_v.tolist()
        self._tempco = u.tempco_per_k

    @property
    def lsb_v(self) -> float:
        """ADC step [V]."""
        return self._lsb_v

    def ideal_voltages(self, twist_rad: np.ndarray, tx_nm=0.0, ty_nm=0.0, temperature_c=None) -> np.ndarray:
        """Noise-free, unfiltered, unquantised channel voltages; no hysteresis state is kept.

        Parameters
        ----------
        twist_rad : (N,) array or float
            Flexure twist [rad] (every channel sees it whole: no slip of the target).
        tx_nm, ty_nm : (N,) array or float
            Off-axis moments [N·m].
        temperature_c : (N,) array or float, optional
            Board temperature [°C] (the calibration temperature if None).

        Returns
        -------
        numpy.ndarray, shape (N, 8)
            Channel voltages [V].
        """
        twist = np.atleast_1d(np.asarray(twist_rad, dtype=float))
        return self._analog(twist, twist, tx_nm, ty_nm, temperature_c)

    def _channel_twist(self, twist: np.ndarray, slipped: np.ndarray) -> np.ndarray:
        """θ_k = (1 - f_k) θ + f_k M(θ), (N, 8) [rad]."""
        f = self.unit.slip_fraction
        return twist[:, None] * (1.0 - f) + slipped[:, None] * f

    def _analog(self, twist: np.ndarray, slipped: np.ndarray, tx_nm, ty_nm, temperature_c) -> np.ndarray:
        n = len(twist)
        pr, u = self.params.photoreflector, self.unit
        tx = _as_series("tx_nm", tx_nm, n)
        ty = _as_series("ty_nm", ty_nm, n)
        temp = _as_series("temperature_c", pr.reference_temperature_c if temperature_c is None else temperature_c, n)
        x = self.params.flexure.sensing_radius_m * self._channel_twist(twist, slipped) * u.signs[None, :]
        optical = u.operating_point_v + x * (u.sensitivity_v_per_m + x * (
            u.quadratic_v_per_m2 + x * (u.cubic_v_per_m3 + x * u.quartic_v_per_m4)))
        gain = np.exp(u.tempco_per_k[None, :] * (temp[:, None] - pr.reference_temperature_c))
        tilt = tx[:, None] * np.sin(u.angles_rad) - ty[:, None] * np.cos(u.angles_rad)
        return gain * optical + u.crosstalk_v_per_nm * tilt

    def read(self, twist_rad: np.ndarray | float, tx_nm=0.0, ty_nm=0.0, temperature_c=None) -> np.ndarray:
        """Channel voltages as the ADC reports them, (N, 8) [V], for consecutive samples (state carries over).

        Parameters
        ----------
        twist_rad : (N,) array or float
            Flexure twist, hub minus outer ring [rad] (``Plant.flexure_angle_rad``).
        tx_nm, ty_nm : (N,) array or float
            Off-axis moments on the sensor [N·m].
        temperature_c : (N,) array or float, optional
            Board temperature [°C] (the calibration temperature if None).

        Returns
        -------
        numpy.ndarray, shape (N, 8)
            Channel voltages [V]: whole ADC counts times :attr:`lsb_v`, within [0, ``adc_reference_v``].
        """
        twist = np.atleast_1d(np.asarray(twist_rad, dtype=float))
        _as_series("twist_rad", twist, len(twist))
        slipped, state = maxwell_slip(twist, self._half_widths, self._slip_state)
        self._slip_state = state.tolist()
        v = self._analog(twist, slipped, tx_nm, ty_nm, temperature_c)
        v = v + self._noise.take(v.size).reshape(v.shape) * self.unit.noise_v
        v = self._filter(v)
        counts = np.clip(np.rint(v / self._lsb_v), 0, 2**self.params.photoreflector.adc_bits - 1)
        return counts * self._lsb_v

    def read_sample(self, twist_rad: float, tx_nm: float = 0.0, ty_nm: float = 0.0,
                    temperature_c: float | None = None) -> np.ndarray:
        """One sample of :meth:`read` for scalar inputs, (8,) [V]: the same model and state, without the
        per-call array checks (the control loop reads once per tick)."""
        return np.array(self.read_sample_list(twist_rad, tx_nm, ty_nm, temperature_c))

    def read_sample_list(self, twist_rad: float, tx_nm: float = 0.0, ty_nm: float = 0.0,
                         temperature_c: float | None = None) -> list[float]:
        """:meth:`read_sample` as a list of eight Python floats [V] (the fast path of a control tick).

        Parameters
        ----------
        twist_rad : float
            Flexure twist, hub minus outer ring [rad].
        tx_nm, ty_nm : float
            Off-axis moments on the sensor [N·m].
        temperature_c : float, optional
            Board temperature [°C] (the calibration temperature if None).

        Returns
        -------
        list of float
            The eight channel voltages [V], quantised as by :meth:`read`.
        """
        slipped = self._slip_sample(twist_rad)
        temp = self._reference_c if temperature_c is None else temperature_c
        if not _same(temp, self._gain_temperature_c):  # the TMP117 moves in 7.8 m°C steps: gains reused between
            self._set_gain_temperature(temp)
        v = self._optical_sample(twist_rad, slipped)
        if tx_nm or ty_nm:
            v = [vk + x * (tx_nm * s - ty_nm * c) for vk, (x, s, c) in zip(v, self._tilt_rows, strict=True)]
        v = self._noise_and_chain(v)
        self._filter_state = v
        return self._quantise(v)

    def _slip_sample(self, twist_rad: float) -> float:
        """Advance the Maxwell-slip elements to one input [rad]; their mean M(θ) [rad] (:func:`slip_mean`).

        Each element is numpy's clip (NaN-propagating, the lower bound first; :func:`clip_nan` written out, a
        call per element costing more than the clip).
        """
        s = []
        for sk, h in zip(self._slip_state, self._half_widths_list, strict=True):
            lo, hi = twist_rad - h, twist_rad + h
            sk = sk if sk > lo or sk != sk else lo
            s.append(sk if sk < hi or sk != sk else hi)
        self._slip_state = s
        return slip_mean(s)

    def _set_gain_temperature(self, temperature_c: float) -> None:
        """Optical gains g_k(T) [-] at a board temperature [°C] (np.exp, as the array form)."""
        self._gain_temperature_c = temperature_c
        self._gain = np.exp(self._tempco * (temperature_c - self._reference_c)).tolist()

    def _optical_sample(self, twist_rad: float, slipped_rad: float) -> list[float]:
        """:func:`optical_voltage` of each channel [V] for one twist and slip [rad]."""
        r = self._sensing_radius_m
        return [optical_voltage(twist_rad, slipped_rad, *row, g, r)
                for row, g in zip(self._channel_rows, self._gain, strict=True)]

    def _noise_and_chain(self, v: list[float]) -> list[float]:
        """The channels' white noise added to the voltages [V], then the first-order sensing chain (one pass;
        none on the first sample, nor when the chain settles within one)."""
        noisy = [vk + z * n for vk, z, n in zip(v, self._noise.take_list(CHANNELS), self._noise_v, strict=True)]
        if self._filter_state is None or not self._filtering:
            return noisy
        a, b = self._alpha, self._one_minus_alpha
        return [sensing_chain(state, vk, a, b) for state, vk in zip(self._filter_state, noisy, strict=True)]

    def _quantise(self, v: list[float]) -> list[float]:
        """ADC counts of the voltages times the LSB [V]: rint (half to even), clipped to [0, max count]."""
        lsb, top = self._lsb_v, self._max_count
        try:  # round() is rint for floats (a whole count is exact in a float); the ternary is the clip
            return [(c if 0 <= (c := round(vk / lsb)) <= top else (0 if c < 0 else top)) * lsb for vk in v]
        except (ValueError, OverflowError):  # a non-finite voltage: numpy's NaN propagation and saturation
            return (np.clip(np.rint(np.array(v) / lsb), 0, top) * lsb).tolist()

    def _filter(self, v: np.ndarray) -> np.ndarray:
        """First-order sensing chain, exact for a signal held over each sample period."""
        if not self._filtering:  # the chain settles within a sample: nothing to carry
            self._filter_state = v[-1].tolist()
            return v
        out = np.empty_like(v)
        state = v[0] if self._filter_state is None else np.array(self._filter_state)
        for i in range(len(v)):
            state = sensing_chain(state, v[i], self._alpha, self._one_minus_alpha)
            out[i] = state
        self._filter_state = state.tolist()
        return out


class NormalStream:
    """Standard normal draws of one generator, handed out in order, drawn in blocks.

    ``Generator.standard_normal(n)`` fills its n values one draw after another, so handing out a block's
    values in order gives exactly the numbers drawing each request's values on demand would. Chosen for
    speed: one numpy call per ``block`` values instead of one per control tick.

    Parameters
    ----------
    rng : numpy.random.Generator
        The only consumer of its draws from here on.
    block : int
        Values drawn per refill.
    """

    def __init__(self, rng: np.random.Generator, block: int = 64 * CHANNELS) -> None:
        self._rng, self._block = rng, block
        self._buffer: list[float] = []
        self._next = 0

    def take_list(self, n: int) -> list[float]:
        """The next n draws as Python floats."""
        i, j = self._next, self._next + n
        if j > len(self._buffer):
            self._buffer = self._buffer[i:] + self._rng.standard_normal(max(self._block, n)).tolist()
            i, j = 0, n
        self._next = j
        return self._buffer[i:j]

    def take(self, n: int) -> np.ndarray:
        """The next n draws, (n,) array (the buffered ones first, then straight from the generator)."""
        held = self._buffer[self._next:self._next + n]
        self._next += len(held)
        rest = self._rng.standard_normal(n - len(held))
        return np.concatenate((held, rest)) if held else rest


class NormalBank:
    """:class:`NormalStream` of N generators at once: ``take(k)`` hands out the next k draws of each generator
    as a (k, N) array. Each generator's draws come in its own order, so unit i gets exactly the numbers its own
    NormalStream would.

    Parameters
    ----------
    n : int
        Number of generators.
    block : int
        Values drawn per generator per refill (a multiple of every k taken).
    """

    def __init__(self, n: int, block: int = 64 * CHANNELS) -> None:
        self._block = block
        self._rngs: list[np.random.Generator | None] = [None] * n
        self._buffer = np.empty((n, block))
        self._next = np.full(n, block)
        self._rows = np.arange(n)[:, None]

    def set_rng(self, i: int, rng: np.random.Generator) -> None:
        """Draw generator i's values from ``rng`` from now on (its only consumer)."""
        self._rngs[i] = rng
        self._next[i] = self._block

    def take(self, k: int) -> np.ndarray:
        """The next k draws of every generator, (k, N): row j holds every generator's j-th."""
        if self._block % k:
            raise ValueError(f"k = {k}: must divide the block of {self._block} draws")
        if self._next.max() >= self._block:
            for i in np.flatnonzero(self._next >= self._block).tolist():
                self._buffer[i] = self._rngs[i].standard_normal(self._block)
                self._next[i] = 0
        start = self._next
        self._next = start + k
        if k == 1:
            return self._buffer[self._rows[:, 0], start][None, :]
        return self._buffer[self._rows, start[:, None] + np.arange(k)].T

    def normal(self, loc: float, scale: float) -> np.ndarray:
        """One ``Generator.normal(loc, scale)`` draw per generator, (N,): loc + scale·z, as numpy computes it."""
        return loc + scale * self.take(1)[0]


class PhotoReflectorStack(PhotoReflectorArray):
    """N sensor units read together, one sample per unit per call: the per-tick path of
    :class:`PhotoReflectorArray` (:meth:`read_sample_list`, its formulas :func:`optical_voltage`,
    :func:`sensing_chain`, :func:`slip_mean`) on (channels, units) arrays, unit i as its own PhotoReflectorArray
    (:meth:`set_unit`) reads it.

    Parameters
    ----------
    n : int
        Number of units; each is set by :meth:`set_unit` before the first read.
    """

    def __init__(self, n: int) -> None:  # the constants come per unit (set_unit), not from parameters
        self.n = n
        self._noise = NormalBank(n)
        self._sensing_radius_m, self._reference_c = np.full(n, np.nan), np.full(n, np.nan)
        self._max_count, self._lsb_v = np.full(n, np.nan), np.full(n, np.nan)
        self._alpha, self._one_minus_alpha = np.full(n, np.nan), np.full(n, np.nan)
        self._filtering = np.zeros(n, dtype=bool)
        self._started = np.zeros(n, dtype=bool)
        self._channel_rows = np.full((8, CHANNELS, n), np.nan)  # (1 - f, f, s, V0, S, Q, C, P) x channel x unit
        self._half_widths = np.full((SLIP_ELEMENTS, n), np.nan)
        self._tempco = np.full((CHANNELS, n), np.nan)
        self._noise_v = np.full((CHANNELS, n), np.nan)
        self._slip_state = np.zeros((SLIP_ELEMENTS, n))
        self._filter_state = np.zeros((CHANNELS, n))
        self._gain_temperature_c = np.full(n, np.nan)

    def set_unit(self, i: int, unit: PhotoReflectorArray) -> None:
        """Unit i becomes ``unit`` as it stands after construction (its constants, its noise generator), from
        rest: no slip, an empty sensing chain."""
        for name in ("_sensing_radius_m", "_reference_c", "_max_count", "_lsb_v", "_alpha", "_one_minus_alpha",
                     "_filtering"):
            getattr(self, name)[i] = getattr(unit, name)
        self._started[i] = False
        self._channel_rows[:, :, i] = np.array(unit._channel_rows).T
        self._half_widths[:, i] = unit._half_widths_list
        self._tempco[:, i] = unit._tempco
        self._noise_v[:, i] = unit._noise_v
        self._slip_state[:, i] = unit._slip_state
        self._filter_state[:, i] = 0.0
        self._gain_temperature_c = np.full(self.n, np.nan)  # the gains are recomputed at the next read
        self._noise.set_rng(i, unit._rng)

    def read_sample_list(self, twist_rad, tx_nm=0.0, ty_nm=0.0, temperature_c=None) -> np.ndarray:
        """:meth:`PhotoReflectorArray.read_sample_list` of every unit: (N,) twists [rad] and temperatures [°C]
        (required) in, the channel voltages [V] out, (8, N)."""
        if temperature_c is None or tx_nm or ty_nm:
            raise ValueError("a stack of units reads (N,) twists [rad] and temperatures [°C], without moments")
        v = super().read_sample_list(twist_rad, tx_nm, ty_nm, temperature_c)
        self._started[:] = True
        return v

    def _slip_sample(self, twist_rad: np.ndarray) -> np.ndarray:
        self._slip_state = clip_nan(self._slip_state, twist_rad - self._half_widths, twist_rad + self._half_widths)
        return slip_mean(self._slip_state)

    def _set_gain_temperature(self, temperature_c: np.ndarray) -> None:
        self._gain_temperature_c = np.array(temperature_c)
        self._gain = np.exp(self._tempco * (temperature_c - self._reference_c))

    def _optical_sample(self, twist_rad: np.ndarray, slipped_rad: np.ndarray) -> np.ndarray:
        return optical_voltage(twist_rad, slipped_rad, *self._channel_rows, self._gain, self._sensing_radius_m)

    def _noise_and_chain(self, v: np.ndarray) -> np.ndarray:
        noisy = v + self._noise.take(CHANNELS) * self._noise_v
        filtered = sensing_chain(self._filter_state, noisy, self._alpha, self._one_minus_alpha)
        return np.where(self._started & self._filtering, filtered, noisy)

    def _quantise(self, v: np.ndarray) -> np.ndarray:
        return np.clip(np.rint(v / self._lsb_v), 0, self._max_count) * self._lsb_v


def reference_torque(tau_nm: np.ndarray, params: TestbedParams, rng: np.random.Generator) -> np.ndarray:
    """The ATI MINI85 reading of a torque [N·m]: gain error, white noise, quantised to its resolution.

    ``round(((1 + g)·τ + n) / r)·r`` with g = ``photoreflector.reference_gain_error`` [1], n ~ N(0,
    ``reference_noise_nm``²) [N·m] and r = ``reference_resolution_nm`` [N·m]. This reading is the truth of
    the calibration rig and the thermal tests; the plant's torque and the load cell do not pass through it.

    Parameters
    ----------
    tau_nm : numpy.ndarray
        True T_z applied to the MINI85 [N·m], any shape.
    params : TestbedParams
        Parameter set; its ``photoreflector.reference_*`` fields describe the MINI85.
    rng : numpy.random.Generator
        Draws the noise (one standard normal per sample, in order).

    Returns
    -------
    numpy.ndarray
        The MINI85 reading [N·m], same shape as ``tau_nm``.
    """
    pr = params.photoreflector
    noisy = ((1.0 + pr.reference_gain_error) * np.asarray(tau_nm, dtype=float)
             + rng.standard_normal(np.shape(tau_nm)) * pr.reference_noise_nm)
    return np.rint(noisy / pr.reference_resolution_nm) * pr.reference_resolution_nm
