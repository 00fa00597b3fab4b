"""Derivative-free global search over a box of parameters (CMA-ES), resumable from a result directory.

A :class:`Space` maps x in [0, 1]^n to parameter values (log-scaled where hi/lo > ``LOG_RATIO``) and to the
``{group: {field: value}}`` overrides of :meth:`sim.params.TestbedParams.replace`. :func:`minimise` runs CMA-ES
(the ``cma`` package, ``pip install -e ".[identify]"``) on a batch objective, one generation per call. With a
:class:`SearchStore` it appends every evaluation to ``evals.jsonl`` and the strategy's state to ``state.pkl``
after each generation: a run resumed from that directory continues from the last finished generation, reuses
the evaluations already made and ends where the uninterrupted run ends. The strategy draws its samples from its
own generator (saved with it), so nothing the objective draws changes them.
"""

from __future__ import annotations

import json
import math
import pickle
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

IDENTIFY_EXTRA = 'pip install -e ".[identify]"'
LOG_RATIO = 3.0  # [-] a dimension whose hi/lo exceeds this is searched in log scale
EDGE = 0.01  # [-] a value within this fraction of its bound's span (in x) sits on that edge
DEFAULT_SIGMA0 = 0.25  # [-] CMA-ES's initial step, a fraction of the unit box's width


def log_scaled(lo: float, hi: float) -> bool:
    """Whether a bound [lo, hi] is searched in log scale: lo > 0 and hi/lo > LOG_RATIO."""
    return lo > 0.0 and hi / lo > LOG_RATIO


@dataclass(frozen=True)
class Dimension:
    """One searched parameter: ``group.field`` between ``lo`` and ``hi`` (its unit), in log scale if ``log``
    (by default when lo > 0 and hi/lo > LOG_RATIO: :func:`log_scaled`)."""

    path: str
    lo: float
    hi: float
    log: bool | None = None

    def __post_init__(self) -> None:
        if self.path.count(".") != 1:
            raise ValueError(f"path = {self.path!r}: expected 'group.field'")
        if not (math.isfinite(self.lo) and math.isfinite(self.hi) and self.lo < self.hi):
            raise ValueError(f"{self.path}: bound [{self.lo}, {self.hi}] must be finite with lo < hi")
        if self.log is None:
            object.__setattr__(self, "log", log_scaled(self.lo, self.hi))
        elif self.log and self.lo <= 0.0:
            raise ValueError(f"{self.path}: a log scale needs lo > 0, got lo = {self.lo}")

    def value(self, x: float) -> float:
        """The parameter value at position ``x`` in [0, 1] (clipped)."""
        x = min(max(float(x), 0.0), 1.0)
        if self.log:
            return self.lo * (self.hi / self.lo) ** x
        return self.lo + x * (self.hi - self.lo)

    def position(self, value: float) -> float:
        """The position in [0, 1] of ``value`` (clipped to the bound)."""
        value = min(max(float(value), self.lo), self.hi)
        if self.log:
            x = math.log(value / self.lo) / math.log(self.hi / self.lo)
        else:
            x = (value - self.lo) / (self.hi - self.lo)
        return min(max(x, 0.0), 1.0)  # rounding of the log map

    def edge(self, x: float) -> str | None:
        """'low' or 'high' when ``x`` sits within EDGE of that end of the bound, else None."""
        return "low" if x <= EDGE else "high" if x >= 1.0 - EDGE else None


@dataclass(frozen=True)
class Space:
    """The searched parameters; x in [0, 1]^n."""

    dims: tuple[Dimension, ...]

    def __post_init__(self) -> None:
        paths = [d.path for d in self.dims]
        if not paths or len(set(paths)) != len(paths):
            raise ValueError(f"a space needs distinct parameters, got {paths}")

    def __len__(self) -> int:
        return len(self.dims)

    def values(self, x: Sequence[float]) -> dict[str, float]:
        """``{group.field: value}`` at ``x``."""
        if len(x) != len(self.dims):
            raise ValueError(f"x has {len(x)} entries; the space has {len(self.dims)}")
        return {d.path: d.value(xi) for d, xi in zip(self.dims, x, strict=True)}

    def overrides(self, x: Sequence[float]) -> dict[str, dict[str, float]]:
        """``{group: {field: value}}`` at ``x`` (for ``TestbedParams.replace`` and a parameter TOML)."""
        out: dict[str, dict[str, float]] = {}
        for path, value in self.values(x).items():
            group, name = path.split(".")
            out.setdefault(group, {})[name] = value
        return out

    def positions(self, values: dict[str, float]) -> np.ndarray:
        """x of ``{group.field: value}`` (each clipped into its bound)."""
        return np.array([d.position(values[d.path]) for d in self.dims])


@dataclass(frozen=True)
class Evaluation:
    """One candidate's score and what to keep of it (JSON-ready)."""

    score: float
    record: dict[str, Any] = field(default_factory=dict)


@dataclass(frozen=True)
class SearchResult:
    """The best candidate found and how the search went.

    Attributes
    ----------
    best_x : ndarray
        Position of the best candidate in [0, 1]^n.
    best : Evaluation
    evaluations : int
        Candidates scored (reused ones included).
    generations : int
    history : list of (generation, evaluations, best score)
    """

    best_x: np.ndarray
    best: Evaluation
    evaluations: int
    generations: int
    history: list[tuple[int, int, float]]


def key(x: Sequence[float]) -> str:
    """The cache key of a candidate: its exact coordinates."""
    return json.dumps([float(v) for v in x])


class SearchStore:
    """A result directory: ``settings.json``, ``evals.jsonl`` (one evaluation a line) and ``state.pkl``.

    Parameters
    ----------
    directory : Path
    settings : dict
        What the evaluations depend on (JSON-ready); a resumed run must give the same.
    resume : bool
        Continue the run in ``directory``; without it, a directory holding a run is refused.
    """

    def __init__(self, directory: Path, settings: dict[str, Any], resume: bool = False) -> None:
        self.directory = Path(directory)
        self.evals_path = self.directory / "evals.jsonl"
        self.state_path = self.directory / "state.pkl"
        settings_path = self.directory / "settings.json"
        settings = json.loads(json.dumps(settings))
        if settings_path.exists():
            if not resume:
                raise ValueError(f"{self.directory} holds a run already: resume it (--resume) or choose another "
                                 f"directory")
            saved = json.loads(settings_path.read_text())
            if saved != settings:
                changed = sorted(k for k in saved.keys() | settings.keys() if saved.get(k) != settings.get(k))
                raise ValueError(f"{self.directory}: the run was made with other settings ({', '.join(changed)}: "
                                 f"{[saved.get(k) for k in changed]}, asked {[settings.get(k) for k in changed]})")
        elif resume:
            raise ValueError(f"{self.directory} holds no run to resume ({settings_path.name} missing)")
        else:
            self.directory.mkdir(parents=True, exist_ok=True)
            settings_path.write_text(json.dumps(settings, indent=1) + "\n")

    def cached(self) -> dict[str, Evaluation]:
        """Every evaluation written (a line cut short by an interruption is skipped)."""
        out = {}
        if self.evals_path.exists():
            for line in self.evals_path.read_text().splitlines():
                try:
                    entry = json.loads(line)
                except json.JSONDecodeError:
                    continue
                out[entry["key"]] = Evaluation(entry["score"], entry["record"])
        return out

    def append(self, x: Sequence[float], evaluation: Evaluation) -> None:
        with self.evals_path.open("a") as fh:
            fh.write(json.dumps({"key": key(x), "x": [float(v) for v in x], "score": evaluation.score,
                                 "record": evaluation.record}) + "\n")

    def load_state(self) -> dict[str, Any] | None:
        if not self.state_path.exists():
            return None
        return pickle.loads(self.state_path.read_bytes())

    def save_state(self, state: dict[str, Any]) -> None:
        tmp = self.state_path.with_suffix(".tmp")
        tmp.write_bytes(pickle.dumps(state))
        tmp.replace(self.state_path)  # atomic: an interruption leaves the previous generation's state


def default_popsize(n: int) -> int:
    """CMA-ES's default population, 4 + floor(3 ln n)."""
    return 4 + int(3 * math.log(n))


def minimise(evaluate: Callable[[list[np.ndarray]], list[Evaluation]], x0: Sequence[float], *, seed: int,
             budget: int, sigma0: float = DEFAULT_SIGMA0, popsize: int | None = None, store: SearchStore | None = None,
             progress: Callable[[int, int, float], None] | None = None) -> SearchResult:
    """CMA-ES over [0, 1]^n from ``x0``, until ``budget`` candidates are scored or the strategy stops.

    Parameters
    ----------
    evaluate : callable
        ``evaluate(xs) -> [Evaluation]``, one per x, in order (a whole generation, for parallel evaluation).
    x0 : sequence of float
        Start, in [0, 1]^n.
    seed : int
        The seed of the strategy's sampling.
    budget : int
        Candidates to score (>= 2); the last generation is completed, so up to popsize - 1 more.
    sigma0 : float
        Initial step size in x (the box is 1 wide).
    popsize : int, optional
        Candidates per generation (default :func:`default_popsize`, at most ``budget``).
    store : SearchStore, optional
        Where evaluations and the state go, and are resumed from.
    progress : callable, optional
        ``progress(generation, evaluations, best_score)`` after each generation.
    """
    try:
        import cma
    except ImportError as exc:
        raise RuntimeError(f"the search needs the cma package: {IDENTIFY_EXTRA}") from exc
    x0 = np.asarray(x0, dtype=float)
    if isinstance(budget, bool) or not isinstance(budget, int) or budget < 2:
        raise ValueError(f"budget = {budget!r}: valid range [2, inf) evaluations")
    if isinstance(seed, bool) or not isinstance(seed, int) or not 0 <= seed < 2**32:
        raise ValueError(f"seed = {seed!r}: valid range [0, 2**32)")
    if not (0.0 < sigma0 <= 1.0):
        raise ValueError(f"sigma0 = {sigma0!r}: valid range (0, 1] (the box is 1 wide)")
    if x0.ndim != 1 or x0.size < 2 or np.any(x0 < 0.0) or np.any(x0 > 1.0):
        raise ValueError(f"x0 = {x0.tolist()}: expected >= 2 coordinates in [0, 1]")
    state = store.load_state() if store is not None else None
    if state is None:
        # the strategy's own generator (pickled with it), not numpy's global one that cma uses by default
        randn = np.random.RandomState(seed).randn
        es = cma.CMAEvolutionStrategy(x0, sigma0, {"bounds": [0.0, 1.0], "seed": math.nan, "randn": randn,
                                                   "verbose": -9,
                                                   "popsize": min(popsize or default_popsize(x0.size), budget)})
        state = {"es": es, "generation": 0, "evaluations": 0, "best_key": None, "best_x": None, "history": []}
    cache = store.cached() if store is not None else {}
    while state["evaluations"] < budget and not state["es"].stop():
        es = state["es"]
        xs = [np.asarray(x, dtype=float) for x in es.ask()]
        todo = list({key(x): x for x in xs if key(x) not in cache}.values())
        for x, evaluation in zip(todo, evaluate(todo) if todo else [], strict=True):
            cache[key(x)] = evaluation
            if store is not None:
                store.append(x, evaluation)
        scores = [cache[key(x)].score for x in xs]
        es.tell(xs, scores)
        for x, score in zip(xs, scores, strict=True):
            if state["best_key"] is None or score < cache[state["best_key"]].score:
                state["best_key"], state["best_x"] = key(x), x
        state["generation"] += 1
        state["evaluations"] += len(xs)
        state["history"].append((state["generation"], state["evaluations"], cache[state["best_key"]].score))
        if store is not None:
            store.save_state(state)
        if progress is not None:
            progress(*state["history"][-1])
    return SearchResult(state["best_x"], cache[state["best_key"]], state["evaluations"], state["generation"],
                        list(state["history"]))
