"""The sensor's paper figures over manufactured units: their spread, and where the paper's value falls in it.

    python -m experiments.units [--units N] [--seed N] [--workers N] [--ray [ADDRESS]] [--json PATH] [--plot DIR]
                                [--params TOML]

A sensor unit is a ``photoreflector.unit_seed`` (its per-channel values are drawn with it). For units 0 .. N-1
(default 24) the calibration and thermal experiments (``experiments.calibration``, ``experiments.thermal``) run
with the same noise seed (``--seed``), each unit one item of ``sim.executor.Executor`` (``--workers N`` local
processes, ``--ray [ADDRESS]`` a Ray cluster; the result is the same on either). For every primary row of Tables
III-V and Sec. III-C the output gives the units' minimum, median and maximum, the unit of the parameters
(``unit_seed`` 0 by default) and the paper's percentile among the units: 100 x (the units whose figure is below
the paper's, plus half of those equal to it) / the units with the figure. A unit whose calibration or thermal
experiment fails is counted and named with its error, and has no figure of that experiment; a unit whose
rational drift fit (Eq. 20) is rejected is named with the model its compensation uses instead; each zero-drift
model's median RMS error on the chamber records, and for how many units it is the lowest, is beside the paper's
statement that the rational function fits best. Figures the same
for every unit (the MINI85's one-hour errors: the reference, not the sensor) are printed apart. Figure:
``units_spread.png`` (each figure's units on a log axis, normalised by the paper's value). 5-30 s of CPU per
unit (``benchmarks/README.md``).
"""

from __future__ import annotations

import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from experiments.calibration import run_calibration
from experiments.common import (
    TARGET_RATIO,
    add_executor_args,
    add_output_args,
    add_params_arg,
    cli_parser,
    executor_from_args,
    is_primary,
    load_params_arg,
    positive_int,
    seed_arg,
    write_outputs,
)
from experiments.thermal import run_thermal
from sim.executor import Executor, stderr_progress
from sim.figures import save_figure
from sim.params import TestbedParams, field_range

PLOT_FILES = ("units_spread.png",)  # the files --plot writes

DEFAULT_UNITS = 24
PERCENTILE_DEFINITION = ("the paper's percentile among the units: 100 x (units whose figure is below the paper's "
                         "+ half of those equal to it) / units with the figure")


def percentile_of(value: float, sample) -> float:
    """The percentile of ``value`` in ``sample`` [%]: 100 x (count below + half the count equal) / size.

    0 when ``value`` is below every element, 100 when above every one, 50 when it equals all of them.
    """
    x = np.asarray(sample, dtype=float)
    if x.ndim != 1 or x.size == 0 or not np.all(np.isfinite(x)):
        raise ValueError(f"sample = {sample!r}: valid samples are one or more finite numbers")
    if not np.isfinite(value):
        raise ValueError(f"value = {value!r}: valid values are finite numbers")
    return 100.0 * (np.count_nonzero(x < value) + 0.5 * np.count_nonzero(x == value)) / x.size


@dataclass(frozen=True)
class Setup:
    """What every unit shares: the base parameters and the noise seed."""

    params: TestbedParams
    seed: int


@dataclass(frozen=True)
class UnitRun:
    """One unit's primary rows (``{table, quantity, unit, paper, sim}``) of both experiments, the drift model its
    compensation uses (None if the thermal experiment failed), each failed experiment's error, and each fitted
    zero-drift model's RMS error on the chamber record [N·m]."""

    unit_seed: int
    rows: tuple[dict[str, Any], ...]
    compensation_model: str | None
    errors: dict[str, str]
    drift_fit_rms_nm: dict[str, float] = field(default_factory=dict)


def run_unit(setup: Setup, unit_seed: int) -> UnitRun:
    """The calibration and thermal experiments on the unit ``unit_seed``: an item of the executor. An experiment
    that fails (an infeasible calibration, no drift fit) leaves its error instead of its rows."""
    params = setup.params.replace(photoreflector={"unit_seed": unit_seed})
    rows, errors, model, drift_rms = [], {}, None, {}
    for name, run in (("calibration", run_calibration), ("thermal", run_thermal)):
        try:
            result = run(params, setup.seed)
        except (ValueError, RuntimeError) as exc:  # InfeasibleCalibrationError and ParameterError are ValueErrors
            errors[name] = f"{type(exc).__name__}: {exc}"
            continue
        rows += [{k: r[k] for k in ("table", "quantity", "unit", "paper")}
                 | {"sim": None if r["sim"] is None else float(r["sim"])} for r in result.rows() if is_primary(r)]
        model = getattr(result, "compensation_model", model)
        if hasattr(result, "models"):
            drift_rms = {name: fit.rmse_nm for name, fit in result.models.fits.items()}
    return UnitRun(unit_seed, tuple(rows), model, errors, drift_rms)


@dataclass(frozen=True)
class FigureSpread:
    """One figure over the units: ``values`` maps each unit with the figure to its value [``unit``]."""

    table: str
    quantity: str
    unit: str
    paper: float
    values: dict[int, float]

    @property
    def spread(self) -> tuple[float, float, float]:
        """(min, median, max) over the units."""
        x = list(self.values.values())
        return float(np.min(x)), float(np.median(x)), float(np.max(x))

    @property
    def percentile(self) -> float:
        """The paper's value's percentile among the units [%] (:func:`percentile_of`)."""
        return percentile_of(self.paper, list(self.values.values()))

    @property
    def same_for_every_unit(self) -> bool:
        """Whether every unit gives the same value (a figure of the rig, not of the sensor unit)."""
        return len(self.values) > 1 and len(set(self.values.values())) == 1

    def to_dict(self, reference_unit: int) -> dict[str, Any]:
        lo, median, hi = self.spread
        return {"table": self.table, "quantity": self.quantity, "unit": self.unit, "paper": self.paper,
                "min": lo, "median": median, "max": hi, "percentile_pct": self.percentile,
                "reference_unit_value": self.values.get(reference_unit), "n_units": len(self.values),
                "same_for_every_unit": self.same_for_every_unit,
                "values": {str(u): v for u, v in self.values.items()}}


def figure_spreads(runs: list[UnitRun]) -> tuple[list[FigureSpread], list[str]]:
    """Each primary figure over the units that have it, in the experiments' row order; and the figures no unit
    simulates (``"table quantity"``, such as the DYJN-104 rows)."""
    keys: dict[tuple[str, str], dict[str, Any]] = {}
    for run in runs:
        for row in run.rows:
            keys.setdefault((row["table"], row["quantity"]), row)
    spreads, missing = [], []
    for key, row in keys.items():
        values = {run.unit_seed: r["sim"] for run in runs for r in run.rows
                  if (r["table"], r["quantity"]) == key and r["sim"] is not None}
        if values:
            spreads.append(FigureSpread(row["table"], row["quantity"], row["unit"], row["paper"], values))
        else:
            missing.append(f"{key[0]} {key[1]}")
    return spreads, missing


@dataclass(frozen=True)
class UnitsResult:
    """Every unit's run, each figure's spread; ``reference_unit``: the unit of the base parameters."""

    seed: int
    reference_unit: int
    runs: list[UnitRun]
    figures: list[FigureSpread]
    not_simulated: list[str]

    @property
    def failures(self) -> dict[int, dict[str, str]]:
        """Unit seed -> {experiment: error} of the units with a failed experiment."""
        return {r.unit_seed: r.errors for r in self.runs if r.errors}

    @property
    def fallbacks(self) -> dict[int, str]:
        """Unit seed -> the drift model its compensation uses, for the units whose Eq. 20 fit was rejected."""
        return {r.unit_seed: r.compensation_model for r in self.runs
                if r.compensation_model not in (None, "rational")}

    def drift_models(self) -> tuple[dict[str, float], dict[str, int]]:
        """Each zero-drift model's median RMS error on the chamber record over the units it was fitted on [N·m],
        and for how many units each model has the lowest RMS."""
        names = sorted({m for r in self.runs for m in r.drift_fit_rms_nm})
        medians = {m: float(np.median([r.drift_fit_rms_nm[m] for r in self.runs if m in r.drift_fit_rms_nm]))
                   for m in names}
        lowest = {m: 0 for m in names}
        for r in self.runs:
            if r.drift_fit_rms_nm:
                lowest[min(r.drift_fit_rms_nm, key=r.drift_fit_rms_nm.__getitem__)] += 1
        return medians, lowest

    def to_dict(self) -> dict[str, Any]:
        medians, lowest = self.drift_models()
        return {"units": [r.unit_seed for r in self.runs], "seed": self.seed, "reference_unit": self.reference_unit,
                "percentile_definition": PERCENTILE_DEFINITION,
                "figures": [f.to_dict(self.reference_unit) for f in self.figures],
                "not_simulated": self.not_simulated,
                "failures": {str(u): e for u, e in self.failures.items()},
                "rational_fit_rejected": {str(u): m for u, m in self.fallbacks.items()},
                "drift_fit_rms_nm": {str(r.unit_seed): r.drift_fit_rms_nm for r in self.runs},
                "drift_fit_median_rms_nm": medians, "drift_fit_lowest_rms_units": lowest}

    def text(self) -> str:
        """The table (paper beside the units' min / median / max, its percentile, the reference unit), then the
        failed units and the rejected drift fits."""
        ref = f"unit {self.reference_unit}"
        width = max(len(f"{f.table} {f.quantity}") for f in self.figures) if self.figures else 8
        lines = [f"The sensor's figures over {len(self.runs)} units (unit_seed {self.runs[0].unit_seed}-"
                 f"{self.runs[-1].unit_seed}), noise seed {self.seed}; pct: {PERCENTILE_DEFINITION}",
                 f"{'figure':{width}s} {'unit':5s} {'paper':>9s} {'min':>9s} {'median':>9s} {'max':>9s} "
                 f"{'pct':>5s} {ref:>9s} {'n':>3s}"]
        for f in self.figures:
            if f.same_for_every_unit:
                continue
            lo, median, hi = f.spread
            own = f.values.get(self.reference_unit)
            lines.append(f"{f'{f.table} {f.quantity}':{width}s} {f.unit:5s} {f.paper:9.4g} {lo:9.4g} {median:9.4g} "
                         f"{hi:9.4g} {f.percentile:5.1f} {'-' if own is None else f'{own:.4g}':>9s} "
                         f"{len(f.values):3d}")
        same = [f for f in self.figures if f.same_for_every_unit]
        if same:
            lines.append("the same for every unit (not a property of the sensor unit): " + "; ".join(
                f"{f.table} {f.quantity} {next(iter(f.values.values())):.4g} {f.unit} (paper {f.paper:.4g})"
                for f in same))
        if self.not_simulated:
            lines.append(f"not simulated: {', '.join(self.not_simulated)}")
        lines.append(f"failed: {len(self.failures)} of {len(self.runs)} units"
                     + "".join(f"\n  unit {u}: {name}: {err}" for u, errs in self.failures.items()
                               for name, err in errs.items()))
        lines.append(f"Eq. 20 drift fit rejected (compensation and zero drift per 1 °C from another model): "
                     f"{len(self.fallbacks)} of {len(self.runs)} units"
                     + (": " + ", ".join(f"unit {u} ({m})" for u, m in self.fallbacks.items())
                        if self.fallbacks else ""))
        medians, lowest = self.drift_models()
        if medians:
            lines.append("zero-drift models on the chamber record (paper: the rational function fits best): median RMS "
                         + ", ".join(f"{m} {v:.5g}" for m, v in medians.items()) + " N·m; lowest RMS for "
                         + ", ".join(f"{m} {n}" for m, n in lowest.items()) + f" of {len(self.runs)} units")
        return "\n".join(lines)

    def plot(self, directory: Path) -> list[Path]:
        """``units_spread.png``: one strip per figure, the units' values over the paper's on a log axis."""
        return [plot_spreads(self, directory)]


def run_units(params: TestbedParams | None = None, seed: int = 0, units: int = DEFAULT_UNITS,
              executor: Executor | None = None) -> UnitsResult:
    """The calibration and thermal experiments on units 0 .. ``units`` - 1 (noise seed ``seed``), on
    ``executor`` (this process if None), and each primary figure's spread over them."""
    params = params or TestbedParams()
    if isinstance(units, bool) or not isinstance(units, int) or not 1 <= units <= _max_units(params):
        raise ValueError(f"units = {units!r}: valid range [1, {_max_units(params)}]")
    runs = (executor or Executor(1)).map(run_unit, range(units), shared=Setup(params, seed))
    figures, missing = figure_spreads(runs)
    return UnitsResult(seed, params.photoreflector.unit_seed, runs, figures, missing)


def _max_units(params: TestbedParams) -> int:
    return int(field_range(params, "photoreflector", "unit_seed")[1]) + 1


def plot_spreads(result: UnitsResult, directory: Path) -> Path:
    """Each figure's units (grey) and the parameters' unit (red) over the paper's value, log axis; the paper at 1,
    the factor-1.5 band shaded."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.ticker import FixedLocator, NullFormatter

    figures = [f for f in result.figures if not f.same_for_every_unit]
    fig, ax = plt.subplots(figsize=(11, 0.4 * len(figures) + 2.2))
    ax.axvspan(1 / TARGET_RATIO, TARGET_RATIO, color="0.92", label=f"within a factor {TARGET_RATIO:g}")
    ax.axvline(1.0, color="k", lw=1.0, label="paper")
    for i, f in enumerate(figures):
        jitter = 0.3 * (np.arange(len(f.values)) / max(len(f.values) - 1, 1) - 0.5)
        ax.plot(np.array(list(f.values.values())) / f.paper, i + jitter, "o", ms=4, color="0.45", alpha=0.8,
                label="units" if i == 0 else None)
        if result.reference_unit in f.values:
            ax.plot(f.values[result.reference_unit] / f.paper, i, "D", ms=7, color="tab:red",
                    label=f"unit {result.reference_unit}" if i == 0 else None)
    ax.set_yticks(range(len(figures)),
                  [f"{f.table} {f.quantity} (paper at {f.percentile:.0f} %)" for f in figures], fontsize=8)
    ax.invert_yaxis()
    ax.set_xscale("log")
    ax.xaxis.set_major_locator(FixedLocator([0.01, 0.02, 0.05, 0.1, 0.2, 0.5, 1, 2, 5, 10, 20, 50, 100]))
    ax.xaxis.set_major_formatter("{x:g}")
    ax.xaxis.set_minor_formatter(NullFormatter())
    ax.set(xlabel="simulated / paper (log axis)",
           title=f"{len(result.runs)} sensor units (unit_seed), noise seed {result.seed}\n"
                 f"percentile: units below the paper's value, ties counted half")
    ax.legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.01, 1.0))
    return save_figure(fig, directory, PLOT_FILES[0])


def main(argv: list[str] | None = None) -> int:
    parser = cli_parser(__doc__, __spec__.name)
    parser.add_argument("--units", type=positive_int, default=DEFAULT_UNITS, metavar="N",
                        help=f"sensor units to run, unit_seed 0 .. N-1 (default {DEFAULT_UNITS})")
    parser.add_argument("--seed", type=seed_arg, default=0, help="seed of every noise draw, for every unit "
                                                                 "(default 0)")
    add_executor_args(parser, "the units")
    add_output_args(parser, "write the spreads, every unit's values, the failures and rejected drift fits",
                    PLOT_FILES)
    add_params_arg(parser)
    args = parser.parse_args(argv)
    params = load_params_arg(parser, args)
    if args.units > _max_units(params):
        parser.error(f"--units {args.units}: valid range [1, {_max_units(params)}] (unit_seed is at most "
                     f"{_max_units(params) - 1})")
    executor = executor_from_args(parser, args, progress=stderr_progress("units"))
    print(f"calibration and thermal experiments on {args.units} sensor units, on {executor.where} ...",
          file=sys.stderr, flush=True)
    start = time.perf_counter()
    result = run_units(params, args.seed, args.units, executor)
    print(f"{args.units} units in {time.perf_counter() - start:.0f} s", file=sys.stderr, flush=True)
    print(result.text())
    write_outputs(args, result.to_dict(), result.plot, run={"units": args.units})
    return 0


if __name__ == "__main__":
    sys.exit(main())
