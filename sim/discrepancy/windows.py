"""Stribeck friction of a rigid joint from the output error of short simulated windows around its low-speed events.

The surrogate's effort balance (:mod:`sim.discrepancy.model`) cannot see the Stribeck velocity of a rigid joint:
its samples within a filter period of a stick-slip transition or a reversal do not count (the filtered effort
smears the friction's jump there), and the low-speed sliding that shows ``v_s`` happens exactly there. This module
fits the static level ``F_s`` and ``v_s`` where they show: it simulates the joint forward through short windows
around each breakaway from rest and each reversal, driven by the delivered command, and compares the simulated
position with the measured one, every other parameter at the current model's values.

Events and windows (at the log's rate)
    The stick-slip transitions and reversals are those the surrogate finds: the velocity low-passed at twice the
    analysis band, stuck below the surrogate's stick velocity (:func:`low_speed_events`). A window starts where the
    state is known exactly or well:

    - *at rest* (``v = 0``): at the latest sample of a stuck stretch around which the raw position stays within
      ``REST_STEPS`` encoder steps (plus ``REST_NOISE_SIGMAS`` x its white noise where the joint is stuck) from
      ``REST_BEFORE_S`` before to ``REST_LEAD_S`` after it. The first counts of a breakaway take milliseconds, so
      the window starts that lead before them; a joint creeping by a step or more over the span is not at rest;
    - *sliding*: ``SLIDE_LEAD_PERIODS`` filter periods before the low-speed stretch of a reversal (a stop of at
      most ``MAX_STOP_S``, or none), at least as far after the previous event, at a speed of at least
      ``MIN_START_SPEED_OF_RMS`` x the log's RMS velocity: the analysis band's velocity is good away from the
      transitions. Its error still moves the window's position by a few encoder steps, so each sliding window's
      start velocity carries a correction fitted with it (a nuisance, ``fit_initial_velocity``).

    A window ends ``post_s`` after its event (the breakaway: ``REST_LEAD_S`` after a rest start; the end of the
    low-speed stretch otherwise), or where the next event's low-speed stretch begins. At most ``max_windows``
    windows are used, spread evenly over the events in time.

Forward model, all windows at once (windows, and the parameter sets of a batch, as array dimensions)::

    m·a = u_d(t) - L(t) - F_f,     u_d the delivered command, L the other effects' loads

``u_d`` is the command through the surrogate's command path at the log's rate (:meth:`Surrogate.mapped_command`:
the drive's limit and the effects' command maps), held over each sample, delayed by the dead time and scaled by
the effort gain; each integration step (``substeps`` per sample) carries its exact mean. ``L`` is the sum of the
model's loads (:meth:`Surrogate.loads`: gravity, cogging, springs, ...) on the measured motion, interpolated from
the analysis grid, and the window's record's own zero where the model carries one (``record_offsets``). Friction
is Karnopp stick-slip: a joint at rest (``v = 0``) stays while ``|u_d - L| <= F_s``
and breaks away at ``±F_s`` from the instant the applied force crosses ``F_s`` (linear between steps, so the
motion is continuous in ``F_s``); sliding, ``F_f = sign(v)·g(v) + σ2·v`` with ``g`` the Stribeck curve
(:func:`sim.discrepancy.laws.stribeck_level`), integrated by Heun's method, the position by the step's mean
velocity; a velocity that would cross zero within a step stops at zero (the position advancing to the stop under
the step's acceleration) and breaks away again for the rest of the step if the force is beyond ``F_s``.

Fit
    The residual is the measured minus the simulated position after each sample, relative to the window's start
    (at rest the mean of the still samples before it, sliding the analysis band's position). The start-velocity
    corrections are projected out window by window (variable projection, linearised: each moves its own window
    only). The cost is unimodal in ``F_s`` at a given ``v_s`` but has a narrow valley along the trade-off between
    them, so the fit profiles it: on ``profile_points`` log-spaced values of ``v_s`` over the effect's range
    (:meth:`StribeckFriction.bounds <sim.discrepancy.effects.stribeck_friction.StribeckFriction.bounds>`), the
    ``F_s`` that minimises the cost (bracketed by a scan of levels, then Newton and bisection steps), refined in
    ``REFINE_ROUNDS`` rounds between the best point's neighbours, then polished jointly by scipy's bounded
    ``least_squares`` in (``F_s``, ``ln v_s``). The windows end soon after their events (``POST_S``): simulated
    longer, a joint sliding slowly in the Stribeck regime (which damps negatively) drifts from the measured one
    whatever the parameters, and the cost loses its shape away from the optimum.

Identifiability
    Standard errors are the sandwich (cluster-robust) ones with the windows as clusters: a window's residuals are
    strongly correlated in time, windows are independent. A profile value of ``v_s`` is *excluded* when its cost
    exceeds the fit's by more than ``exclude_z²`` x the curvature-adjusted scale (the likelihood ratio with the
    robust over the naive variance of ``ln v_s`` as the scale: the profile's ``z``). ``v_s`` is *resolved* when the
    values not excluded (the interval, its ends interpolated in ``ln v_s``) reach neither end of the range; an
    interval that reaches the lower end only bounds it from above ("v_s below X"), one that reaches the upper end
    from below; a profile flat over the whole range (no Stribeck drop: ``F_s = F_c``) bounds nothing.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np
from scipy.ndimage import maximum_filter1d, minimum_filter1d
from scipy.optimize import least_squares

from sim.discrepancy.laws import stribeck_level
from sim.discrepancy.signals import white_noise_std

if TYPE_CHECKING:
    from sim.discrepancy.model import Surrogate

MAX_WINDOWS = 40  # windows per fit, spread over the log's events
MIN_WINDOWS = 4  # a log shows its low speeds in windows with at least this many in each of its fit and held-out parts
VELOCITY_FLOOR_OF_TOP = 1e-3  # the least velocity step of the start-velocity corrections: x the log's top speed
SUBSTEPS = 2  # integration steps per sample of the log
REST_LEAD_S = 0.02  # a window at rest starts this long before the position first moves [s]
REST_BEFORE_S = 0.02  # ... and the position has been still for this long before the start [s]
REST_STEPS = 1  # still: within this many encoder steps (a creep of one step per REST_BEFORE_S + REST_LEAD_S shows)
REST_NOISE_SIGMAS = 6.0  # ... plus this many standard deviations of the position's white noise
SLIDE_LEAD_PERIODS = 1.0  # a sliding window starts this many filter periods before its low-speed stretch
MIN_START_SPEED_OF_RMS = 0.1  # ... at a speed of at least this x the log's RMS velocity, and its low-speed
MAX_STOP_S = 0.04  # stretch lasts at most this long [s] (a longer stop is a window at rest, or none)
POST_S = 0.03  # windows end this long after their event [s] ...
MIN_POST_S = 0.015  # ... and one with less than this after its event is not used [s]
PROFILE_POINTS = 9  # log-spaced Stribeck velocities of the profile
PROFILE_ITERATIONS = 8  # at most this many steps in F_s per profile point, ...
PROFILE_TOLERANCE = 1e-4  # ... until the step is below this x the breakaway scale (F_c)
BREAKAWAY_SCAN = (0.0, 0.2, 0.4, 0.65, 0.95, 1.3, 1.7)  # levels scanned for the brackets: F_c + this x the
# breakaway scale (F_c, or BREAKAWAY_SCALE_OF_EFFORT x the log's largest effort without a Coulomb level)
BREAKAWAY_SCALE_OF_EFFORT = 0.05
EXCLUDE_Z = 3.0  # a Stribeck velocity is excluded at this z of the profile (module docstring)
STEP_BREAKAWAY = 1e-3  # finite-difference steps: x the breakaway scale (F_c) ...
STEP_LOG_VELOCITY = 1e-2  # ... in ln v_s ...
STEP_INITIAL_VELOCITY = 1e-3  # ... x the window's start speed
MAX_NFEV = 12  # the least-squares polish from the profile's best point: at most this many evaluations ...
POLISH_TOLERANCE = 1e-6  # ... and its relative tolerances in the parameters and the cost
REFINE_ROUNDS = 3  # rounds of the profile's refinement between the best point's neighbours ...
REFINE_POINTS = 4  # ... each of this many points
REFINE_MARGIN = 0.02  # ... their breakaway brackets widened by this x the breakaway scale


@dataclass(frozen=True)
class Windows:
    """The windows of a log: what the forward model needs and the measured positions it is compared with.

    Arrays have one row per window; sample columns run over the longest window (``mask`` marks each window's
    own samples). Units [hinge | slide]: N·m | N, rad | m, rad/s | m/s.
    """

    start: np.ndarray  # full-rate index of each window's start
    event: np.ndarray  # full-rate index of each window's event (breakaway or the end of its low-speed stretch)
    at_rest: np.ndarray  # bool: the window starts stuck (v = 0)
    forcing: np.ndarray  # u_d - L per integration step, with one step before the start [N·m | N]
    measured: np.ndarray  # measured position after each sample, relative to the start [rad | m]
    mask: np.ndarray  # bool: a sample of the window
    velocity0: np.ndarray  # start velocity [rad/s | m/s] (0 at rest)
    step: float  # integration step [s]
    substeps: int
    events: int  # events found in the log (before the cap)

    @property
    def count(self) -> int:
        return len(self.start)


@dataclass(frozen=True)
class WindowFit:
    """Breakaway level and Stribeck velocity fitted on the windows around a rigid joint's low-speed events.

    Attributes
    ----------
    breakaway, stribeck_velocity : float
        The fitted F_s [N·m | N] and v_s [rad/s | m/s].
    breakaway_se, stribeck_velocity_se : float
        Their standard errors (sandwich, windows as clusters; inf where the cost does not curve).
    resolved : bool
        Whether the windows bound v_s on both sides (see the module docstring).
    interval : (float, float)
        The Stribeck velocities the windows do not exclude [rad/s | m/s] (an end of the effect's range where they
        reach it).
    bound : str
        What the windows say of v_s when it is not resolved ("v_s below X", "v_s above X", "v_s not bounded
        within X-Y"; empty if resolved).
    profile_velocity, profile_cost, profile_breakaway : ndarray
        The profile, v_s ascending: the grid over the effect's range, the refinement's points and the fit; the
        cost there with F_s (and the start-velocity corrections) minimised [rad² | m²]; that F_s [N·m | N].
    profile_z : ndarray
        The profile's z: the square root of each point's cost rise over the fit, over the effective residual
        variance (module docstring) [1].
    cost : float
        Sum of the squared position residuals at the fit, the corrections projected out [rad² | m²].
    rms : float
        RMS of those residuals [rad | m].
    windows, events : int
        Windows used; events found in the log.
    at_rest : int
        Windows that start at rest.
    evaluations : int
        Forward simulations of all windows (each a batch of parameter sets).
    seconds : float
        Wall time of the fit.
    """

    breakaway: float
    stribeck_velocity: float
    breakaway_se: float
    stribeck_velocity_se: float
    resolved: bool
    interval: tuple[float, float]
    bound: str
    profile_velocity: np.ndarray = field(repr=False)
    profile_cost: np.ndarray = field(repr=False)
    profile_breakaway: np.ndarray = field(repr=False)
    profile_z: np.ndarray = field(repr=False)
    cost: float = math.nan
    rms: float = math.nan
    windows: int = 0
    events: int = 0
    at_rest: int = 0
    evaluations: int = 0
    seconds: float = 0.0

    def to_dict(self) -> dict:
        return {"breakaway": self.breakaway, "stribeck_velocity": self.stribeck_velocity,
                "breakaway_se": self.breakaway_se, "stribeck_velocity_se": self.stribeck_velocity_se,
                "resolved": self.resolved, "interval": list(self.interval), "bound": self.bound,
                "profile": {"stribeck_velocity": self.profile_velocity.tolist(), "cost": self.profile_cost.tolist(),
                            "breakaway": self.profile_breakaway.tolist(), "z": self.profile_z.tolist()},
                "cost": self.cost, "rms": self.rms, "windows": self.windows, "events": self.events,
                "at_rest": self.at_rest, "evaluations": self.evaluations, "seconds": self.seconds}


# ---------------------------------------------------------------------------------------------------- events


def low_speed_events(model: Surrogate) -> list[tuple[int, int]]:
    """The log's low-speed events as (first sample of the low-speed stretch, first moving sample after it), full
    rate: every stuck stretch followed by motion (a breakaway, or a reversal with a stop), and every sign change of
    the moving velocity (a reversal without a stop, the stretch one sample long). Stuck and moving as the surrogate
    finds them (:attr:`Surrogate.transition_velocity`, below its stick velocity)."""
    v = model.transition_velocity
    stuck = np.abs(v) < model.stick_velocity
    return _events(v, stuck)


def _events(v: np.ndarray, stuck: np.ndarray) -> list[tuple[int, int]]:
    """:func:`low_speed_events` of the full-rate transition velocity ``v`` and its stuck samples."""
    n = len(v)
    edges = np.flatnonzero(stuck[1:] != stuck[:-1]) + 1
    starts = np.r_[0, edges]
    ends = np.r_[edges, n]
    events = [(int(a), int(b)) for a, b in zip(starts, ends, strict=True) if stuck[a] and b < n]
    moving = np.flatnonzero(~stuck)
    flips = moving[1:][(np.sign(v[moving[1:]]) != np.sign(v[moving[:-1]])) & (np.diff(moving) == 1)]
    events += [(int(i), int(i)) for i in flips]
    return sorted(events, key=lambda e: e[1])


def _segment_of(model: Surrogate) -> np.ndarray:
    """Which joined log each full-rate sample belongs to."""
    n = len(model.data.t_full)
    out = np.zeros(n, dtype=int)
    for i, (a, b) in enumerate(model.data.bounds):
        out[a:b] = i
    return out


def _part_mask(model: Surrogate, part: str) -> np.ndarray:
    """Full-rate samples of the chosen part ('fit', 'held' or 'all': both, guards excluded)."""
    d = model.data
    masks = {"fit": d.fit, "held": d.held, "all": d.fit | d.held}
    if part not in masks:
        raise ValueError(f"part = {part!r}; expected one of {tuple(masks)}")
    on_grid = np.searchsorted(d.grid, np.arange(len(d.t_full)), side="right") - 1
    return masks[part][on_grid]


def find_windows(model: Surrogate, theta: dict[str, float], *, max_windows: int = MAX_WINDOWS,
                 substeps: int = SUBSTEPS, post_s: float = POST_S, part: str = "all") -> Windows:
    """The windows of ``model``'s log around its low-speed events, with the forward model's forcing at ``theta``
    (module docstring). ``part``: the windows lie in the fit part, the held-out part, or either ('all')."""
    if model.testbed:
        raise ValueError("the windowed Stribeck fit is for a rigid joint (the testbed's friction is LuGre)")
    d = model.data
    n, dt = len(d.t_full), d.dt
    y = d.position_full
    band_period = 1.0 / model.config.filter_cutoff_hz
    lead_rest, before_rest = int(round(REST_LEAD_S / dt)), max(1, int(round(REST_BEFORE_S / dt)))
    lead_slide = int(round(SLIDE_LEAD_PERIODS * band_period / dt))
    post, min_post = int(round(post_s / dt)), max(1, int(round(MIN_POST_S / dt)))
    max_stop = int(round(MAX_STOP_S / dt))
    # still: the raw position within REST_STEPS encoder steps from REST_BEFORE_S before to REST_LEAD_S after
    span = before_rest + lead_rest + 1
    origin = (before_rest - lead_rest) // 2  # centre the filters' footprint on [i - before, i + lead]
    v = model.transition_velocity
    stuck = np.abs(v) < model.stick_velocity
    # the encoder's noise where the joint is still (a moving joint's quantisation is no noise of a still one)
    noise = white_noise_std(y[stuck]) if stuck.sum() > 8 else 0.0
    tolerance = REST_STEPS * max(d.position_resolution, 1e-12) * (1 + 1e-9) + REST_NOISE_SIGMAS * noise
    still = (maximum_filter1d(y, span, origin=origin, mode="nearest")
             - minimum_filter1d(y, span, origin=origin, mode="nearest")) <= tolerance
    allowed = _part_mask(model, part)
    segment = _segment_of(model)
    speed_floor = MIN_START_SPEED_OF_RMS * float(np.sqrt(np.mean(d.velocity_full ** 2)))
    events = _events(v, stuck)
    candidates: list[tuple[int, int, int, bool]] = []  # (start, event, end, at rest)
    for k, (a, b) in enumerate(events):
        previous = events[k - 1][1] if k else 0
        following = events[k + 1][0] if k + 1 < len(events) else n - 1
        start = None
        if b > a:  # a stuck stretch: the latest start at rest within it (or a little after its detected end)
            look = np.flatnonzero(still[a:min(b + post // 2, n - lead_rest - 1)])
            if len(look):
                start = a + int(look[-1])
                event = start + lead_rest
                rest = True
        if start is None:
            start, event, rest = a - lead_slide, b, False
            if (start - lead_slide < previous or start < 0 or abs(d.velocity_full[start]) < speed_floor
                    or b - a > max_stop):
                continue
        end = min(event + post, following, n - 1)
        if end - event < min_post or not allowed[start:end + 1].all() or segment[start] != segment[end]:
            continue
        candidates.append((start, event, end, rest))
    if not candidates:
        raise ValueError("the log has no low-speed event with a window around it (a breakaway from rest, or a "
                         "reversal after sliding)")
    if len(candidates) > max_windows:
        pick = np.unique(np.round(np.linspace(0, len(candidates) - 1, max_windows)).astype(int))
        candidates = [candidates[i] for i in pick]
    return _assemble(model, theta, candidates, substeps, len(events))


def _assemble(model: Surrogate, theta: dict[str, float], candidates: list[tuple[int, int, int, bool]],
              substeps: int, events: int) -> Windows:
    """The windows' arrays (forcing per step, measured positions) for ``candidates`` (start, event, end, at
    rest)."""
    d = model.data
    n, dt = len(d.t_full), d.dt
    y = d.position_full
    starts, event, ends = (np.array([c[i] for c in candidates]) for i in range(3))
    rest = np.array([c[3] for c in candidates])
    lengths = ends - starts  # samples compared after the start
    width = int(lengths.max())
    h = dt / substeps
    # delivered effort: the mapped command held over (t_k - dt, t_k], centred where the surrogate centres it, then
    # delayed; each step's exact mean from its cumulative integral
    held = theta["effort_gain"] * model.mapped_command(theta)
    knots = np.r_[d.t_full[0] - dt, d.t_full]
    integral = np.r_[0.0, np.cumsum(held) * dt]
    shift = theta["delay"] + 0.5 * (d.hold_s - dt)
    steps = np.arange(-1, width * substeps + 1) * h  # step boundaries relative to the start, one step before it
    bounds = d.t_full[starts][:, None] + steps[None, :] - shift
    delivered = np.diff(np.interp(bounds, knots, integral), axis=1) / h
    middle = d.t_full[starts][:, None] + steps[None, :-1] + 0.5 * h
    loads = model.loads(theta)
    load = np.interp(middle, d.t, loads) if np.ndim(loads) else np.full(middle.shape, float(loads))
    zeros = model.record_offsets(theta).get("effort")
    if zeros:  # each record's own zero of the logged effort (the effect record_offsets)
        load = load + np.asarray(zeros)[_segment_of(model)[starts]][:, None]
    columns = np.arange(1, width + 1)
    mask = columns[None, :] <= lengths[:, None]
    index = np.minimum(starts[:, None] + columns[None, :], n - 1)
    filtered = d.filt_full(y)
    reference = np.empty(len(starts))
    before = max(1, int(round(REST_BEFORE_S / dt)))
    for w, (s, r) in enumerate(zip(starts, rest, strict=True)):
        reference[w] = float(np.mean(y[max(s - before, 0):s + 1])) if r else float(filtered[s])
    measured = np.where(mask, y[index] - reference[:, None], 0.0)
    velocity0 = np.where(rest, 0.0, d.velocity_full[starts])
    return Windows(start=starts, event=event, at_rest=rest, forcing=delivered - load, measured=measured, mask=mask,
                   velocity0=velocity0, step=h, substeps=substeps, events=events)


# ---------------------------------------------------------------------------------------------- forward model


def simulate(windows: Windows, inertia: float, coulomb: float, viscous: float, breakaway: np.ndarray,
             stribeck_velocity: np.ndarray, velocity0: np.ndarray | None = None) -> np.ndarray:
    """Positions after each sample of every window, relative to its start [rad | m], for a batch of parameter
    sets: ``breakaway`` and ``stribeck_velocity`` of shape (B,) or (B, W) (a value per window), ``velocity0`` (B, W)
    (default: the windows' own).
    Returns (B, W, samples). Karnopp stick-slip (module docstring); the joint is stuck while its velocity is
    exactly zero (a stop sets it to zero, a breakaway away from it).
    """
    fs, vs = (np.asarray(x, dtype=float) for x in (breakaway, stribeck_velocity))
    fs = fs[:, None] if fs.ndim == 1 else fs  # (B, 1) or (B, W)
    vs = vs[:, None] if vs.ndim == 1 else vs
    shape = (np.broadcast_shapes(fs.shape, vs.shape)[0], windows.count)
    v = np.array(np.broadcast_to(windows.velocity0 if velocity0 is None else velocity0, shape), dtype=float)
    h, substeps = windows.step, windows.substeps
    width = windows.measured.shape[1]
    inv_m = 1.0 / inertia
    damping = viscous * inv_m
    # sliding: a = f/m - sign(v)·g(v)/m - σ2·v/m, g(v) = F_c + (F_s - F_c)·exp(curve·v²) (model.stribeck_level)
    curve = np.broadcast_to(-1.0 / (vs * vs), shape).copy()
    drop = np.broadcast_to((stribeck_level(np.zeros(1), coulomb, fs, vs) - coulomb) * inv_m, shape).copy()
    level = coulomb * inv_m
    # breaking away, precomputed for every step (step-major): the force beyond the static level, the acceleration
    # it gives, and the part of the step after the applied force crossed it (linear between steps; the whole step
    # if it was beyond before)
    force = np.moveaxis(windows.forcing, 1, 0)[:, None, :]  # (steps + 1, 1, W)
    excess = np.abs(force) - fs[None]  # (steps + 1, B, W)
    previous, current = excess[:-1], excess[1:]
    with np.errstate(divide="ignore", invalid="ignore"):
        part = np.where(previous < 0.0, current / (current - previous), 1.0)
    breaking = (current > 0.0).astype(float)
    tau = breaking * h * np.clip(part, 0.0, 1.0)  # 0: stays stuck
    force = force[1:]
    drive = breaking * (force - np.sign(force) * fs[None]) * inv_m
    half_drive = 0.5 * drive
    pushing = np.ascontiguousarray(np.broadcast_to(force * inv_m, tau.shape))
    q = np.zeros(shape)
    out = np.empty((width,) + shape)
    a, a_end, v_end, work, sign = (np.empty(shape) for _ in range(5))

    def acceleration(j: int, speed: np.ndarray, into: np.ndarray) -> None:
        """The sliding acceleration at ``speed`` in step j, into ``into`` (in place: the loop's hot path)."""
        np.multiply(speed, speed, out=work)
        np.multiply(work, curve, out=work)
        np.exp(work, out=work)
        np.multiply(work, drop, out=work)
        np.add(work, level, out=work)
        np.multiply(work, np.sign(speed, out=sign), out=work)
        np.subtract(pushing[j], work, out=into)
        into -= damping * speed

    with np.errstate(divide="ignore", invalid="ignore"):
        for k in range(width):
            for s in range(substeps):
                j = k * substeps + s
                stuck = v == 0.0
                # sliding, by Heun's method (the mean of the accelerations at the step's start and at its Euler
                # end); the position by the step's mean velocity
                acceleration(j, v, a)
                np.multiply(a, h, out=v_end)
                v_end += v
                moving = v * v_end > 0.0
                acceleration(j, v_end, a_end)
                a_end += a
                a_end *= 0.5 * h
                a_end += v
                np.copyto(v_end, a_end, where=moving)
                stop = v * v_end <= 0.0  # stuck, or a velocity that would cross zero: it stops at zero ...
                t_move = np.where(stuck, 0.0, np.where(stop, -v / a, h))
                # ... and breaks away for the rest of the step if the force is beyond the static level; a stuck
                # joint breaks away for the part of the step after the force crossed it (or stays)
                free = np.where(stuck, tau[j], (h - t_move) * breaking[j])
                q += 0.5 * (v + np.where(stop, 0.0, v_end)) * t_move + half_drive[j] * free * free
                v = np.where(stop, drive[j] * free, v_end)
            out[k] = q
    return np.moveaxis(out, 0, 2)


# ------------------------------------------------------------------------------------------------------- fit


class _Problem:
    """The windows' position residuals as a function of (F_s, ln v_s), the sliding windows' start-velocity
    corrections projected out, for batches of parameter points with finite-difference Jacobians.

    Each correction moves its own window only: the residual and the Jacobian in (F_s, ln v_s) are taken orthogonal
    to its column, window by window (variable projection, linearised about the windows' own start velocities). The
    cost is the sum of the squared projected residuals [rad² | m²].
    """

    def __init__(self, windows: Windows, theta: dict[str, float], level_scale: float, velocity_floor: float,
                 nuisance: bool) -> None:
        self.windows = windows
        self.inertia, self.coulomb, self.viscous = theta["inertia"], theta["coulomb"], theta["viscous"]
        self.level_scale = level_scale
        self.sliding = np.flatnonzero(~windows.at_rest) if nuisance else np.zeros(0, dtype=int)
        self.dv_step = STEP_INITIAL_VELOCITY * np.maximum(np.abs(windows.velocity0[self.sliding]), velocity_floor)
        self.f_step = STEP_BREAKAWAY * level_scale
        self.evaluations = 0
        self.window_of_row = np.repeat(np.arange(windows.count), windows.mask.sum(axis=1))

    def evaluate(self, fs: np.ndarray, log_vs: np.ndarray, columns: int = 0) -> dict[str, np.ndarray]:
        """At P points (F_s, ln v_s), from one batched simulation: the projected residual ``rp`` (P, W, samples)
        [rad | m], its cost per window ``window_costs`` (P, W) and the Jacobian ``jp`` (P, columns, W, samples) in
        the first ``columns`` of (F_s, ln v_s)."""
        fs, log_vs = np.asarray(fs, dtype=float), np.asarray(log_vs, dtype=float)
        p, n = len(fs), len(self.sliding)
        steps = [(self.f_step, 0.0), (0.0, STEP_LOG_VELOCITY)][:columns]
        lanes = [(0.0, 0.0)] + steps + ([(0.0, 0.0)] if n else [])  # the last: every correction stepped
        w = self.windows
        v0 = np.repeat(w.velocity0[None, :], len(lanes) * p, axis=0)
        if n:
            v0[-p:, self.sliding] += self.dv_step
        self.evaluations += 1
        q = simulate(w, self.inertia, self.coulomb, self.viscous, np.concatenate([fs + df for df, _ in lanes]),
                     np.exp(np.concatenate([log_vs + dl for _, dl in lanes])), v0)
        r = np.where(w.mask[None], w.measured[None] - q, 0.0).reshape(len(lanes), p, *w.measured.shape)
        base = r[0].copy()
        jac = np.zeros((p, columns) + w.measured.shape)
        for i, (df, dl) in enumerate(steps):
            jac[:, i] = (r[1 + i] - r[0]) / (df or dl)
        if n:
            sl = self.sliding
            jd = (r[-1][:, sl] - r[0][:, sl]) / self.dv_step[None, :, None]  # (P, N, samples)
            dd = np.sum(jd * jd, axis=-1)
            dd = np.where(dd > 0.0, dd, np.inf)
            base[:, sl] -= jd * (np.sum(jd * base[:, sl], axis=-1) / dd)[..., None]
            if columns:
                jac[:, :, sl] -= jd[:, None] * (np.sum(jd[:, None] * jac[:, :, sl], axis=-1) / dd[:, None])[..., None]
        return {"rp": base, "jp": jac, "window_costs": np.sum(base * base, axis=-1)}

    def profile(self, log_vs: np.ndarray, start: np.ndarray, lower: np.ndarray, upper: np.ndarray
                ) -> tuple[np.ndarray, np.ndarray]:
        """For each ln v_s of ``log_vs``, the F_s within its bracket [lower, upper] (the cost is unimodal in it there)
        that minimises the cost: Newton steps on the cost's gradient, bisection where a step would leave the
        bracket, which shrinks by the gradient's sign, until the step or the bracket is below PROFILE_TOLERANCE x
        the breakaway scale. Returns (F_s (P,), cost (P,))."""
        fs, lo, hi = (np.array(x, dtype=float) for x in (start, lower, upper))
        best_fs, best_cost = fs.copy(), np.full(len(fs), np.inf)
        tolerance = PROFILE_TOLERANCE * self.level_scale
        active = np.ones(len(fs), dtype=bool)
        for _ in range(PROFILE_ITERATIONS):
            i = np.flatnonzero(active)
            out = self.evaluate(fs[i], log_vs[i], columns=1)
            cost = out["window_costs"].sum(axis=1)
            better = cost < best_cost[i]
            best_fs[i[better]], best_cost[i[better]] = fs[i[better]], cost[better]
            jp, rp = out["jp"][:, 0], out["rp"]
            a = np.sum(jp * jp, axis=(1, 2))
            g = np.sum(jp * rp, axis=(1, 2))  # half the cost's derivative in F_s
            hi[i] = np.where(g > 0.0, np.minimum(hi[i], fs[i]), hi[i])
            lo[i] = np.where(g <= 0.0, np.maximum(lo[i], fs[i]), lo[i])
            newton = fs[i] - g / np.where(a > 0.0, a, np.inf)
            following = np.where((a > 0.0) & (newton > lo[i]) & (newton < hi[i]), newton, 0.5 * (lo[i] + hi[i]))
            active[i] = (np.abs(following - fs[i]) > tolerance) & (hi[i] - lo[i] > tolerance)
            fs[i] = following
            if not active.any():
                break
        return best_fs, best_cost


def _sandwich(jac: np.ndarray, r: np.ndarray, cluster: np.ndarray, clusters: int) -> tuple[np.ndarray, np.ndarray]:
    """(the naive covariance factor (JᵀJ)⁻¹, the cluster-robust covariance (JᵀJ)⁻¹·Σ_c s_c s_cᵀ·(JᵀJ)⁻¹ with
    s_c = J_cᵀ r_c) of a least-squares fit; a parameter whose column is zero (the cost does not depend on it) has
    inf on its diagonal in both."""
    norms = np.sqrt(np.sum(jac * jac, axis=0))
    live = norms > 1e-12 * max(float(norms.max(initial=0.0)), 1e-300)
    k = jac.shape[1]
    bread, robust = np.full((k, k), np.nan), np.full((k, k), np.nan)
    np.fill_diagonal(bread, np.inf)
    np.fill_diagonal(robust, np.inf)
    if live.any():
        j = jac[:, live]
        inverse = np.linalg.pinv(j.T @ j)
        scores = np.zeros((clusters, j.shape[1]))
        np.add.at(scores, cluster, j * r[:, None])
        index = np.ix_(live, live)
        bread[index] = inverse
        robust[index] = inverse @ (scores.T @ scores) @ inverse
    return bread, robust


def fit_stribeck(model: Surrogate, theta: dict[str, float], velocity_range: tuple[float, float],
                 breakaway_high: float, *, max_windows: int = MAX_WINDOWS, substeps: int = SUBSTEPS,
                 post_s: float = POST_S, part: str = "all", fit_initial_velocity: bool = True,
                 exclude_z: float = EXCLUDE_Z, profile_points: int = PROFILE_POINTS) -> WindowFit:
    """Fit a rigid joint's breakaway level F_s and Stribeck velocity v_s by the output error of windows simulated
    around its low-speed events (module docstring), every other parameter at ``theta``'s values (a full parameter
    vector of the surrogate: its inertia, Coulomb and viscous levels, command path and effects' loads).

    ``part`` chooses the windows' part of the log ('fit', 'held' or 'all'); F_s is searched from the Coulomb level
    up to ``breakaway_high``, v_s over ``velocity_range`` [rad/s | m/s] (the effect's bounds).

    Raises
    ------
    ValueError
        The testbed, or a log without a usable low-speed event.
    """
    start_time = time.perf_counter()
    windows = find_windows(model, theta, max_windows=max_windows, substeps=substeps, post_s=post_s, part=part)
    v_low, v_high = velocity_range
    f_low = theta["coulomb"]
    unit = f_low if f_low > 0 else BREAKAWAY_SCALE_OF_EFFORT * model.scale.effort
    f_high = max(breakaway_high, f_low + unit)
    problem = _Problem(windows, theta, unit, v_low, fit_initial_velocity)
    grid = np.linspace(math.log(v_low), math.log(v_high), profile_points)
    # the profile on the grid: for each v_s the F_s of a scan of levels that fits best, bracketed by its neighbours
    levels = np.unique(np.clip(f_low + unit * np.array(BREAKAWAY_SCAN), f_low, f_high))
    costs = problem.evaluate(np.repeat(levels, len(grid)), np.tile(grid, len(levels)))["window_costs"].sum(axis=1)
    k = np.argmin(costs.reshape(len(levels), len(grid)), axis=0)
    upper_fs = np.where(k + 1 < len(levels), levels[np.minimum(k + 1, len(levels) - 1)], f_high)
    grid_fs, grid_cost = problem.profile(grid, levels[k], levels[np.maximum(k - 1, 0)], upper_fs)
    # refined between the best point's neighbours (the profile is unimodal there): rounds of equally spaced points,
    # each F_s bracketed by its neighbours' (the valley's F_s falls as v_s rises)
    points_v, points_fs, points_cost = list(grid), list(grid_fs), list(grid_cost)
    for _ in range(REFINE_ROUNDS):
        order = np.argsort(points_v)
        pv, pf, pc = (np.asarray(x)[order] for x in (points_v, points_fs, points_cost))
        i = int(np.argmin(pc))
        lo, hi = max(i - 1, 0), min(i + 1, len(pv) - 1)
        inner = np.linspace(pv[lo], pv[hi], REFINE_POINTS + 2)[1:-1]
        guess = np.interp(inner, pv[lo:hi + 1], pf[lo:hi + 1])
        margin = REFINE_MARGIN * unit
        refined_fs, refined_cost = problem.profile(
            inner, guess, np.clip(np.minimum(guess, pf[hi]) - margin, f_low, f_high),
            np.clip(np.maximum(guess, pf[lo]) + margin, f_low, f_high))
        points_v += list(inner)
        points_fs += list(refined_fs)
        points_cost += list(refined_cost)
    best = int(np.argmin(points_cost))
    # the joint polish in (F_s, ln v_s)
    mask = windows.mask
    cache: dict[bytes, dict[str, np.ndarray]] = {}

    def evaluate(x: np.ndarray) -> dict[str, np.ndarray]:
        key = x.tobytes()
        if key not in cache:
            cache.clear()
            cache[key] = problem.evaluate(x[:1], x[1:], columns=2)
        return cache[key]

    lower, upper = np.array([f_low, grid[0]]), np.array([f_high, grid[-1]])
    inside = 1e-9 * (upper - lower)
    x0 = np.clip([points_fs[best], points_v[best]], lower + inside, upper - inside)
    solution = least_squares(lambda x: evaluate(x)["rp"][0][mask], x0,
                             jac=lambda x: np.moveaxis(evaluate(x)["jp"][0], 0, -1)[mask], bounds=(lower, upper),
                             x_scale=np.array([unit, 1.0]), max_nfev=MAX_NFEV, method="trf",
                             xtol=POLISH_TOLERANCE, ftol=POLISH_TOLERANCE)
    x = solution.x if float(evaluate(solution.x)["window_costs"].sum()) <= points_cost[best] else x0
    out = evaluate(x)
    cost = float(out["window_costs"].sum())
    bread, robust = _sandwich(np.moveaxis(out["jp"][0], 0, -1)[mask], out["rp"][0][mask], problem.window_of_row,
                              windows.count)
    fs, vs = float(x[0]), float(math.exp(x[1]))
    se_fs, se_lv = (math.sqrt(robust[i, i]) if robust[i, i] >= 0.0 else math.inf for i in (0, 1))
    # the profile's z: the likelihood ratio over the effective residual variance, the robust over the naive
    # covariance factor of ln v_s (of F_s where the cost does not depend on v_s; the naive variance without either)
    ratios = [robust[i, i] / bread[i, i] for i in (1, 0)
              if math.isfinite(bread[i, i]) and bread[i, i] > 0.0 and robust[i, i] > 0.0]
    variance = ratios[0] if ratios else cost / max(int(mask.sum()) - 2, 1)
    points_v.append(float(x[1]))  # the fit is the profile's lowest point
    points_fs.append(fs)
    points_cost.append(cost)
    order = np.argsort(points_v)
    pv, pf, pc = (np.asarray(x)[order] for x in (points_v, points_fs, points_cost))
    rise = pc - cost
    z = np.sign(rise) * np.sqrt(np.abs(rise) / max(variance, 1e-300))
    interval, resolved, bound = _interval(pv, z, exclude_z, x[1], model.rig.joint)
    return WindowFit(
        breakaway=fs, stribeck_velocity=vs, breakaway_se=se_fs, stribeck_velocity_se=vs * se_lv,
        resolved=resolved, interval=interval, bound=bound, profile_velocity=np.exp(pv), profile_cost=pc,
        profile_breakaway=pf, profile_z=z, cost=cost, rms=math.sqrt(cost / max(int(mask.sum()), 1)),
        windows=windows.count, events=windows.events, at_rest=int(windows.at_rest.sum()),
        evaluations=problem.evaluations, seconds=time.perf_counter() - start_time)


def _interval(log_vs: np.ndarray, z: np.ndarray, limit: float, best: float, joint: str
              ) -> tuple[tuple[float, float], bool, str]:
    """(the v_s interval not excluded, resolved, what bounds v_s) from the profile's points (ln v_s ascending, their
    z): the contiguous run of points with z <= limit around the fit, its ends where z crosses the limit (linear in
    ln v_s between points), or the profile's ends."""
    unit = "m/s" if joint == "slide" else "rad/s"
    inside = z <= limit
    k = int(np.argmin(np.abs(log_vs - best)))
    if not inside[k]:
        inside = inside.copy()
        inside[k] = True
    lo = hi = k
    while lo > 0 and inside[lo - 1]:
        lo -= 1
    while hi < len(log_vs) - 1 and inside[hi + 1]:
        hi += 1

    def crossing(i: int, j: int) -> float:  # between point i (inside) and j (outside)
        share = (limit - z[i]) / (z[j] - z[i]) if z[j] != z[i] else 0.5
        return math.exp(log_vs[i] + min(max(share, 0.0), 1.0) * (log_vs[j] - log_vs[i]))

    low_end, high_end = lo == 0, hi == len(log_vs) - 1
    low = math.exp(log_vs[0]) if low_end else crossing(lo, lo - 1)
    high = math.exp(log_vs[-1]) if high_end else crossing(hi, hi + 1)
    if low_end and high_end:
        return (low, high), False, f"v_s not bounded within {low:.3g}-{high:.3g} {unit}"
    if low_end:
        return (low, high), False, f"v_s below {high:.3g} {unit}"
    if high_end:
        return (low, high), False, f"v_s above {low:.3g} {unit}"
    return (low, high), True, ""


def window_counts(model: Surrogate, theta: dict[str, float]) -> dict[str, int]:
    """The windows of the fit and the held-out part ({'fit': n, 'held': n}; 0 where a part has none)."""
    counts = {}
    for part in ("fit", "held"):
        try:
            counts[part] = find_windows(model, theta, part=part).count
        except ValueError:
            counts[part] = 0
    return counts


# ------------------------------------------------------------------------------------------ the held-out channel

LOW_SPEED = "low_speed"  # the residual channel of the windows' position error [rad | m]


def position_error(model: Surrogate, theta: dict[str, float], part: str = "held") -> tuple[np.ndarray, int] | None:
    """The windows' position error at ``theta`` on the analysis grid: for each grid sample, the RMS of the
    measured minus the simulated position over the window samples that fall on it (the sliding windows' start
    velocities corrected as in the fit), NaN where no window sample does [rad | m]; and the number of windows of
    ``part``. None where the part has fewer than MIN_WINDOWS.

    The static level is the surrogate's (:meth:`Surrogate.static_level`: a rig with one dry level breaks away at
    its Coulomb level); the channel lets an effect's evidence at the low-speed events, which the effort balance
    leaves out, be scored like the balance's own channels."""
    try:
        windows = find_windows(model, theta, part=part)
    except ValueError:
        return None
    if windows.count < MIN_WINDOWS:
        return None
    scale = theta["coulomb"] if theta["coulomb"] > 0 else BREAKAWAY_SCALE_OF_EFFORT * model.scale.effort
    velocity_floor = VELOCITY_FLOOR_OF_TOP * model.scale.velocity  # the corrections' least step; a model without a
    # Stribeck drop takes it as its (irrelevant) Stribeck velocity
    problem = _Problem(windows, theta, scale, velocity_floor, True)
    static = model.static_level(theta)
    velocity = theta["stribeck_velocity"] if static > theta["coulomb"] else velocity_floor
    r = problem.evaluate(np.array([static]), np.array([math.log(velocity)]))["rp"][0]
    d = model.data
    index = (windows.start[:, None] + np.arange(1, windows.measured.shape[1] + 1)[None, :])[windows.mask]
    cell = np.minimum(index // d.grid_step, len(d.grid) - 1)
    squares = np.bincount(cell, weights=r[windows.mask] ** 2, minlength=len(d.grid))
    counts = np.bincount(cell, minlength=len(d.grid))
    with np.errstate(invalid="ignore", divide="ignore"):
        out = np.where(counts > 0, np.sqrt(squares / np.maximum(counts, 1)), np.nan)
    return out, windows.count
