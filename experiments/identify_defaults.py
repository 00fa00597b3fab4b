"""Joint identification of the uncertain defaults against the paper's tables (CMA-ES, resumable).

    python -m experiments.identify_defaults [--part {drivetrain,sensor,joint}] [--out DIR] [--resume]
                                            [--budget N] [--seeds 0,1] [--workers N] [--ray [ADDRESS]] [--fast]
                                            [--duration S] [--holdout GROUP] [--params TOML] [--rerun PATH.rrd]
                                            [--no-plot]

What it fits, to what
---------------------
``--part`` chooses the parameters (:data:`PARTS`), each searched in [0, 1] mapped onto its source bound
(``sim.params.source_bound``; log scale where hi/lo > 3), and the experiments that score them:

* ``drivetrain`` (the default): gear friction, backlash, torque droop, command delay, current loop, load-cell
  amplifier (:data:`DRIVETRAIN`) against Tables VI-VII: every step, disturbance, sine and square test under both
  feedbacks (the cases of ``experiments.step`` and ``experiments.sinusoid``, their rows built by those modules)
  and the breakaway ramp (``sim.characterize``). The paper fixes the breakaway (0.13 N·m); the load-cell reading
  noise stays the closed form of its source.
* ``sensor``: the photo-reflector array's curvature, noise, slip, tilt-response spread and temperature
  coefficients (:data:`SENSOR`) against Tables III-V and Sec. III-C: the calibration and thermal experiments
  (``experiments.calibration``, ``experiments.thermal``). The cubic and quartic curvature follow the quadratic
  one on the 1/d² reflector's family (:func:`tied_overrides`).
* ``joint``: both sets against every table at once.

A candidate runs its part's experiments once per seed. Its score is the mean over the seeds of

* the RMS over the primary rows of the fitted tables of ln(sim / paper) (a factor 1.5 is 0.405), plus
* (drivetrain and joint) hinge penalties, 0 inside a band and (ln(value / nearest band end))² outside it, on the
  behaviours the paper describes (:data:`BANDS`): current feedback reaching 30 / 40 / 65 % (± 0.1) of the steps,
  increasing with the step; losing regulation at ≈ 0.3 N·m of disturbance; sensor feedback holding past 2 N·m;
  one-sided actuation of the low-torque current-feedback waveforms (``experiments.paper``); the breakaway
  0.13 ± 10 %.

The solver time constants (numerical) follow their source's rule, two physics steps, where a candidate lengthens
the step. A candidate the parameters refuse (a constraint between fields) scores :data:`INFEASIBLE_SCORE`. CMA-ES
(``experiments.search``, ``pip install -e ".[identify]"``) starts at the defaults with step 0.25 and stops after
``--budget`` candidates. Every (candidate, seed, case) is one item of ``sim.executor.Executor``: ``--workers N``
local processes or ``--ray [ADDRESS]`` (a local cluster without an address); the result is the same on either.

Outputs in ``--out DIR``: ``evals.jsonl`` (every candidate: x, overrides, score, its parts and rows),
``state.pkl`` (the strategy after each generation), ``defaults.json`` (the base parameters' evaluation, for
comparison), ``best_params.toml`` (for ``--params`` of every experiment),
``report.md`` and ``report.json`` (the score, each parameter with its bound and whether it sits on an edge, every
figure paper beside simulation, the score of each figure group, and each group held out in turn without a
refit: the evaluated candidate best without it, scored on it). ``--resume`` continues the run in DIR and reuses
its evaluations. ``--holdout GROUP`` leaves one figure group (:data:`GROUPS`) and its behaviours out of the score
and reports the best candidate's score on it. ``--fast`` runs the physics under ``simulation.substeps_rule =
"fast"`` (RMS figures within 1 % of the accurate rule's, peak errors within 9 %: a search may use it, the figures
it reports are then the fast rule's) and ``--duration`` shortens every motor test (a check of the command line,
not the paper's figures). --rerun
records the best candidate's step and sinusoid runs (first seed), run once more after the search (not re-run
during it). The command draws no figures (--no-plot is accepted, as by every experiment).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import sys
import time
import tomllib
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from controllers.feedback import FEEDBACK_KINDS
from experiments.calibration import run_calibration
from experiments.common import (
    add_executor_args,
    add_no_figures_arg,
    add_params_arg,
    add_rerun_args,
    cli_parser,
    executor_from_args,
    is_primary,
    load_params_arg,
    positive_int,
    record_rerun,
    run_seconds,
    seed_arg,
    short_run_banner,
    write_json,
)
from experiments.paper import ACTUATION_LEVEL, ONE_SIDED_SHARE, PAPER_BREAKAWAY_NM
from experiments.search import (
    DEFAULT_SIGMA0,
    Dimension,
    Evaluation,
    SearchResult,
    SearchStore,
    Space,
    log_scaled,
    minimise,
)
from experiments.sinusoid import SinusoidResult, run_sinusoid, run_sinusoid_case
from experiments.step import (
    PAPER_DISTURBANCE_LOST_NM,
    PAPER_REACHED_FRACTION,
    StepResult,
    run_disturbance_case,
    run_step,
    run_step_case,
)
from experiments.thermal import NOT_MODELLED, run_thermal
from experiments.thermal import PAPER_FIGURES as THERMAL_FIGURES
from models.gim8108_testbed.derived import FIXTURES, SOLVER_TIME_CONSTANTS, physics_timestep
from sensor.calibration import InfeasibleCalibrationError
from sim.characterize import measure_breakaway
from sim.executor import Executor
from sim.params import ParameterError, TestbedParams, field_range, source_bound
from sim.protocols import STEPS_NM, WAVEFORMS
from sim.runlog import RunLog

# The searched parameters of each part, each on its source bound (sim.params.source_bound).
DRIVETRAIN = ("friction.coulomb_torque_nm", "friction.load_friction_coefficient", "friction.stribeck_velocity_rad_s",
              "friction.viscous_nms_per_rad", "friction.presliding_stiffness_nm_per_rad",
              "motor.torque_saturation_per_nm", "backlash.width_rad", "motor.command_delay_s",
              "motor.current_loop_time_constant_s", "loadcell.amplifier_bandwidth_hz")
SENSOR = ("photoreflector.quadratic_fraction_max", "photoreflector.noise_min_v", "photoreflector.noise_max_v",
          "photoreflector.slip_fraction_min", "photoreflector.slip_fraction_max", "photoreflector.crosstalk_spread",
          "photoreflector.optical_tempco_min_per_k", "photoreflector.optical_tempco_max_per_k")
PARTS = {"drivetrain": DRIVETRAIN, "sensor": SENSOR, "joint": DRIVETRAIN + SENSOR}
# The sensor part's experiments by case kind, each its own figure group.
SENSOR_CASES = {"calibration": run_calibration, "thermal": run_thermal}
DEFAULT_PART = "drivetrain"
# the files a run writes in --out (checked against the inputs before it starts)
OUT_FILES = ("settings.json", "evals.jsonl", "state.pkl", "defaults.json", "best_params.toml", "report.json",
             "report.md")
FIT_TABLES = ("VI", "VII", "III", "IV", "III-B resolution", "V", "III-C")
# Rows reported but not fitted: figures of an instrument the simulation does not model.
UNFITTED = {(table, quantity) for key, table, quantity, *_ in THERMAL_FIGURES if key in NOT_MODELLED}
# A 1/d² reflector response over a gap change ±Δ about d: its quadratic, cubic and quartic terms are 1.5·(Δ/d),
# 2·(Δ/d)² and 2.5·(Δ/d)³ of the linear one (models/gim8108_testbed/README.md, Derivations).
CURVATURE_FAMILY = {"quadratic_fraction_max": (1.5, 1), "cubic_fraction_max": (2.0, 2),
                    "quartic_fraction_max": (2.5, 3)}
# [-] a candidate the parameters refuse: above any simulated score (each penalty is at most ~(ln 2e3)² = 58)
INFEASIBLE_SCORE = 1e4
RATIO_FLOOR = 1e-2  # [-] a figure the simulation does not produce (None, <= 0) counts as this ratio
# Figure groups (one test each, both feedbacks): --holdout leaves one out of the score.
GROUPS = {"steps": "the 0.05, 0.1 and 0.2 N·m steps (Table VI) and the reached fractions",
          "disturbance": "the disturbance test (Table VI) and where regulation is lost or held",
          **{w.name.replace(" ", "_").replace("·", ""): f"the {w.name} test (Table VII)" for w in WAVEFORMS},
          "calibration": "the calibration experiment (Tables III-IV, the resolution comparison)",
          "thermal": "the temperature experiment (Table V, Sec. III-C)"}
# Behaviour bands (paper Sec. IV, the motor experiments): value -> [lo, hi].
BANDS = {**{f"reached fraction {s:g} N·m": (f - 0.1, f + 0.1) for s, f in PAPER_REACHED_FRACTION.items()},
         "current-feedback regulation lost at [N·m]": (0.2, 0.45),
         "sensor-feedback regulation held to [N·m]": (PAPER_DISTURBANCE_LOST_NM["sensor"], math.inf),
         "one-sided share": (ONE_SIDED_SHARE, 1.0),
         "output level": (ACTUATION_LEVEL, math.inf),
         "breakaway [N·m]": (0.9 * PAPER_BREAKAWAY_NM, 1.1 * PAPER_BREAKAWAY_NM)}


def default_space(params: TestbedParams | None = None, part: str = DEFAULT_PART) -> Space:
    """The searched parameters of ``part`` on their source bounds, each cut to the field's valid range (an open end
    of it, such as a backlash width > 0, nudges the bound inside); the scale follows the source bound."""
    params = params or TestbedParams()
    dims = []
    for path in PARTS[part]:
        lo, hi = source_bound(path)
        valid_lo, valid_hi = field_range(params, *path.split("."))
        dims.append(Dimension(path, max(lo, valid_lo), min(hi, valid_hi), log=log_scaled(lo, hi)))
    return Space(tuple(dims))


def tied_overrides(overrides: dict[str, dict[str, float]]) -> dict[str, dict[str, float]]:
    """``overrides`` with the cubic and quartic curvature on the quadratic's 1/d² family (:data:`CURVATURE_FAMILY`)
    when the quadratic is among them: one gap ratio Δ/d = quadratic / 1.5 sets all three."""
    quadratic = overrides.get("photoreflector", {}).get("quadratic_fraction_max")
    if quadratic is None:
        return overrides
    k, n = CURVATURE_FAMILY["quadratic_fraction_max"]
    ratio = (quadratic / k) ** (1.0 / n)
    tied = {name: k_i * ratio**n_i for name, (k_i, n_i) in CURVATURE_FAMILY.items()}
    return {**overrides, "photoreflector": {**overrides["photoreflector"], **tied}}


def candidate_overrides(base: TestbedParams, overrides: dict[str, dict[str, float]]) -> dict[str, dict[str, float]]:
    """``overrides`` with the curvature terms tied (:func:`tied_overrides`) and the solver time constants a
    candidate needs: their source's rule, two physics steps of the accurate rule
    (``models.gim8108_testbed.build.check_time_constants``), where the candidate lengthens the step (a softer
    presliding stiffness does). They are numerical, not identified."""
    overrides = tied_overrides(overrides)
    try:
        params = base.replace(**overrides)
    except ParameterError:  # a rule between fields refuses the candidate: run_case scores it infeasible
        return overrides
    two_steps = 2.0 * max(physics_timestep(params, fixture, "accurate")[0] for fixture in FIXTURES) * (1.0 + 1e-6)
    out = {group: dict(values) for group, values in overrides.items()}
    for group, name in SOLVER_TIME_CONSTANTS:
        if getattr(getattr(params, group), name) < two_steps:
            out.setdefault(group, {})[name] = two_steps
    return out


def waveform_group(name: str) -> str:
    return name.replace(" ", "_").replace("·", "")


@dataclass(frozen=True)
class Setup:
    """What every item shares: the base parameters and the test length."""

    params: TestbedParams
    duration_s: float | None = None


def cases(part: str = DEFAULT_PART) -> list[tuple[str, str, Any]]:
    """(kind, feedback, argument) of every case of one candidate and seed: steps, disturbance, waveforms
    (drivetrain); the calibration and thermal experiments (sensor); all of them (joint)."""
    out: list[tuple[str, str, Any]] = []
    if part != "sensor":
        for feedback in FEEDBACK_KINDS:
            out += [("step", feedback, s) for s in STEPS_NM]
            out.append(("disturbance", feedback, None))
            out += [("waveform", feedback, i) for i in range(len(WAVEFORMS))]
    if part != "drivetrain":
        out += [(kind, "", None) for kind in SENSOR_CASES]
    return out


def run_case(setup: Setup, item: tuple[dict, int, tuple[str, str, Any]]) -> dict[str, Any]:
    """One case of one candidate and seed: its rows (each tagged with its group) and behaviour figures; or the
    error a refused parameter set (or a sensor no calibration can meet the paper's bound for) raises. An item of
    the executor."""
    overrides, seed, (kind, feedback, arg) = item
    try:
        params = setup.params.replace(**overrides)
        if kind == "breakaway":
            return {"kind": kind, "rows": [], "breakaway_nm": measure_breakaway(params).torque_nm}
        if kind in SENSOR_CASES:
            experiment = SENSOR_CASES[kind](params, seed)
            return {"kind": kind, "feedback": "", "group": kind,
                    "rows": [{**row, "group": kind} for row in experiment.rows()]}
        if kind == "step":
            hold = {} if setup.duration_s is None else {"hold_s": setup.duration_s}
            case = run_step_case(params, feedback, arg, seed, **hold)
            stats = {"reference_nm": arg, "reached_fraction": case.error.reached_fraction}
            group = "steps"
        elif kind == "disturbance":
            case = run_disturbance_case(params, feedback, seed, setup.duration_s)
            stats = {"lost_nm": case.disturbance_at_loss_nm, "max_nm": case.disturbance_max_nm}
            group = "disturbance"
        else:
            kwargs = {} if setup.duration_s is None else {"duration_s": setup.duration_s}
            case = run_sinusoid_case(params, feedback, WAVEFORMS[arg], seed, **kwargs)
            stats = {"amplitude_nm": case.waveform.amplitude_nm, "positive_share": case.positive_share,
                     "output_level": case.output_level}
            group = waveform_group(case.waveform.name)
    except (ParameterError, InfeasibleCalibrationError, RuntimeError) as exc:
        return {"kind": kind, "error": f"{type(exc).__name__}: {exc}"}
    case = dataclasses.replace(case, log=None)
    result = SinusoidResult([case], seed) if kind == "waveform" else StepResult([case], seed)
    rows = [{**row, "group": group} for row in result.rows()]
    return {"kind": kind, "feedback": feedback, "group": group, "rows": rows, **stats}


def primary(row: dict[str, Any]) -> bool:
    """A fitted row: a figure of a fitted table (:data:`FIT_TABLES`) read as the paper's primary definition."""
    return row["table"] in FIT_TABLES and is_primary(row) and (row["table"], row["quantity"]) not in UNFITTED


def log_ratio(row: dict[str, Any]) -> float:
    ratio = row["ratio"] if row["ratio"] is not None and row["ratio"] > 0.0 else RATIO_FLOOR
    return math.log(max(ratio, RATIO_FLOOR))


def hinge(value: float | None, band: tuple[float, float]) -> float:
    """0 inside ``band``, (ln(value / nearest end))² outside; a missing or non-positive value counts as 1e-3."""
    lo, hi = band
    value = max(value if value is not None else 0.0, 1e-3)
    if value < lo:
        return math.log(lo / value) ** 2
    return math.log(value / hi) ** 2 if value > hi else 0.0


def penalties(results: list[dict[str, Any]]) -> dict[str, tuple[str, float]]:
    """Behaviour name -> (group, penalty) from one seed's case results (and the breakaway)."""
    out: dict[str, tuple[str, float]] = {}
    fractions = [(r["reference_nm"], r["reached_fraction"]) for r in results
                 if r["kind"] == "step" and r["feedback"] == "current"]
    for step, f in fractions:
        out[f"reached fraction {step:g} N·m"] = ("steps", hinge(f, BANDS[f"reached fraction {step:g} N·m"]))
    ordered = [f for _, f in sorted(fractions)]
    if ordered:
        out["reached fraction increases with the step"] = ("steps", sum(
            math.log(max(a, 1e-3) / max(b, 1e-3)) ** 2 for a, b in zip(ordered, ordered[1:], strict=False) if b < a))
    for r in results:
        if r["kind"] == "disturbance" and r["feedback"] == "current":
            lost = r["lost_nm"] if r["lost_nm"] is not None else r["max_nm"]  # never lost: at least the maximum
            name = "current-feedback regulation lost at [N·m]"
            out[name] = ("disturbance", hinge(lost, BANDS[name]))
        elif r["kind"] == "disturbance":
            held = r["lost_nm"] if r["lost_nm"] is not None else r["max_nm"]
            name = "sensor-feedback regulation held to [N·m]"
            out[name] = ("disturbance", hinge(held, BANDS[name]))
        elif r["kind"] == "waveform" and r["feedback"] == "current" and r["amplitude_nm"] <= 0.1:
            share = max(r["positive_share"], 1.0 - r["positive_share"])
            out[f"{r['group']}: one-sided share"] = (r["group"], hinge(share, BANDS["one-sided share"]))
            out[f"{r['group']}: output level"] = (r["group"], hinge(r["output_level"], BANDS["output level"]))
        elif r["kind"] == "breakaway":
            out["breakaway [N·m]"] = ("breakaway", hinge(r["breakaway_nm"], BANDS["breakaway [N·m]"]))
    return out


def seed_score(results: list[dict[str, Any]], holdout: str | None = None) -> dict[str, Any]:
    """One seed's score: RMS ln(sim/paper) over the primary rows plus the penalties, ``holdout``'s left out;
    with every behaviour's group and penalty (``behaviours``, held out or not) for :func:`rotation`."""
    rows = [row for r in results for row in r["rows"]]
    behaviours = penalties(results)
    return {**score_parts(rows, behaviours, {holdout}), "behaviours": behaviours}


def score_parts(rows: list[dict[str, Any]], behaviours: dict[str, tuple[str, float]],
                excluded: set[str | None]) -> dict[str, Any]:
    """RMS ln(sim/paper) over the primary rows, the penalties and their sum, groups in ``excluded`` left out."""
    fitted = [row for row in rows if primary(row) and row["group"] not in excluded]
    rms = math.sqrt(sum(log_ratio(row) ** 2 for row in fitted) / len(fitted)) if fitted else 0.0
    pens = {name: p for name, (group, p) in behaviours.items() if group not in excluded}
    return {"rms_log_ratio": rms, "penalties": pens, "score": rms + sum(pens.values())}


def rotation(records: list[dict[str, Any]], holdout: str | None = None) -> dict[str, dict[str, Any]]:
    """Each figure group held out in turn, without refitting: among the evaluated candidates (their records),
    the best on the score without the group, and that candidate's RMS ln(sim/paper) on the group's rows."""
    records = [r for r in records if "seeds" in r]
    out = {}
    for group in GROUPS:
        def fit(record, group=group):
            return float(np.mean([score_parts(p["rows"], p["behaviours"], {holdout, group})["score"]
                                  for p in record["seeds"].values()]))

        best = min(records, key=fit, default=None)
        held = [group_scores(p["rows"]).get(group) for p in best["seeds"].values()] if best else [None]
        if None in held:  # no candidate, or the group has no primary rows
            continue
        out[group] = {"fit_score": fit(best), "held_out_rms_log_ratio": float(np.mean(held)),
                      "overrides": best["overrides"]}
    return out


def group_scores(rows: list[dict[str, Any]]) -> dict[str, float]:
    """RMS ln(sim/paper) of each group's primary rows."""
    out = {}
    for group in GROUPS:
        logs = [log_ratio(r) for r in rows if primary(r) and r["group"] == group]
        if logs:
            out[group] = math.sqrt(sum(x * x for x in logs) / len(logs))
    return out


class Objective:
    """The batch objective of :func:`experiments.search.minimise`: candidates x seeds x cases on an executor."""

    def __init__(self, space: Space, setup: Setup, seeds: tuple[int, ...], executor: Executor,
                 holdout: str | None = None, part: str = DEFAULT_PART) -> None:
        self.space, self.setup, self.seeds, self.executor, self.holdout = space, setup, seeds, executor, holdout
        self.part = part

    def __call__(self, xs: list[np.ndarray]) -> list[Evaluation]:
        return self.run([candidate_overrides(self.setup.params, self.space.overrides(x)) for x in xs])

    def run(self, overrides: list[dict[str, dict[str, float]]]) -> list[Evaluation]:
        """The evaluations of parameter sets given as overrides of the base parameters."""
        items = [(i, (o, seed, case)) for i, o in enumerate(overrides) for seed in self.seeds
                 for case in cases(self.part)]
        if self.part != "sensor":
            items += [(i, (o, self.seeds[0], ("breakaway", "", None))) for i, o in enumerate(overrides)]
        results = self.executor.map(run_case, [item for _, item in items], shared=self.setup)
        return [self.evaluate(overrides[i], [(item, r) for (j, item), r in zip(items, results, strict=True)
                                             if j == i]) for i in range(len(overrides))]

    def evaluate(self, overrides: dict, done: list[tuple[tuple, dict[str, Any]]]) -> Evaluation:
        errors = sorted({r["error"] for _, r in done if "error" in r})
        if errors:
            return Evaluation(INFEASIBLE_SCORE, {"overrides": overrides, "errors": errors})
        breakaway = [r for _, r in done if r["kind"] == "breakaway"]
        per_seed = {}
        for seed in self.seeds:
            results = [r for (_, s, case), r in done if s == seed and case[0] != "breakaway"] + breakaway
            per_seed[seed] = {**seed_score(results, self.holdout),
                              "rows": [row for r in results for row in r["rows"]]}
        score = float(np.mean([p["score"] for p in per_seed.values()]))
        return Evaluation(score, {"overrides": overrides, "seeds": {str(s): p for s, p in per_seed.items()},
                                  "breakaway_nm": breakaway[0]["breakaway_nm"] if breakaway else None})


def params_toml(overrides: dict[str, dict[str, float]], header: str = "") -> str:
    """A parameter TOML (``sim.params.load_params``) of ``{group: {field: value}}``."""
    lines = [f"# {line}" for line in header.splitlines()]
    for group, values in overrides.items():
        lines += ["", f"[{group}]"] + [f"{name} = {float(value)!r}" for name, value in values.items()]
    return "\n".join(lines).lstrip("\n") + "\n"


def report(space: Space, base: TestbedParams, best_x: np.ndarray, best: Evaluation, settings: dict[str, Any],
           holdout: str | None, evaluations: int, generations: int) -> dict[str, Any]:
    """The report's content (JSON-ready): score, parameters with bounds and edges, figures, groups. Each value is
    the one evaluated (the base's under the candidate's overrides)."""
    if "seeds" not in best.record:
        raise RuntimeError(f"no candidate the parameters accept was found: {best.record['errors']}")
    defaults = {row[0]: row[1] for row in base.rows()}
    units = {row[0]: row[2] for row in base.rows()}
    evaluated = {row[0]: row[1] for row in base.replace(**best.record["overrides"]).rows()}
    parameters = [{"path": d.path, "value": evaluated[d.path], "default": defaults[d.path], "unit": units[d.path],
                   "bound": [d.lo, d.hi], "log_scale": d.log, "x": float(x), "edge": d.edge(x)}
                  for d, x in zip(space.dims, best_x, strict=True)]
    seeds = best.record["seeds"]
    first = next(iter(seeds.values()))["rows"]
    figures = []
    for k, row in enumerate(first):
        sims = {s: p["rows"][k]["sim"] for s, p in seeds.items()}
        logs = [log_ratio(p["rows"][k]) for p in seeds.values()] if row["ratio"] is not None else []
        figures.append({"table": row["table"], "quantity": row["quantity"], "unit": row["unit"],
                        "reading": row.get("reading", "primary"),
                        "paper": row["paper"], "group": row["group"], "fitted": primary(row) and row["group"]
                        != holdout, "sim": sims, "ratio": math.exp(float(np.mean(logs))) if logs else None})
    scored = [group_scores(p["rows"]) for p in seeds.values()]
    groups = {g: float(np.mean([s[g] for s in scored])) for g in GROUPS if all(g in s for s in scored)}
    return {"score": best.score, "settings": settings, "evaluations": evaluations, "generations": generations,
            "holdout": holdout, "holdout_score": groups.get(holdout) if holdout else None,
            "per_seed": {s: {"rms_log_ratio": p["rms_log_ratio"], "penalties": p["penalties"]}
                         for s, p in seeds.items()},
            "breakaway_nm": best.record["breakaway_nm"], "parameters": parameters, "figures": figures,
            "group_scores": groups}


def markdown(rep: dict[str, Any]) -> str:
    """The report as Markdown."""
    def num(v):
        return "-" if v is None else f"{v:.4g}"

    s = rep["settings"]
    lines = ["# Identification of the uncertain defaults (experiments.identify_defaults)", "",
             f"Score {rep['score']:.4f} (part {s.get('part', DEFAULT_PART)}: mean over seeds {s['seeds']} of RMS "
             f"ln(sim/paper) over the primary rows of its tables plus behaviour penalties), {rep['evaluations']} "
             f"evaluations in "
             f"{rep['generations']} generations (the base parameters score {rep['defaults_score']:.4f}); substeps "
             f"rule {s['substeps_rule']}, "
             + ("full-length tests." if s["duration_s"] is None else
                f"**tests cut to {s['duration_s']:g} s: not comparable with the paper's figures.**"), ""]
    if rep.get("base_kept"):
        lines += ["No candidate of the search scored below the base parameters: the result is the base parameters "
                  "(the figures below are theirs).", ""]
    if rep["holdout"]:
        lines += [f"Held out of the fit: **{rep['holdout']}**; its RMS ln(sim/paper) with the best candidate: "
                  f"{num(rep['holdout_score'])}.", ""]
    lines += ["## Parameters", "", "| parameter | value | default | unit | bound | scale | on an edge |",
              "|---|---|---|---|---|---|---|"]
    lines += [f"| {p['path']} | {p['value']:.4g} | {p['default']:.4g} | {p['unit']} | [{p['bound'][0]:.4g}, "
              f"{p['bound'][1]:.4g}] | {'log' if p['log_scale'] else 'linear'} | {p['edge'] or 'no'} |"
              for p in rep["parameters"]]
    lines += ["", "## Penalties (per seed)", "", "| seed | RMS ln ratio | penalties |", "|---|---|---|"]
    lines += [f"| {seed} | {v['rms_log_ratio']:.4f} | "
              + ", ".join(f"{k} {x:.3g}" for k, x in v["penalties"].items() if x > 0.0) + " |"
              for seed, v in rep["per_seed"].items()]
    seeds = list(rep["per_seed"])
    lines += ["", "## Figures, paper beside simulation", "",
              "| table | quantity | reading | unit | paper | " + " | ".join(f"sim seed {s}" for s in seeds)
              + " | ratio (geometric mean) | in the RMS |", "|---|---|---|---|---|" + "---|" * len(seeds) + "---|---|"]
    lines += [f"| {f['table']} | {f['quantity'].replace('|', chr(92) + '|')} | {f['reading']} | {f['unit']} | "
              f"{num(f['paper'])} | "
              + " | ".join(num(f["sim"][s]) for s in seeds) + f" | {num(f['ratio'])} | "
              f"{'yes' if f['fitted'] else 'no'} |" for f in rep["figures"]]
    lines += ["", "## RMS ln(sim/paper) by figure group", "", "| group | RMS ln ratio | held out |", "|---|---|---|"]
    lines += [f"| {g} | {v:.4f} | {'yes' if g == rep['holdout'] else 'no'} |" for g, v in rep["group_scores"].items()]
    lines += ["", "## Each group held out in turn (no refit)", "",
              "Among this run's evaluations, the candidate best on the score without the group, and its RMS "
              "ln(sim/paper) on the group: a selection, not a fit that never saw the group (the search saw every "
              "group but the one --holdout names).", "",
              "| group | score without it | held-out RMS ln ratio | best candidate's RMS ln ratio on it |",
              "|---|---|---|---|"]
    lines += [f"| {g} | {v['fit_score']:.4f} | {v['held_out_rms_log_ratio']:.4f} | {rep['group_scores'][g]:.4f} |"
              for g, v in rep["rotation"].items()]
    return "\n".join(lines) + "\n"


def choose_best(result: SearchResult, base: Evaluation, base_x: np.ndarray) -> tuple[Evaluation, np.ndarray, bool]:
    """The search's best candidate, or the base parameters if no candidate scored below them.

    Returns the evaluation, its position in the unit box and whether it is the base's."""
    if base.score <= result.best.score:
        return base, np.asarray(base_x, dtype=float), True
    return result.best, result.best_x, False


def run_candidate(params: TestbedParams, seed: int = 0,
                  duration_s: float | None = None) -> tuple[list[dict], dict[str, RunLog]]:
    """The Table VI-VII rows of one parameter set and the run logs they come from (for --rerun)."""
    step = run_step(params, seed=seed, duration_s=duration_s)
    sine = run_sinusoid(params, seed=seed, duration_s=duration_s)
    return step.rows() + sine.rows(), {**step.logs(), **sine.logs()}


def seed_list(text: str) -> tuple[int, ...]:
    """argparse type of --seeds: comma-separated non-negative integers."""
    try:
        seeds = tuple(int(s) for s in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r}: expected comma-separated integers, e.g. 0,1") from None
    if not seeds or min(seeds) < 0 or len(set(seeds)) != len(seeds):
        raise argparse.ArgumentTypeError(f"{text!r}: expected distinct integers >= 0")
    return seeds


def search_seed_arg(text: str) -> int:
    """argparse type of --search-seed: an integer in [0, 2**32) (CMA-ES's sampling seed)."""
    value = seed_arg(text)
    if value >= 2**32:
        raise argparse.ArgumentTypeError(f"{value}: valid range [0, 2**32)")
    return value


def main(argv: list[str] | None = None) -> None:
    parser = cli_parser(__doc__, __spec__.name)
    parser.add_argument("--part", choices=tuple(PARTS), default=DEFAULT_PART,
                        help="which parameters, against which experiments: drivetrain (Tables VI-VII, the default), "
                             "sensor (Tables III-V, Sec. III-C) or joint (both)")
    parser.add_argument("--out", type=Path, default=Path("identify_run"), metavar="DIR",
                        help="result directory: evaluations, strategy state, best_params.toml, report "
                             "(default identify_run)")
    parser.add_argument("--resume", action="store_true", help="continue the run in --out, reusing its evaluations")
    parser.set_defaults(out_files=OUT_FILES)
    parser.add_argument("--budget", type=positive_int, default=500, metavar="N",
                        help="candidates to evaluate (default 500; the last generation is completed)")
    parser.add_argument("--seeds", type=seed_list, default=(0, 1), metavar="S,S",
                        help="noise seeds each candidate runs with (default 0,1)")
    parser.add_argument("--search-seed", type=search_seed_arg, default=1, metavar="N",
                        help="seed of the CMA-ES sampling (default 1)")
    parser.add_argument("--sigma0", type=float, default=DEFAULT_SIGMA0, metavar="F",
                        help="initial step of the search as a fraction of each bound's width, in (0, 1] (default "
                             "0.25; smaller to refine around the parameters of --params)")
    add_executor_args(parser, "the evaluations")
    parser.add_argument("--fast", action="store_true",
                        help='simulation.substeps_rule = "fast" (exploration: ~2x faster; RMS figures within 1 %%, '
                             'peak errors within 9 %%)')
    parser.add_argument("--duration", type=run_seconds, metavar="S",
                        help="shorten every test to S seconds (a check of the command line, not the paper's figures)")
    parser.add_argument("--holdout", choices=tuple(GROUPS), metavar="GROUP",
                        help=f"leave one figure group out of the score and report it: {', '.join(GROUPS)}")
    add_params_arg(parser)
    add_rerun_args(parser, "the best candidate's step, disturbance and sinusoid runs (first seed; run once more "
                           "after the search, not re-run during it)")
    add_no_figures_arg(parser)
    args = parser.parse_args(argv)
    base = load_params_arg(parser, args)
    if args.fast:
        base = base.replace(simulation={"substeps_rule": "fast"})
    if args.budget < 2:
        parser.error(f"--budget {args.budget}: valid range [2, inf) evaluations")
    sensor_group = args.holdout in SENSOR_CASES
    if args.holdout is not None and (args.part == "drivetrain" and sensor_group
                                     or args.part == "sensor" and not sensor_group):
        parser.error(f"--holdout {args.holdout}: not a figure group of --part {args.part}")
    if not (0.0 < args.sigma0 <= 1.0):
        parser.error(f"--sigma0 {args.sigma0}: valid range (0, 1] (a fraction of each bound's width)")
    space = default_space(base, args.part)
    settings = {"space": [[d.path, d.lo, d.hi] for d in space.dims], "seeds": list(args.seeds),
                "search_seed": args.search_seed, "substeps_rule": base.simulation.substeps_rule,
                "duration_s": args.duration, "holdout": args.holdout,
                "params": str(args.params) if args.params else None}
    if args.sigma0 != DEFAULT_SIGMA0:  # recorded only when set, so directories without the option still resume
        settings["sigma0"] = args.sigma0
    if args.part != DEFAULT_PART:  # likewise
        settings["part"] = args.part
    try:
        store = SearchStore(args.out, settings, resume=args.resume)
    except ValueError as exc:
        parser.error(f"--out {args.out}: {exc}")
    executor = executor_from_args(parser, args)
    objective = Objective(space, Setup(base, args.duration), args.seeds, executor, args.holdout, args.part)
    start = time.perf_counter()
    runs = len(cases(args.part)) * len(args.seeds) + (args.part != "sensor")
    print(f"identifying {len(space)} parameters ({args.part}), {len(args.seeds)} seed(s), {runs} runs per candidate"
          f", on {executor.where}; results in {args.out}", file=sys.stderr, flush=True)
    saved = store.load_state()
    done_before = saved["evaluations"] if saved else 0

    def progress(generation: int, done: int, best: float) -> None:
        elapsed = time.perf_counter() - start
        eta = max(args.budget - done, 0) * elapsed / max(done - done_before, 1)
        print(f"generation {generation}: best score {best:.4f}, {done}/{args.budget} evaluations, "
              f"{elapsed:.0f} s elapsed, ETA {eta:.0f} s", file=sys.stderr, flush=True)

    defaults_path = args.out / "defaults.json"
    if defaults_path.exists():
        defaults = Evaluation(**json.loads(defaults_path.read_text()))
    else:
        defaults = objective.run([candidate_overrides(base, {})])[0]
        write_json(defaults_path, {"score": defaults.score, "record": defaults.record})
    print(f"defaults (the base parameters, outside the search): score {defaults.score:.4f}", file=sys.stderr,
          flush=True)
    x0 = space.positions({row[0]: row[1] for row in base.rows()})
    result = minimise(objective, x0, seed=args.search_seed, budget=args.budget, sigma0=args.sigma0, store=store,
                      progress=progress)
    best, best_x, kept_base = choose_best(result, defaults, x0)
    overrides = best.record["overrides"]
    rep = report(space, base, best_x, best, settings, args.holdout, result.evaluations, result.generations)
    rep["base_kept"] = kept_base
    rep["seconds"] = time.perf_counter() - start
    rep["defaults_score"] = defaults.score
    rep["rotation"] = rotation([e.record for e in store.cached().values()], args.holdout)
    if args.params is not None:  # the file's own overrides stay, under the candidate's
        with args.params.open("rb") as fh:
            from_file = tomllib.load(fh)
        overrides = {g: {**from_file.get(g, {}), **overrides.get(g, {})} for g in {**from_file, **overrides}}
    (args.out / "best_params.toml").write_text(params_toml(
        overrides, f"experiments.identify_defaults: score {best.score:.4f} "
                   f"({result.evaluations} evaluations, seeds {list(args.seeds)}, "
                   f"substeps rule {base.simulation.substeps_rule})"))
    write_json(args.out / "report.json", rep)
    (args.out / "report.md").write_text(markdown(rep))
    short_run_banner(args)
    if kept_base:
        print(f"no candidate scored below the base parameters ({defaults.score:.4f}; the search's best "
              f"{result.best.score:.4f}): they are the result")
    print(f"best score {best.score:.4f} after {result.evaluations} evaluations ({result.generations} "
          f"generations, {rep['seconds']:.0f} s); the defaults score {defaults.score:.4f}")
    for p in rep["parameters"]:
        edge = f"  ON THE {p['edge'].upper()} EDGE" if p["edge"] else ""
        print(f"  {p['path']:45s} {p['value']:<10.4g} bound [{p['bound'][0]:.4g}, {p['bound'][1]:.4g}] "
              f"{p['unit']}{edge}")
    if args.holdout:
        print(f"held out {args.holdout}: RMS ln ratio {rep['holdout_score']:.4f}")
    print(f"report: {args.out / 'report.md'}; parameters: {args.out / 'best_params.toml'}")
    if args.rerun or args.rerun_spawn:
        params = base.replace(**overrides)
        _, logs = run_candidate(params, args.seeds[0], args.duration)
        print(f"rerun: the best candidate's runs ({overrides})")
        record_rerun(args, logs, params)


if __name__ == "__main__":
    main()
