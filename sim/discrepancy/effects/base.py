"""What an effect of the library is: its parameters, bounds, model term, MuJoCo realisation and diagnostics.

An effect is a named physical mechanism with a few parameters (each one entry of the surrogate's parameter
vector ``theta``, SI units). One subclass of :class:`Effect` per module of :mod:`sim.discrepancy.effects` holds
all of it:

``params``           the parameters: unit, description, the value that switches the effect off (``neutral``),
                     the rig field that carries it (a rig with that field has the effect natively: a finding is
                     then a *re-fit* of the rig's value), the range a rig file may state (``valid``)
``bounds``           the range a fit may use, scaled to the rig and the log (:class:`Scale`): never fixed
                     absolute numbers, so a rig of any size is fitted within its own scale
``command``          a memoryless map of the effort command (before the drive's dead time)
``load``             the effort the joint needs for the effect [N·m | N], added to the model's balance
``sensor``           what the effect adds to the torque sensor's reading [N·m]
``starts``           starting values of a fit (grids, or linear sub-problems solved directly)
``fit``              a fit of its own where the surrogate's least squares cannot see the effect (Stribeck)
``identifiable``     whether the log can reveal it, and if not, why
``simpler``          the simpler law its fitted parameters make it over the span of the log, if any
``signature``        the signal whose correlation with the residual points at it (diagnostics)
``realise``          how the MuJoCo simulation carries it (:class:`Realisation`)
``draw``             the range the synthetic generator draws a hidden value from

The baseline physics (the testbed's LuGre gear friction, load-dependent friction, backlash, dead time, the rigid
joint's friction curve) is evaluated by :mod:`sim.discrepancy.model` from the entries of ``theta`` that the
friction, delay and backlash effects own; those effects add no term of their own.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, ClassVar

import numpy as np

if TYPE_CHECKING:
    from sim.discrepancy.model import Surrogate
    from sim.discrepancy.rig import Rig

TESTBED, HINGE, SLIDE = "testbed", "hinge", "slide"  # kinds of rig: the GIM8108 testbed, rigid hinge, rigid slide
ALL_RIGS = frozenset({TESTBED, HINGE, SLIDE})
RIGID_RIGS = frozenset({HINGE, SLIDE})
TWO_PI = 2.0 * math.pi


def rig_kind(rig: Rig) -> str:
    """'testbed', 'hinge' (a rigid hinge) or 'slide' (a rigid slide)."""
    return TESTBED if rig.model == "testbed" else rig.joint


@dataclass(frozen=True)
class Param:
    """One parameter of an effect.

    Attributes
    ----------
    key : str
        Its entry in ``theta``.
    unit_hinge, unit_slide : str
        Unit on a rotational and on a linear joint.
    description : str
        What it is, for reports.
    neutral : float or None
        The value at which the effect is absent (None: no such value, e.g. a period or a phase).
    default : float
        The value a rig without the effect carries when ``neutral`` is None (irrelevant while it is absent).
    fields : dict of str to str
        Rig kind -> the rig-file field that states it natively ('friction.coulomb', ...); absent kinds carry
        it as an added effect.
    valid : (float, float)
        Range a rig file may state (physical validity; the fit's range is :meth:`Effect.bounds`).
    cyclic : bool
        An angle (a phase): its fit range is a formality, it is wrapped to [-π, π) afterwards.
    firm : bool
        Its fit range is a structural limit (a fraction, a frequency inside the analysis band), not a scale of
        plausibility: a fit that ends at it is not repeated with a wider range.
    """

    key: str
    unit_hinge: str
    unit_slide: str
    description: str
    neutral: float | None = 0.0
    default: float = 0.0
    fields: dict[str, str] = field(default_factory=dict)
    valid: tuple[float, float] = (-math.inf, math.inf)
    cyclic: bool = False
    firm: bool = False

    def unit(self, joint: str) -> str:
        return self.unit_slide if joint == SLIDE else self.unit_hinge


@dataclass(frozen=True)
class Scale:
    """Characteristic quantities of a rig on a log, in SI units (N·m or N, rad or m by joint): the scale that
    every effect's fit bounds are drawn from.

    Attributes
    ----------
    effort : float
        The largest effort the log or the rig can apply: max(|command|, the rig's peak effort if stated).
    inertia : float
        The rig's (output-referred) inertia or mass.
    velocity : float
        The largest |filtered velocity| of the motor-side position in the log (at least one resolution step
        per second, so that a still log still has a scale).
    position_span : float
        Range of the motor-side position in the log.
    load_span : float
        Range of the transmitted torque (the testbed; 0 for a rigid joint).
    duration : float
        Length of the log [s].
    dt : float
        Sampling step [s].
    band_hz : float
        The analysis band (the residual filter's cut-off) [Hz].
    baseline : dict of str to float
        The rig's own parameter vector (theta before any fit), for bounds relative to the rig's values.
    """

    effort: float
    inertia: float
    velocity: float
    position_span: float
    load_span: float
    duration: float
    dt: float
    band_hz: float
    baseline: dict[str, float] = field(default_factory=dict)


@dataclass(frozen=True)
class OwnFit:
    """An effect's parameters fitted a way of their own (:meth:`Effect.fit`): values and standard errors (theta
    keys, SI units), and what the fit adds to the report."""

    values: dict[str, float]
    errors: dict[str, float]
    details: dict = field(default_factory=dict)
    unresolved: tuple[str, ...] = ()  # parameters the log bounds from one side only: stated, not refused at a bound


@dataclass(frozen=True)
class Realisation:
    """How a MuJoCo simulation of a rig carries an effect (anything left None is not used).

    Attributes
    ----------
    command : callable or None
        ``u -> u'``: the command as the drive turns it into effort (before its dead time).
    load : callable or None
        ``(q, qd, t) -> effort`` the joint needs for the effect [N·m | N] (motor-side position and velocity, time
        since the start [s]); applied as a generalised force ``-load`` on the joint at every physics step (rigid
        joint) or control tick (the testbed's motor joint).
    lever_load : callable or None
        The testbed: ``q_lever -> torque`` the lever needs [N·m], applied on the lever every control tick.
    sensor : callable or None
        The testbed: ``(tau, temperature) -> reading offset`` [N·m] added to the torque sensor.
    dcmotor_cogging : (amplitude, poles, phase) or None
        The testbed: MuJoCo dcmotor cogging at the motor shaft [N·m, 1, rad].
    compliant_body : (fraction, stiffness, damping) or None
        A rigid joint: a second body behind a spring-damper on the joint's axis ([1], [N/m | N·m/rad],
        [N·s/m | N·m·s/rad]).
    """

    command: Callable[[float], float] | None = None
    load: Callable[[float, float, float], float] | None = None
    lever_load: Callable[[float], float] | None = None
    sensor: Callable[[np.ndarray, np.ndarray], np.ndarray] | None = None
    dcmotor_cogging: tuple[float, int, float] | None = None
    compliant_body: tuple[float, float, float] | None = None


class Effect:
    """Base class of the library's effects; see the module docstring. Subclasses set the class attributes and
    override the hooks they need."""

    name: ClassVar[str]
    description: ClassVar[str]
    params: ClassVar[tuple[Param, ...]]
    channel: ClassVar[str] = "effort"  # the residual channel it changes most: 'effort', 'sensor', 'kinematic'
    rigs: ClassVar[frozenset[str]] = ALL_RIGS  # kinds of rig it applies to
    signature: ClassVar[str] = ""  # diagnostics signature that points at it
    order: ClassVar[int] = 100  # position in reports and candidate lists
    refined_starts: ClassVar[int] = 1  # a fit refines the best this many starts (a cost with several minima)
    # the experiment whose log reveals it (experiments.synthetic_logs.EXPERIMENTS; docs/discrepancy.md, "Effects
    # and the experiments that reveal them"), and whether that log needs a fine motor encoder (a finer position
    # step than the 16-bit one resolves its motion)
    revealing_experiment: ClassVar[str]
    needs_fine_motor_encoder: ClassVar[bool] = False
    low_speed_evidence: ClassVar[bool] = False  # a rigid joint: scored on the low-speed windows' position error
    # too (sim.discrepancy.windows), where the effort balance leaves its evidence out
    min_records: ClassVar[int] = 1  # the fewest records (logs) of one rig an analysis needs to consider it
    linear_signature: ClassVar[bool] = False  # its term is its signature times a parameter (a level, a coefficient):
    # a gain while the residual does not follow the signature came by another way (the stuck samples' band), and
    # the fit is refused as degenerate (rule 'evidence')
    any_size: ClassVar[bool] = False  # rule 'size' asks only that it change the effort by more than the encoder's
    # resolution leaves, not by min_effort_change of the command (a dead time matters at any size)
    explains_at_bound: ClassVar[bool] = True  # a fit at its bound is a near explanation (not: a gain that only
    # scales the whole balance)

    @property
    def keys(self) -> tuple[str, ...]:
        return tuple(p.key for p in self.params)

    @property
    def stationary_keys(self) -> tuple[str, ...]:
        """The parameters rule 'stationary' compares between the fit and the held-out part (not the phases)."""
        return tuple(p.key for p in self.params if not p.cyclic)

    def n_parameters(self, model: Surrogate) -> int:
        """Parameters the effect fits on ``model``'s log, for the information criterion (default: its own)."""
        return len(self.params)

    def param(self, key: str) -> Param:
        return next(p for p in self.params if p.key == key)

    def applies(self, rig: Rig) -> bool:
        return rig_kind(rig) in self.rigs

    def native(self, rig: Rig) -> bool:
        """Whether ``rig``'s own fields state the effect (every parameter that switches it on and off, or every
        parameter if none does): then the rig file carries it, and it is written there."""
        kind = rig_kind(rig)
        switches = [p for p in self.params if p.neutral is not None] or list(self.params)
        return all(kind in p.fields for p in switches)

    def present(self, theta: dict[str, float]) -> bool:
        """Whether ``theta`` carries the effect (some parameter with a neutral value is not at it; an effect
        without such a parameter, e.g. the inertia, is always present)."""
        switches = [p for p in self.params if p.neutral is not None]
        return not switches or any(theta.get(p.key, p.neutral) != p.neutral for p in switches)

    def absent(self) -> dict[str, float]:
        """Parameter values of a rig without the effect."""
        return {p.key: p.default if p.neutral is None else p.neutral for p in self.params}

    # -- fitting ------------------------------------------------------------------------------------------
    def bounds(self, key: str, scale: Scale, theta: dict[str, float]) -> tuple[float, float]:
        """Range of parameter ``key`` in a fit, from the rig's and log's ``scale`` (and current ``theta``)."""
        raise NotImplementedError(f"{self.name}: no bounds for {key!r}")

    def starts(self, model: Surrogate, theta: dict[str, float]) -> tuple[list[dict[str, float]], tuple[str, ...]]:
        """Starting points of a fit (each a partial theta) and keys held at the screened value (not refined).
        Default: a step of 30 % of the current value (or 1 % of the range) each way of every parameter."""
        starts = []
        for p in self.params:
            low, high = self.bounds(p.key, model.scale, theta)
            value = theta[p.key]
            span = high - low if math.isfinite(high - low) else 1.0
            step = max(0.3 * abs(value), 0.01 * span)
            starts += [{p.key: min(max(value + s, low), high)} for s in (-step, step)]
        return starts, ()

    def fit(self, model: Surrogate, theta: dict[str, float], mask: np.ndarray | None = None) -> OwnFit | None:
        """Fit the effect's parameters a way of their own on ``mask`` (default the fit part), every other parameter
        at ``theta``'s values (the selection then re-fits those with them); None (default): the surrogate's least
        squares from :meth:`starts`, jointly with the others."""
        return None

    def canonical(self, theta: dict[str, float], joint: str) -> dict[str, float]:
        """One representative of parameter sets that describe the same physics (default: ``theta``)."""
        return theta

    def identifiable(self, model: Surrogate, theta: dict[str, float]) -> str | None:
        """None if the log can reveal the effect; otherwise why not."""
        return None

    def simpler(self, model: Surrogate, theta: dict[str, float]) -> tuple[str, str] | None:
        """(the simpler effect, why) if the law with the fitted ``theta`` degenerates into that effect's over the
        span of the log (a spring whose rest position lies outside the motion: a constant effort there); None
        otherwise (default). The selection then names the simpler law unless this one explains significantly
        more (rule 'simpler')."""
        return None

    # -- the surrogate's terms ----------------------------------------------------------------------------
    def command(self, u: np.ndarray, theta: dict[str, float], peak: float) -> np.ndarray:
        """The command as the drive delivers it, for this effect [N·m | N] (default: unchanged)."""
        return u

    def load(self, model: Surrogate, theta: dict[str, float]) -> np.ndarray | float:
        """Effort the joint needs for this effect on the analysis grid, filtered [N·m | N] (default 0)."""
        return 0.0

    def lever_load(self, model: Surrogate, theta: dict[str, float]) -> np.ndarray | float:
        """The testbed: torque the lever needs for this effect on the analysis grid [N·m] (default 0)."""
        return 0.0

    def evidence(self, model: Surrogate, theta: dict[str, float], residual: np.ndarray,
                 mask: np.ndarray) -> float | None:
        """Correlation of ``residual`` (the effect's channel) with the effect's signature on ``mask`` [1]
        (None: no signature on this log). Default: :meth:`signature_signal`."""
        signal = self.signature_signal(model, theta)
        return None if signal is None else correlation(residual[mask], np.broadcast_to(signal, residual.shape)[mask])

    def signature_signal(self, model: Surrogate, theta: dict[str, float]) -> np.ndarray | None:
        """The signal named :attr:`signature` on the analysis grid (None: none)."""
        return None

    def sensor(self, model: Surrogate, theta: dict[str, float], tau: np.ndarray) -> np.ndarray | float:
        """What the effect adds to the torque sensor's reading for transmitted torque ``tau`` [N·m]."""
        return 0.0

    # -- simulation ---------------------------------------------------------------------------------------
    def realise(self, values: dict[str, float], rig: Rig) -> Realisation:
        """How MuJoCo carries the effect with ``values`` (theta keys) on ``rig``; default: through the rig's
        own parameters (a native effect)."""
        return Realisation()

    def draw(self, rig: Rig, rng: np.random.Generator) -> dict[str, float]:
        """A hidden value for a synthetic log of ``rig`` (theta keys); changes of a parameter the rig carries
        are relative to its value."""
        raise NotImplementedError(f"{self.name} has no synthetic range")

    def __repr__(self) -> str:
        return f"<effect {self.name}>"


# ------------------------------------------------------------------------------------------------ helpers


def up_or_down(rng: np.random.Generator, value: float, up: tuple[float, float], down: tuple[float, float]) -> float:
    """``value`` times a factor drawn from ``up`` or ``down`` (each half the time): a change away from 1."""
    return value * float(rng.uniform(*(up if rng.random() < 0.5 else down)))


def signed(rng: np.random.Generator, low: float, high: float) -> float:
    """A magnitude drawn from [low, high] with a random sign (the sign drawn first)."""
    sign = 1.0 if rng.random() < 0.5 else -1.0
    return sign * float(rng.uniform(low, high))


def wrap_angle(angle: float) -> float:
    """``angle`` in [-π, π) [rad]."""
    return (angle + math.pi) % TWO_PI - math.pi


def correlation(a: np.ndarray, b: np.ndarray) -> float:
    """Pearson correlation of the finite pairs of ``a`` and ``b`` [1] (0 if either is constant)."""
    ok = np.isfinite(a) & np.isfinite(b)
    if ok.sum() < 2:
        return 0.0
    a, b = a[ok] - a[ok].mean(), b[ok] - b[ok].mean()
    den = math.sqrt(float(a @ a) * float(b @ b))
    return float(a @ b) / den if den > 0 else 0.0


def sliding_fraction(model: Surrogate) -> float:
    """Fraction of the grid samples in which the joint slides [1]."""
    return float(np.mean(~model.stuck))


MIN_SLIDING_FRACTION = 0.05  # friction effects need >= 5 % of the samples sliding


def needs_sliding(model: Surrogate) -> str | None:
    """Why a friction effect cannot be revealed (the joint hardly slides), or None."""
    fraction = sliding_fraction(model)
    if fraction < MIN_SLIDING_FRACTION:
        return (f"the joint slides in only {100 * fraction:.1f} % of the samples (needs "
                f"{100 * MIN_SLIDING_FRACTION:g} %)")
    return None


MIN_INERTIAL_FRACTION = 0.02  # an inertial effect needs the log's inertial effort (RMS) at 2 % of the command's


def needs_acceleration(model: Surrogate, theta: dict[str, float]) -> str | None:
    """Why an effect on the inertial effort cannot be revealed (the log hardly accelerates the joint), or None."""
    inertial = theta["inertia"] * float(np.sqrt(np.mean(model.data.acceleration**2)))
    command = float(np.sqrt(np.mean(model.data.u**2)))
    if inertial < MIN_INERTIAL_FRACTION * command:
        return (f"the inertial effort is {inertial:.3g} RMS, below {100 * MIN_INERTIAL_FRACTION:g} % of the "
                f"command's {command:.3g}: the log hardly accelerates the joint")
    return None


def canonical_sine(theta: dict[str, float], amplitude: str, phase: str) -> dict[str, float]:
    """``A·sin(· + φ)`` with A >= 0 and φ in [-π, π) (``-A·sin(· + φ) = A·sin(· + φ + π)``)."""
    theta = dict(theta)
    if theta[amplitude] < 0:
        theta[amplitude] = -theta[amplitude]
        theta[phase] += math.pi
    theta[phase] = wrap_angle(theta[phase])
    return theta


def reversals(velocity: np.ndarray, threshold: float) -> int:
    """Number of motion reversals: sign changes of the velocity among samples with |v| > threshold."""
    moving = np.sign(velocity[np.abs(velocity) > threshold])
    return int(np.count_nonzero(np.diff(moving) != 0))


def linear_starts(model: Surrogate, theta: dict[str, float], columns: list[np.ndarray]) -> np.ndarray | None:
    """Least-squares coefficients ``c`` with ``Σ c_i·columns_i ≈ effort residual`` on the fit part (None if no
    sample counts): the exact start of an effect whose load is linear in its parameters."""
    r = model.residuals(theta)["effort"]
    ok = model.data.fit & np.isfinite(r)
    if ok.sum() < len(columns) + 1:
        return None
    a = np.column_stack([np.broadcast_to(c, r.shape)[ok] for c in columns])
    coef, *_ = np.linalg.lstsq(a, r[ok], rcond=None)
    return coef


