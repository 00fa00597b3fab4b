"""Sensor calibration and evaluation (paper Sec. III-A/B, Tables III-IV, the LS/QP resolution comparison).

    python -m experiments.calibration [--seed N] [--json PATH] [--plot DIR] [--params TOML]

Simulates the calibration rig (test weights to ±25 N·m five times each way, the T_x/T_y moment protocol),
fits LS and the paper's QP, evaluates the QP calibration on a second session of the same protocols, and
prints every figure beside the paper's, then the alternative readings of Tables III-IV the paper's text allows
(:data:`ALTERNATIVE_FIGURES`: the 50 N·m span as full scale, the max error on hold means, the crosstalk relative to
the applied moment and under a calibration that did not see the moment records) as rows of their own. Figures:
``calibration_channels.png`` (paper Fig. 6),
``calibration_nonlinearity.png`` (Fig. 7: nonlinearity and hysteresis, the curves whose peaks are Table III's),
``calibration_crosstalk_noise.png`` (Fig. 8(b)-(f): crosstalk, channel voltages under T_x / T_y, LS and QP noise).
"""

from __future__ import annotations

import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from experiments.common import (
    ALTERNATIVE,
    TARGET_RATIO,
    add_output_args,
    add_params_arg,
    add_rerun_args,
    cli_parser,
    format_rows,
    load_params_arg,
    paper_row,
    record_log,
    record_rerun,
    run_errors,
    seed_arg,
    write_outputs,
)
from sensor import metrics
from sensor.evaluation import SensorEvaluation, evaluate_sensor, measured_cycles
from sensor.protocol import CALIBRATION_LEVELS_NM, CROSSTALK_LEVELS_NM
from sim.figures import moving_mean, save_figure
from sim.params import TestbedParams

# the files --plot writes: Figs. 6, 7 and 8(b)-(f)
PLOT_FILES = ("calibration_channels.png", "calibration_nonlinearity.png", "calibration_crosstalk_noise.png")
CHANNELS_PNG, NONLINEARITY_PNG, CROSSTALK_PNG = PLOT_FILES
TABLE = "calibration"
# (figure name, table, quantity, unit, paper value); paper Tables III, IV and Sec. III-B.
PAPER_FIGURES: tuple[tuple[str, str, str, str, float], ...] = (
    ("max_error_pct_fs", "III", "max error", "% FS", 0.0830),
    ("rms_error_nm", "III", "RMS error", "N·m", 0.0266),
    ("nonlinearity_pct_fs", "III", "nonlinearity", "% FS", 0.111),
    ("hysteresis_pct_fs", "III", "hysteresis", "% FS", 0.139),
    ("repeatability_pct_fs", "IV", "repeatability", "% FS", 0.0849),
    ("crosstalk_tx_pct_fs", "IV", "crosstalk T_x", "% FS", 0.148),
    ("crosstalk_ty_pct_fs", "IV", "crosstalk T_y", "% FS", 0.126),
    ("ls_std_nm", "III-B resolution", "LS std", "N·m", 0.0160),
    ("ls_resolution_3sigma_nm", "III-B resolution", "LS 3-sigma resolution", "N·m", 0.0480),
    ("qp_std_nm", "III-B resolution", "QP std", "N·m", 0.00746),
    ("qp_resolution_3sigma_nm", "III-B resolution", "QP 3-sigma resolution", "N·m", 0.0224),
    ("qp_improvement", "III-B resolution", "QP improvement over LS", "x", 2.14),
)


def comparison_rows(figures: dict[str, tuple[float, str]],
                    paper: tuple[tuple[str, str, str, str, float], ...]) -> list[dict[str, Any]]:
    """Rows ``{table, quantity, unit, paper, sim, ratio}`` (ratio = sim / paper; None for a figure not
    simulated, ``figures[name][0]`` None) for the named figures."""
    return [paper_row(table, quantity, unit, value, figures[name][0]) for name, table, quantity, unit, value in paper]


def alternative_rows(figures: dict[str, tuple[float, str]],
                     alternatives: tuple[tuple[str, str, str, str, float, str], ...]) -> list[dict[str, Any]]:
    """Rows of alternative readings (:func:`experiments.common.paper_row` with ``reading="alternative"``) from
    ``(figure name, table, quantity, unit, paper value under that reading, reason)`` entries."""
    return [paper_row(table, quantity, unit, value, figures[name][0], reading=ALTERNATIVE, reason=reason)
            for name, table, quantity, unit, value, reason in alternatives]


@dataclass(frozen=True)
class CalibrationExperiment:
    """The evaluation and its comparison rows (:meth:`rows`); :meth:`plot` draws its figures."""

    evaluation: SensorEvaluation
    comparison: list[dict[str, Any]]

    def rows(self) -> list[dict[str, Any]]:
        """Every figure of Tables III-IV and the resolution comparison beside the paper's."""
        return self.comparison

    def to_dict(self) -> dict[str, Any]:
        return {"rows": self.rows(), "evaluation": self.evaluation.to_dict()}

    def plot(self, directory: Path) -> list[Path]:
        """Figs. 6-8 like the paper's, written to ``directory`` (paths)."""
        return plot_calibration(self.evaluation, directory)


def run_calibration(params: TestbedParams | None = None, seed: int = 0) -> CalibrationExperiment:
    """Calibrate and evaluate the default (or given) sensor unit: the paper's figures, then the alternative
    readings (:data:`ALTERNATIVE_FIGURES`)."""
    evaluation = evaluate_sensor(params or TestbedParams(), seed)
    return CalibrationExperiment(evaluation, comparison_rows(evaluation.figures, PAPER_FIGURES)
                                 + alternative_rows(evaluation.figures, ALTERNATIVE_FIGURES))


# Paper Sec. III-B: the peaks of Fig. 7(c) and (d), the deviation curves behind Table III's 0.111 and 0.139 % FS.
PAPER_FIG7_PEAK_PCT_FS = {"nonlinearity": 0.1106, "hysteresis": 0.1389}
PAPER_CROSSTALK_VOLTAGE_V = 0.06  # Sec. III-B: channel voltage change under 25 N·m of T_x or T_y (Fig. 8(c)-(d))
MAGNIFIED_HALF_WIDTH_NM = 0.3  # [N·m] half width of Fig. 7(b)'s window (the paper magnifies about -0.3 N·m)
CROSSTALK_PLOT_MEAN_S = 0.1  # [s] window of the running mean drawn over the raw crosstalk output (display only)


def paper_value(name: str, paper=PAPER_FIGURES) -> float:
    """The paper's value of the figure ``name`` in a table of ``(name, table, quantity, unit, value)`` rows."""
    return next(value for key, *_, value in paper if key == name)


CALIBRATION_SPAN_NM = 2 * max(CALIBRATION_LEVELS_NM)  # [N·m] the ±25 N·m calibration's span (Sec. III-A/B)
CROSSTALK_MOMENT_NM = max(CROSSTALK_LEVELS_NM)  # [N·m] the largest T_x / T_y moment applied (Sec. III-B)
SPAN_REASON = (f"Eq. 14 calls FS 'the full-scale span', {CALIBRATION_SPAN_NM:g} N·m for the ±"
               f"{max(CALIBRATION_LEVELS_NM):g} N·m calibration, where the FS sentence of Sec. III-B names 80 N·m.")


def _nm_of(name: str, reference_nm: float) -> float:
    """The paper's % figure ``name`` as a torque [N·m]: that percentage of ``reference_nm``."""
    return paper_value(name) * reference_nm / 100.0


# (figure name, table, quantity, unit, paper value under the reading, reason): the readings of Tables III-IV that
# the paper's text also allows (docs/fidelity.md, "Alternative readings"), reported beside the primary rows.
ALTERNATIVE_FIGURES: tuple[tuple[str, str, str, str, float, str], ...] = (
    ("max_error_level_means_pct_fs", "III", "max error, on the mean of each test-weight hold", "% FS",
     paper_value("max_error_pct_fs"),
     "The paper does not say whether its max error is over the raw 1 kHz samples or over each level's mean."),
    *((f"{name}_nm", table, f"{quantity}, {paper_value(f'{name}_pct_fs'):g} % of the {CALIBRATION_SPAN_NM:g} N·m "
       f"calibration span", "N·m", _nm_of(f"{name}_pct_fs", CALIBRATION_SPAN_NM), SPAN_REASON)
      for name, table, quantity in (("nonlinearity", "III", "nonlinearity"), ("hysteresis", "III", "hysteresis"),
                                    ("repeatability", "IV", "repeatability"))),
    *((f"crosstalk_t{axis}_nm", "IV", f"crosstalk T_{axis}, {paper_value(f'crosstalk_t{axis}_pct_fs'):g} % of "
       f"the {CROSSTALK_MOMENT_NM:g} N·m applied moment", "N·m",
       _nm_of(f"crosstalk_t{axis}_pct_fs", CROSSTALK_MOMENT_NM),
       "Crosstalk is commonly given relative to the applied off-axis moment, and the paper names no full scale "
       "for it beyond its general FS sentence.")
      for axis in "xy"),
    *((f"crosstalk_t{axis}_tz_only_pct_fs", "IV", f"crosstalk T_{axis}, calibrated on the T_z loading record alone",
       "% FS", paper_value(f"crosstalk_t{axis}_pct_fs"),
       "The paper does not say whether its calibration data included the T_x / T_y moment records.")
      for axis in "xy"),
)


@dataclass(frozen=True, eq=False)
class BranchFigure:
    """What Fig. 7 plots, from the metric functions on the samples Table III uses (preload cycles excluded).

    ``level_nm`` are the reference-torque bins holding both branches [N·m]; ``ascending_nm``,
    ``descending_nm``, ``average_nm`` the QP output of each branch and their mean there, ``line_nm`` the
    least-squares line of the mean [N·m]; ``nonlinearity_pct_fs`` the mean's deviation from the line and
    ``hysteresis_pct_fs`` the ascending minus the descending branch [% FS]. Their largest magnitudes are the
    table's nonlinearity and hysteresis. ``bin_width_nm``: width of the reference-torque bins [N·m].
    """

    level_nm: np.ndarray
    ascending_nm: np.ndarray
    descending_nm: np.ndarray
    average_nm: np.ndarray
    line_nm: np.ndarray
    nonlinearity_pct_fs: np.ndarray
    hysteresis_pct_fs: np.ndarray
    bin_width_nm: float


def branch_figure(ev: SensorEvaluation) -> BranchFigure:
    """Fig. 7's curves: :func:`sensor.metrics.nonlinearity` and :func:`~sensor.metrics.hysteresis` on the
    evaluation session's measured cycles (as :func:`sensor.evaluation.evaluate_sensor` calls them)."""
    m = measured_cycles(ev.evaluation_record, ev.qp)
    ref, out, direction, fs = m.reference_nm, m.output_nm, m.direction, ev.qp.fs_nm
    bc = metrics.branch_curves(ref, out, direction)
    nl = metrics.nonlinearity(ref, out, direction, fs_nm=fs)
    hy = metrics.hysteresis(ref, out, direction, fs_nm=fs)
    c = bc.level_nm[bc.both]
    asc, desc = c + bc.ascending_error_nm[bc.both], c + bc.descending_error_nm[bc.both]
    return BranchFigure(c, asc, desc, 0.5 * (asc + desc), nl.slope * c + nl.offset_nm,
                        100.0 * nl.deviation_nm / nl.fs_nm, 100.0 * hy.difference_nm / hy.fs_nm,
                        float(np.diff(bc.bin_edges_nm).mean()))


def crosstalk_trace(ev: SensorEvaluation, axis: str) -> tuple[np.ndarray, metrics.CrosstalkResult]:
    """Apparent T_z under the ``axis`` moment [N·m], tared on the unloaded samples as Table IV's crosstalk
    (:func:`sensor.metrics.crosstalk`), and that metric's result."""
    rec = ev.crosstalk_records[axis]
    tau, unloaded = ev.qp.predict(rec.voltages_v), rec.schedule.branch == 0
    return tau - tau[unloaded].mean(), metrics.crosstalk(tau, tare_mask=unloaded, fs_nm=ev.qp.fs_nm)


def plot_calibration(ev: SensorEvaluation, out_dir: Path) -> list[Path]:
    """Figures like the paper's Figs. 6-8: calibration, nonlinearity and hysteresis, crosstalk and noise."""
    import matplotlib
    matplotlib.use("Agg")

    return [plot_channels(ev, out_dir), plot_nonlinearity(ev, out_dir), plot_crosstalk_noise(ev, out_dir)]


def _pct_fs(torque_nm, fs_nm: float):
    return 100.0 * torque_nm / fs_nm


def _nm(pct_fs, fs_nm: float):
    return pct_fs * fs_nm / 100.0


def _fs_axis(ax, quantity: str, fs_nm: float) -> None:
    """A right-hand axis in % FS beside an axis in N·m."""
    ax.secondary_yaxis("right", functions=(lambda t: _pct_fs(t, fs_nm), lambda p: _nm(p, fs_nm))).set_ylabel(
        f"{quantity} [% FS]")


def plot_channels(ev: SensorEvaluation, out_dir: Path) -> Path:
    """Fig. 6: the calibration session's loading, the channel voltages against torque; and the QP error on
    the evaluation session (Table III's max and RMS error)."""
    import matplotlib.pyplot as plt

    rec = ev.calibration_record
    fig, ax = plt.subplots(1, 3, figsize=(16, 4.4))
    ax[0].plot(rec.time_s, rec.tau_reference_nm, lw=0.8)
    ax[0].set(xlabel="time [s]", ylabel="MINI85 torque [N·m]",
              title="(a) calibration session: a preload, then 5 cycles each way")
    step = max(1, len(rec.time_s) // 4000)
    for k in range(rec.voltages_v.shape[1]):
        ax[1].plot(rec.tau_reference_nm[::step], rec.voltages_v[::step, k], ".", ms=1, label=f"ch {k + 1}")
    ax[1].set(xlabel="MINI85 torque [N·m]", ylabel="channel voltage [V]", title="(b) the eight channels' responses")
    ax[1].legend(markerscale=8, fontsize=7, ncol=2)
    m = measured_cycles(ev.evaluation_record, ev.qp)
    ref, err = m.reference_nm, m.output_nm - m.reference_nm
    k = int(np.argmax(np.abs(err)))
    ax[2].plot(ref[::step], err[::step], ".", ms=1, label=f"1 sample in {step}")
    ax[2].plot(ref[k], err[k], "s", ms=8, mfc="none", color="tab:red", label="largest error")
    ax[2].legend(fontsize=8, loc="lower right")
    _fs_axis(ax[2], "error", ev.qp.fs_nm)
    (emax, _), (rms, _) = ev.figures["max_error_pct_fs"], ev.figures["rms_error_nm"]
    ax[2].set(xlabel="MINI85 torque [N·m]", ylabel="QP output - MINI85 [N·m]",
              title=f"(c) QP error, evaluation session (5 cycles each way)\nmax {emax:.3f} % FS (paper "
                    f"{paper_value('max_error_pct_fs'):.3f}), RMS {rms:.4f} N·m "
                    f"(paper {paper_value('rms_error_nm'):.4f})")
    fig.suptitle("Calibration experiment (paper Fig. 6; Table III's errors)", fontsize=11)
    return save_figure(fig, out_dir, CHANNELS_PNG)


def plot_nonlinearity(ev: SensorEvaluation, out_dir: Path) -> Path:
    """Fig. 7: branch average and its line, a magnified view, the nonlinearity and hysteresis deviations."""
    import matplotlib.pyplot as plt

    bf = branch_figure(ev)
    fig, ax = plt.subplots(2, 2, figsize=(12, 8.5))
    for a in ax[0]:
        a.plot(bf.level_nm, bf.ascending_nm, "-", color="tab:blue", lw=0.8, label="ascending branch")
        a.plot(bf.level_nm, bf.descending_nm, "-", color="tab:orange", lw=0.8, label="descending branch")
        a.plot(bf.level_nm, bf.average_nm, "o", ms=3, color="k", label="branch average")
        a.plot(bf.level_nm, bf.line_nm, "--", color="tab:red", lw=1.0, label="least-squares line of the average")
        a.set(xlabel="MINI85 torque [N·m]", ylabel="QP sensor output [N·m]")
    ax[0, 0].legend(fontsize=8)
    ax[0, 0].set_title(f"(a) branch average and its line ({bf.level_nm.size} bins of {bf.bin_width_nm:.2f} "
                       "N·m)")
    _magnify(ax[0, 1], bf, ev.qp.fs_nm)
    for a, values, name, title in (
            (ax[1, 0], bf.nonlinearity_pct_fs, "nonlinearity", "(c) nonlinearity: average - line"),
            (ax[1, 1], bf.hysteresis_pct_fs, "hysteresis", "(d) hysteresis: ascending - descending")):
        _deviation_panel(a, bf.level_nm, values, PAPER_FIG7_PEAK_PCT_FS[name], title, ev.qp.fs_nm)
    fig.suptitle("Nonlinearity and hysteresis of the QP calibration on the evaluation session, preload cycles "
                 "excluded (paper Fig. 7, Table III)", fontsize=11)
    return save_figure(fig, out_dir, NONLINEARITY_PNG)


def _magnify(ax, bf: BranchFigure, fs_nm: float) -> None:
    """Fig. 7(b): a window of ``MAGNIFIED_HALF_WIDTH_NM`` about the largest nonlinearity, its deviation drawn."""
    k = int(np.argmax(np.abs(bf.nonlinearity_pct_fs)))
    c, h = bf.level_nm[k], MAGNIFIED_HALF_WIDTH_NM
    ends = np.interp([c - h, c + h], bf.level_nm, bf.line_nm)
    ax.set_xlim(c - h, c + h)
    ax.set_ylim(ends[0] - 0.6 * h, ends[1] + 0.6 * h)
    ax.annotate("", xy=(c, bf.average_nm[k]), xytext=(c, bf.line_nm[k]),
                arrowprops={"arrowstyle": "<->", "color": "tab:red", "shrinkA": 0, "shrinkB": 0})
    ax.text(c + 0.03 * h, 0.5 * (bf.average_nm[k] + bf.line_nm[k]),
            f" {_nm(abs(bf.nonlinearity_pct_fs[k]), fs_nm):.3f} N·m", color="tab:red", va="center", fontsize=8)
    ax.set_title(f"(b) magnified around {c:.1f} N·m, the largest deviation from the line")


def _deviation_panel(ax, level_nm: np.ndarray, values_pct_fs: np.ndarray, paper_peak: float, title: str,
                     fs_nm: float) -> None:
    """A deviation curve [% FS] against torque, its peak marked beside the paper's (dotted, both signs)."""
    k = int(np.argmax(np.abs(values_pct_fs)))
    ax.plot(level_nm, values_pct_fs, "o-", ms=3, lw=1.0, label="simulated")
    ax.plot(level_nm[k], values_pct_fs[k], "s", ms=8, mfc="none", color="tab:red",
            label=f"peak {abs(values_pct_fs[k]):.4f} % FS at {level_nm[k]:.1f} N·m")
    for sign in (1, -1):
        ax.axhline(sign * paper_peak, color="0.4", ls=":",
                   label=f"paper's peak {paper_peak} % FS" if sign > 0 else None)
    ax.axhline(0.0, color="0.8", lw=0.6)
    ax.set(xlabel="MINI85 torque [N·m]", ylabel="deviation [% FS]", title=title)
    ax.secondary_yaxis("right", functions=(lambda p: _nm(p, fs_nm), lambda t: _pct_fs(t, fs_nm))).set_ylabel(
        "deviation [N·m]")
    ax.legend(fontsize=8)


def plot_crosstalk_noise(ev: SensorEvaluation, out_dir: Path) -> Path:
    """Fig. 8(b)-(f): apparent T_z and the channel voltages under T_x and under T_y, each with the applied
    moment; the no-load output of the LS and the QP calibration."""
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(2, 3, figsize=(18, 10))
    for col, (axis, letter) in enumerate((("x", "c"), ("y", "d"))):
        _crosstalk_panel(ax[0, col], ev, axis)
        _voltage_panel(ax[1, col], ev, axis, letter)
    res = ev.resolution_record
    for a, cal, name, letter in ((ax[0, 2], ev.ls, "ls", "e"), (ax[1, 2], ev.qp, "qp", "f")):
        a.plot(res.time_s, cal.predict(res.voltages_v), lw=0.4)
        std, res3 = ev.figures[f"{name}_std_nm"][0], ev.figures[f"{name}_resolution_3sigma_nm"][0]
        a.set(xlabel="time [s]", ylabel="torque, no load [N·m]",
              title=f"({letter}) {name.upper()} calibration: no load, 1 kHz, unfiltered\nσ {std:.4f} N·m (paper "
                    f"{paper_value(f'{name}_std_nm')}),\n3σ {res3:.4f} N·m (paper "
                    f"{paper_value(f'{name}_resolution_3sigma_nm')})")
    ax[1, 2].sharey(ax[0, 2])
    fig.suptitle("Crosstalk and resolution (paper Fig. 8(b)-(f), Table IV, Sec. III-B)", fontsize=11)
    return save_figure(fig, out_dir, CROSSTALK_PNG)


def _moment(ev: SensorEvaluation, axis: str) -> np.ndarray:
    schedule = ev.crosstalk_records[axis].schedule
    return schedule.tx_nm if axis == "x" else schedule.ty_nm


def _twin_moment(ax, time_s: np.ndarray, moment_nm: np.ndarray, axis: str):
    twin = ax.twinx()
    twin.plot(time_s, moment_nm, color="0.3", lw=1.2, ls="--", label=f"applied T_{axis} (right axis)")
    twin.set_ylabel(f"applied T_{axis} [N·m]")
    return twin


def _crosstalk_panel(ax, ev: SensorEvaluation, axis: str) -> None:
    """Fig. 8(b), one axis: the tared apparent T_z (raw and a running mean), its peak, the applied moment."""
    rec = ev.crosstalk_records[axis]
    apparent, xt = crosstalk_trace(ev, axis)
    n = max(1, round(CROSSTALK_PLOT_MEAN_S / float(rec.time_s[1] - rec.time_s[0])))
    ax.plot(rec.time_s, apparent, lw=0.3, color="tab:blue", alpha=0.5, label="apparent T_z, 1 kHz samples")
    ax.plot(rec.time_s[n - 1:], moving_mean(apparent, n), lw=1.2, color="navy",
            label=f"apparent T_z, {CROSSTALK_PLOT_MEAN_S:g} s mean")
    ax.plot(rec.time_s[xt.at_index], apparent[xt.at_index], "s", ms=8, mfc="none", color="tab:red",
            label="largest |apparent T_z|: the crosstalk")
    paper = paper_value(f"crosstalk_t{axis}_pct_fs")
    for sign in (1, -1):
        ax.axhline(sign * _nm(paper, ev.qp.fs_nm), color="0.4", ls=":",
                   label=f"paper's crosstalk {paper} % FS" if sign > 0 else None)
    ax.set(xlabel="time [s]", ylabel="apparent T_z, tared at no load [N·m]",
           title=f"(b) crosstalk under T_{axis}: QP output with T_z = 0\n"
                 f"{xt.crosstalk_pct_fs:.3f} % FS (paper {paper} % FS)")
    twin = _twin_moment(ax, rec.time_s, _moment(ev, axis), axis)
    _joint_legend(ax, twin, ncol=2)


def _voltage_panel(ax, ev: SensorEvaluation, axis: str, letter: str) -> None:
    """Fig. 8(c)/(d): each channel's voltage change from its no-load mean under the applied moment."""
    rec = ev.crosstalk_records[axis]
    dv_mv = 1e3 * (rec.voltages_v - rec.voltages_v[rec.schedule.branch == 0].mean(axis=0))
    step = max(1, len(rec.time_s) // 6000)
    for k in range(dv_mv.shape[1]):
        ax.plot(rec.time_s[::step], dv_mv[::step, k], lw=0.5, label=f"ch {k + 1}")
    ax.set(xlabel="time [s]", ylabel="channel voltage change [mV]",
           title=f"({letter}) channel voltages under T_{axis}\nlargest change {np.abs(dv_mv).max():.0f} mV "
                 f"(paper about {1e3 * PAPER_CROSSTALK_VOLTAGE_V:.0f} mV)")
    twin = _twin_moment(ax, rec.time_s, _moment(ev, axis), axis)
    _joint_legend(ax, twin, ncol=5)


def _joint_legend(ax, twin, ncol: int) -> None:
    """One legend for an axis and its twin, below the axes (clear of the traces)."""
    handles, labels = ax.get_legend_handles_labels()
    h2, l2 = twin.get_legend_handles_labels()
    ax.legend(handles + h2, labels + l2, fontsize=8, ncol=ncol, loc="upper center", bbox_to_anchor=(0.5, -0.13))


def main(argv: list[str] | None = None) -> int:
    parser = cli_parser(__doc__, __spec__.name)
    parser.add_argument("--seed", type=seed_arg, default=0, help="seed of every noise draw (default 0)")
    add_output_args(parser, "write {rows: [...]} and the calibrations", PLOT_FILES)
    add_params_arg(parser)
    add_rerun_args(parser, "the rig records (channel voltages, MINI85 and QP-sensor torque; no mechanics, no 3D)")
    args = parser.parse_args(argv)
    params = load_params_arg(parser, args)
    print("calibrating on the simulated rig (T_z loading, T_x/T_y moments) and evaluating ...", file=sys.stderr)
    with run_errors(parser):
        result = run_calibration(params, args.seed)
    print(format_rows("Sensor calibration and evaluation (Tables III-IV, the resolution comparison)", result.rows(),
                      band=TARGET_RATIO))
    sel = result.evaluation.gamma_selection
    print(f"\nQP: gamma = {sel.gamma:g} chosen by RMSE^2 + {sel.lambda_weight:g} Var(quiet); "
          f"{result.evaluation.qp.diagnostics.n_active_constraints} active error bounds")
    write_outputs(args, result.to_dict(), result.plot)
    ev = result.evaluation
    records = {"calibration": ev.calibration_record, "evaluation": ev.evaluation_record,
               "no load": ev.resolution_record}
    record_rerun(args, lambda: {name: record_log(r.time_s, r.voltages_v, tau_sensor_nm=ev.qp.predict(r.voltages_v),
                                                 tau_mini85_nm=r.tau_reference_nm, tau_applied_nm=r.tau_true_nm)
                                for name, r in records.items()}, params)
    return 0


if __name__ == "__main__":
    sys.exit(main())
