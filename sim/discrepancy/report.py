"""Text and figures of a :class:`~sim.discrepancy.analysis.DiscrepancyResult`."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from sim.discrepancy.analysis import DiscrepancyResult
from sim.figures import save_figure

SIGNATURES_SHOWN = 6  # strongest signatures listed in the text report


def format_result(result: DiscrepancyResult) -> str:
    """A plain-text report: split, baseline RMSE, findings in order, what the log cannot reveal, verdict."""
    b = result.baseline
    lines = [f"Discrepancy analysis: fit part {b['split']['fit']}, held out {b['split']['held_out']} "
             f"({b['split']['fit_samples']} / {b['split']['held_out_samples']} samples, {b['split']['guard_s']} s "
             f"filter guards)"]
    for key, entry in b["free_parameters"].items():
        lines.append(f"  re-fitted baseline {key}: {entry['value']:.6g} (rig {entry['rig']:.6g})")
    lines.append("Baseline held-out RMSE: " + ", ".join(
        f"{c} {v:.4g} {result.units[c]}" if math.isfinite(v) else f"{c} n/a (no sample counts)"
        for c, v in b["rmse_heldout"].items()))
    lines.append("Strongest signatures in the baseline residual (held-out correlation; a shape the residual "
                 "resembles is a candidate, a finding needs the significance rule: held-out gain, ΔBIC, "
                 "consistency):")
    for s in b["signatures"][:SIGNATURES_SHOWN]:
        lines.append(f"  {s['channel']:>9s}  {s['signature']:<36s} {s['correlation']:+.3f}")
    if result.findings:
        lines.append("Findings, in the order accepted:")
        for i, f in enumerate(result.findings, 1):
            params = ", ".join(
                f"{k} = {v['value']:.5g} {v['unit']}" + (f" (baseline {v['baseline']:.5g})" if "baseline" in v else "")
                for k, v in f.parameters.items())
            ch = f.evidence.get("channel")
            lines.append(f"  {i}. {f.effect}: {params}")
            lines.append(f"     held-out RMSE {f.rmse_heldout_before:.4g} -> {f.rmse_heldout_after:.4g} "
                         f"({100 * f.gain:.1f} % better); evidence: '{f.evidence['signature']}' in the {ch} residual "
                         f"(correlation {f.evidence['correlation_before'] or 0:+.3f}), ΔBIC {f.evidence['delta_bic']:.1f}, "
                         f"consistency t {f.evidence['consistency_t']:.2f}")
    lines.append("The log cannot reveal:")
    for name, why in b["not_identifiable"].items():
        lines.append(f"  {name}: {why}")
    if result.replay:
        r = result.replay
        lines.append(f"MuJoCo replay of the held-out part ({r['windows']} windows of {r['window_s']} s, re-initialised "
                     f"from the measured state), {r['signal']}: RMSE baseline {r['rmse_baseline']:.4g} {r['unit']}, "
                     f"extended {r['rmse_extended']:.4g} {r['unit']}")
    lines.append(f"Verdict: {result.verdict}")
    return "\n".join(lines)


def plot_result(result: DiscrepancyResult, directory: Path) -> list[Path]:
    """Residuals before/after, their autocorrelation, the replay; PNG files in ``directory``."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    paths = []
    channels = list(result.residuals_baseline)
    fig, axes = plt.subplots(len(channels), 1, figsize=(10, 2.6 * len(channels)), squeeze=False)
    for ax, c in zip(axes[:, 0], channels, strict=True):
        ax.plot(result.time, result.residuals_baseline[c], lw=0.6, label="baseline")
        ax.plot(result.time, result.residuals_final[c], lw=0.6, label="extended")
        ax.axvspan(result.time[result.held][0], result.time[-1], color="0.9", zorder=0, label="held out")
        ax.set_ylabel(f"{c} [{result.units[c]}]")
        ax.legend(loc="upper right", fontsize=7)
    axes[-1, 0].set_xlabel("time [s]")
    fig.suptitle("Residuals (measured - model)")
    paths.append(save_figure(fig, directory, "discrepancy_residuals.png"))

    fig, ax = plt.subplots(figsize=(6, 3.5))
    for c in channels:
        r = result.residuals_baseline[c][result.held]
        r = r[np.isfinite(r)] - np.nanmean(r)
        lags = np.arange(0, min(500, len(r) // 2))
        ac = [float(r[: len(r) - k] @ r[k:]) / float(r @ r) for k in lags]
        ax.plot(lags * (result.time[1] - result.time[0]), ac, label=c)
    ax.set_xlabel("lag [s]")
    ax.set_ylabel("autocorrelation [1]")
    ax.set_title("Baseline residual autocorrelation (held out)")
    ax.legend()
    paths.append(save_figure(fig, directory, "discrepancy_autocorrelation.png"))

    sigs = result.baseline["signatures"][:10]
    fig, ax = plt.subplots(figsize=(7, 3.5))
    ax.barh([f"{s['signature']} ({s['channel']})" for s in sigs][::-1], [s["correlation"] for s in sigs][::-1])
    ax.set_xlabel("correlation with the baseline residual [1]")
    paths.append(save_figure(fig, directory, "discrepancy_signatures.png"))

    if result.replay:
        r = result.replay
        fig, ax = plt.subplots(figsize=(10, 3.5))
        ax.plot(r["time"], r["measured"], "k.", ms=1, label="measured")
        ax.plot(r["time"], r["simulated_baseline"], ".", ms=1, label=f"baseline (RMSE {r['rmse_baseline']:.3g})")
        ax.plot(r["time"], r["simulated_extended"], ".", ms=1, label=f"extended (RMSE {r['rmse_extended']:.3g})")
        ax.set_xlabel("time [s]")
        ax.set_ylabel(f"{r['signal']} [{r['unit']}]")
        ax.set_title(f"MuJoCo replay, windows of {r['window_s']} s from the measured state")
        ax.legend(markerscale=8)
        paths.append(save_figure(fig, directory, "discrepancy_replay.png"))
    return paths
