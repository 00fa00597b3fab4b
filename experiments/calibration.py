"""Sensor calibration and evaluation (paper Sec. IV-A/B, Tables III-IV, the LS/QP resolution comparison).

    python -m experiments.calibration [--seed N] [--json PATH] [--plot DIR] [--params TOML]

Simulates the calibration rig (test weights to ±25 N·m five times each way, the T_x/T_y moment protocol),
fits LS and the paper's QP, evaluates the QP calibration on a second session of the same protocols, and
prints every figure beside the paper's.
"""

from __future__ import annotations

import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from experiments.common import (TARGET_RATIO, add_output_args, add_params_arg, add_rerun_args, cli_parser, format_rows,
                                load_params_arg, record_log, record_rerun, run_errors, seed_arg, write_outputs)
from sensor.evaluation import SensorEvaluation, evaluate_sensor
from sim.figures import save_figure
from sim.params import TestbedParams

TABLE = "calibration"
# (figure name, table, quantity, unit, paper value); paper Tables III, IV and Sec. IV-B.
PAPER_FIGURES: tuple[tuple[str, str, str, str, float], ...] = (
    ("max_error_pct_fs", "III", "max error", "% FS", 0.0830),
    ("rms_error_nm", "III", "RMS error", "N·m", 0.0266),
    ("nonlinearity_pct_fs", "III", "nonlinearity", "% FS", 0.111),
    ("hysteresis_pct_fs", "III", "hysteresis", "% FS", 0.139),
    ("repeatability_pct_fs", "IV", "repeatability", "% FS", 0.0849),
    ("crosstalk_tx_pct_fs", "IV", "crosstalk T_x", "% FS", 0.148),
    ("crosstalk_ty_pct_fs", "IV", "crosstalk T_y", "% FS", 0.126),
    ("ls_std_nm", "IV-B resolution", "LS std", "N·m", 0.0160),
    ("ls_resolution_3sigma_nm", "IV-B resolution", "LS 3-sigma resolution", "N·m", 0.0480),
    ("qp_std_nm", "IV-B resolution", "QP std", "N·m", 0.00746),
    ("qp_resolution_3sigma_nm", "IV-B resolution", "QP 3-sigma resolution", "N·m", 0.0224),
    ("qp_improvement", "IV-B resolution", "QP improvement over LS", "x", 2.14),
)


def comparison_rows(figures: dict[str, tuple[float, str]],
                    paper: tuple[tuple[str, str, str, str, float], ...]) -> list[dict[str, Any]]:
    """Rows ``{table, quantity, unit, paper, sim, ratio}`` (ratio = sim / paper) for the named figures."""
    return [{"table": table, "quantity": quantity, "unit": unit, "paper": value, "sim": figures[name][0],
             "ratio": figures[name][0] / value} for name, table, quantity, unit, value in paper]


@dataclass(frozen=True)
class CalibrationExperiment:
    """The evaluation, its comparison rows and the figures written (paths)."""

    evaluation: SensorEvaluation
    rows: list[dict[str, Any]]
    figures: list[Path] = field(default_factory=list)

    def to_dict(self) -> dict[str, Any]:
        return {"rows": self.rows, "evaluation": self.evaluation.to_dict(),
                "figures": [str(p) for p in self.figures]}


def run_calibration(params: TestbedParams | None = None, seed: int = 0,
                    plot_dir: Path | None = None) -> CalibrationExperiment:
    """Calibrate and evaluate the default (or given) sensor unit; figures to ``plot_dir`` if given."""
    evaluation = evaluate_sensor(params or TestbedParams(), seed)
    figures = plot_calibration(evaluation, plot_dir) if plot_dir is not None else []
    return CalibrationExperiment(evaluation, comparison_rows(evaluation.figures, PAPER_FIGURES), figures)


def plot_calibration(ev: SensorEvaluation, out_dir: Path) -> list[Path]:
    """Figures like the paper's Figs. 6-8: channel responses, errors and hysteresis, crosstalk and noise."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from sensor import metrics

    paths = []
    rec = ev.calibration_record
    fig, ax = plt.subplots(1, 2, figsize=(11, 4))
    ax[0].plot(rec.time_s, rec.tau_reference_nm, lw=0.8)
    ax[0].set(xlabel="time [s]", ylabel="MINI85 torque [N·m]", title="calibration loading (5x each way)")
    step = max(1, len(rec.time_s) // 4000)
    for k in range(8):
        ax[1].plot(rec.tau_reference_nm[::step], rec.voltages_v[::step, k], ".", ms=1, label=f"ch {k + 1}")
    ax[1].set(xlabel="torque [N·m]", ylabel="channel voltage [V]", title="channel responses")
    ax[1].legend(markerscale=8, fontsize=7, ncol=2)
    paths.append(save_figure(fig, out_dir, "calibration_channels.png"))

    evr = ev.evaluation_record
    out = ev.qp.predict(evr.voltages_v)
    direction = metrics.reference_direction(evr.tau_reference_nm)
    bc = metrics.branch_curves(evr.tau_reference_nm, out, direction)
    fig, ax = plt.subplots(1, 2, figsize=(11, 4))
    ax[0].plot(evr.tau_reference_nm[::step], (out - evr.tau_reference_nm)[::step], ".", ms=1)
    ax[0].set(xlabel="torque [N·m]", ylabel="QP error [N·m]", title="error on the evaluation session")
    for name in ("ascending", "descending"):
        ax[1].plot(bc.level_nm[bc.both], getattr(bc, f"{name}_error_nm")[bc.both], label=name)
    ax[1].set(xlabel="torque [N·m]", ylabel="branch error [N·m]", title="hysteresis branches")
    ax[1].legend()
    paths.append(save_figure(fig, out_dir, "calibration_hysteresis.png"))

    fig, ax = plt.subplots(1, 3, figsize=(14, 4))
    for axis, r in ev.crosstalk_records.items():
        ax[0].plot(r.time_s, ev.qp.predict(r.voltages_v), lw=0.6, label=f"T_{axis} applied")
    ax[0].set(xlabel="time [s]", ylabel="apparent T_z [N·m]", title="crosstalk")
    ax[0].legend()
    res = ev.resolution_record
    for a, cal, name in ((ax[1], ev.ls, "LS"), (ax[2], ev.qp, "QP")):
        tau = cal.predict(res.voltages_v)
        a.plot(res.time_s, tau, lw=0.4)
        a.set(xlabel="time [s]", ylabel="torque [N·m]", title=f"{name}: no load, 3σ = {3 * tau.std(ddof=1):.4f} N·m")
    paths.append(save_figure(fig, out_dir, "calibration_noise.png"))
    return paths


def main(argv: list[str] | None = None) -> int:
    parser = cli_parser(__doc__, __spec__.name)
    parser.add_argument("--seed", type=seed_arg, default=0, help="seed of every noise draw (default 0)")
    add_output_args(parser, "write {rows: [...]} and the calibrations")
    add_params_arg(parser)
    add_rerun_args(parser, "the rig records (channel voltages, MINI85 and QP-sensor torque; no mechanics, no 3D)")
    args = parser.parse_args(argv)
    params = load_params_arg(parser, args)
    print("calibrating on the simulated rig (T_z loading, T_x/T_y moments) and evaluating ...", file=sys.stderr)
    with run_errors(parser):
        result = run_calibration(params, args.seed, args.plot)
    print(format_rows("Sensor calibration and evaluation (Tables III-IV, the resolution comparison)", result.rows,
                      band=TARGET_RATIO))
    sel = result.evaluation.gamma_selection
    print(f"\nQP: gamma = {sel.gamma:g} chosen by RMSE^2 + {sel.lambda_weight:g} Var(quiet); "
          f"{result.evaluation.qp.diagnostics.n_active_constraints} active error bounds")
    write_outputs(args, {"rows": result.rows, **{k: v for k, v in result.to_dict().items() if k != "rows"}})
    for p in result.figures:
        print(f"figure: {p}")
    ev = result.evaluation
    records = {"calibration": ev.calibration_record, "evaluation": ev.evaluation_record,
               "no load": ev.resolution_record}
    record_rerun(args, lambda: {name: record_log(r.time_s, r.voltages_v, tau_sensor_nm=ev.qp.predict(r.voltages_v),
                                                 tau_mini85_nm=r.tau_reference_nm, tau_applied_nm=r.tau_true_nm)
                                for name, r in records.items()}, params)
    return 0


if __name__ == "__main__":
    sys.exit(main())
