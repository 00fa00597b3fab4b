"""Text and figures of a :class:`~sim.discrepancy.analysis.DiscrepancyResult`."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from sim.discrepancy.analysis import DiscrepancyResult
from sim.discrepancy.effects import EFFECTS
from sim.figures import save_figure

# the figures plot_result writes (the replay's only when the replay ran)
PLOT_FILES = ("discrepancy_residuals.png", "discrepancy_autocorrelation.png", "discrepancy_signatures.png",
              "discrepancy_replay.png")
RESIDUALS_PNG, AUTOCORRELATION_PNG, SIGNATURES_PNG, REPLAY_PNG = PLOT_FILES
SIGNATURES_SHOWN = 6  # strongest signatures listed in the text report
Y_PERCENTILES = (0.5, 99.5)  # residual figures: the y-range holds these percentiles of the samples that count
Y_MARGIN = 0.15  # ... plus this share of the range each way
MAX_LAG_S = 0.5  # autocorrelation figure: lags up to this [s]


def _value(entry: dict) -> str:
    """'value unit (rig ..., fit range [low, high])'."""
    unit = "" if entry["unit"] == "1" else entry["unit"]  # dimensionless
    text = f"{entry['value']:.5g} {unit}".rstrip()
    notes = []
    if "baseline" in entry:
        notes.append(f"rig {entry['baseline']:.5g}")
    if "bounds" in entry:
        low, high = entry["bounds"]
        notes.append(f"fit range [{low:.4g}, {high:.4g}]")
    if "bound" in entry:
        notes.append(f"not resolved: {entry['bound']}")
    return text + (f" ({'; '.join(notes)})" if notes else "")


def _free(entry: dict) -> str:
    """'value unit (rig ...; range [low, high])', and the bound it ends at."""
    low, high = entry["bounds"]
    text = (f"{entry['value']:.6g} {entry['unit']} (rig {entry['rig']:.6g}; range [{low:.4g}, {high:.4g}] "
            f"{entry['unit']})")
    if "saved_as" in entry:
        text += f"; in the rig file {entry['saved_as']['field']} = {entry['saved_as']['value']:.6g}"
    if "at_bound" in entry:
        text += (f"; at the {entry['at_bound']} bound: the rig's value is far off, or another effect pulls it "
                 f"there")
    return text


def _zeros(entry: dict) -> str:
    """'effort +0.12 N·m, sensor -0.03 N·m': each channel's own zero of a log."""
    return ", ".join(f"{c} {v['value']:+.4g} {v['unit']}" for c, v in entry.items() if c != "log")


def format_result(result: DiscrepancyResult) -> str:
    """A plain-text report: split, baseline, the time convention, findings in order, refused candidates, the
    tentative effects, the final model (the saved rig), the unexplained remainder, each log's relative effort error,
    what the logs cannot reveal, the verdict."""
    b = result.baseline
    split = b["split"]
    if "logs" in split:
        parts = "; ".join(f"{entry['log']} ({entry['role']}, fitted: {entry['fitted']})" for entry in split["logs"])
        lines = [f"Discrepancy analysis of {len(split['logs'])} logs: {parts}"]
    else:
        lines = [f"Discrepancy analysis: fit part {split['fit']}, held out {split['held_out']}"]
    lines[0] += (f"; {split['fit_samples']} / {split['held_out_samples']} analysis-grid samples fit / held out, "
                 f"{split['guard_s']} s filter guards")
    for entry in b["time_convention"]:
        lines.append(f"  time convention of {entry['log']}, as first read: {entry['time_convention']} "
                     f"({entry['from']})")
    for key, entry in b["free_parameters"].items():
        lines.append(f"  re-fitted baseline {key}: {_free(entry)}")
    for entry in b.get("record_offsets") or []:
        lines.append(f"  {entry['log']}: its own zero (the rig's record_offsets), " + _zeros(entry))
    lines.append("Baseline held-out RMSE: " + ", ".join(
        f"{c} {v:.4g} {result.units[c]}" if math.isfinite(v) else f"{c} n/a (no held-out samples)"
        for c, v in b["rmse_heldout"].items()))
    lines.append("Strongest signatures in the baseline residual (held-out correlation; a shape the residual "
                 "resembles is a candidate, a finding needs the significance rule):")
    for s in b["signatures"][:SIGNATURES_SHOWN]:
        lines.append(f"  {s['channel']:>9s}  {s['signature']:<40s} {s['correlation']:+.3f}  ({s['effect']})")
    if b.get("time_convention_mismatch"):
        lines.append(f"Time convention: {b['time_convention_mismatch']}")
        if result.findings:
            lines.append(f"  read so, the rig's held-out {result.findings[0].evidence['channel']} RMSE is "
                         f"{result.findings[0].rmse_heldout_before:.4g}")
    if result.findings:
        lines.append("Findings, in the order accepted (the values saved; held-out RMSE of the final model with the "
                     "findings up to each):")
        for i, f in enumerate(result.findings, 1):
            params = ", ".join(f"{k} = {_value(v)}" for k, v in f.parameters.items())
            what = "re-fit of the rig's value" if f.kind == "re-fit" else "new to the rig"
            ev = f.evidence
            correlation = ev["correlation_before"]
            lines.append(f"  {i}. {f.effect} ({what}): {params}")
            lines.append(f"     held-out {ev['channel']} RMSE {f.rmse_heldout_before:.4g} -> "
                         f"{f.rmse_heldout_after:.4g} ({100 * f.gain:.1f} % better); ΔBIC {ev['delta_bic']:.1f}, "
                         f"events z {ev['event_z']:.2f}"
                         + (f"; '{ev['signature']}' correlates {correlation:+.3f} with the residual before"
                            if correlation is not None and math.isfinite(correlation) else ""))
            low = ev.get("low_speed")
            if low:
                fit = low.get("fit") or {}
                lines.append(f"     low-speed windows held out: position error {low['rmse_before']:.3g} -> "
                             f"{low['rmse_after']:.3g} {low['unit']} RMS"
                             + (f"; fitted on {fit['windows']} windows of the fit part, "
                                + (f"v_s within [{fit['interval'][0]:.3g}, {fit['interval'][1]:.3g}]"
                                   if fit["resolved"] else f"{fit['bound']} (the log shows no slower sliding)")
                                if fit else ""))
            for alt in ev.get("alternatives") or []:
                lines.append(f"     the log tells it only weakly from {alt['effect']} (held-out "
                             f"{alt['rmse_heldout_after']:.4g} instead of {f.evidence['rmse_accepted']:.4g} when it "
                             f"was accepted; " + ", ".join(f"{k} = {v:.4g}" for k, v in alt["parameters"].items())
                             + ")")
    if result.rejected:
        lines.append("Refused candidates with a held-out gain of 10 % or more (and the rule that refused them):")
        for r in result.rejected:
            params = ", ".join(f"{k} = {_value({'value': v['value'], 'unit': v['unit']})}"
                               for k, v in r["parameters"].items())
            note = f"; {r['note']}" if r["note"] else ""
            sides = ", ".join(f"{k} ({side})" for k, side in r["at_bound"].items())
            bound = f"; at bound: {sides}" if sides else ""
            lines.append(f"  {r['effect']}: {100 * r['gain']:.1f} % gain, refused by '{r['rejected_by']}' "
                         f"({params}{bound}{note})")
    if result.tentative:
        lines.append("Tentative, not saved (values of the search's model, which held them):")
        for f in result.tentative:
            params = ", ".join(f"{k} = {_value(v)}" for k, v in f.parameters.items())
            lines.append(f"  {f.effect}: {params}; {f.evidence.get('why_not_saved', '')}")
    final = result.final
    if final:
        lines.append("Final model (what --save-rig writes, read back on the logs): held-out RMSE "
                     + ", ".join(f"{c} {v:.4g} {result.units[c]}" if math.isfinite(v) else f"{c} n/a"
                                 for c, v in final["rmse_heldout"].items()))
        for key, entry in final.get("free_parameters", {}).items():
            lines.append(f"  re-fitted {key}: {_free(entry)}")
        for entry in final.get("record_offsets") or []:
            lines.append(f"  {entry['log']}: its own zero, " + _zeros(entry))
    s = result.structure
    if s.unexplained:
        lines.append("Unexplained: the residual holds a discrepancy the library does not name:")
        lines += [f"  {line}" for line in s.description + s.refused]
    lines.append("Residual left (held out): " + ", ".join(f"{c} {v:.4g} {result.units[c]}"
                                                          for c, v in s.rmse.items() if math.isfinite(v))
                 + f"; effort error in a typical {result.baseline['config']['block_s']:g} s block (median) "
                 f"{100 * s.remainder_fraction:.2g} % of the command's RMS"
                 + f"; a generic model of it explains {max(100 * s.generic_gain, 0.0):.1f} %; Ljung-Box p "
                 f"{s.whiteness.get('p_value', float('nan')):.3g}; the position encoder's resolution alone leaves "
                 f"{s.resolution_floor:.3g} {result.units['effort']}")
    lines.append("Relative effort prediction error ‖F - F̂‖/‖F‖ (F the command in the analysis band):")
    for entry in result.logs:
        e = entry["relative_effort_error"]
        tentative = (f" (with the tentative effects as well: {e['with_tentative']:.4f})"
                     if "with_tentative" in e else "")
        zero = "; its own zero fitted on it" if entry.get("own_zero") and entry["role"] == "validation" else ""
        lines.append(f"  {entry['log']} ({entry['role']}, {entry['scored']}{zero}): baseline {e['baseline']:.4f}, "
                     f"final model {e['final']:.4f}{tentative}")
    if b["not_identifiable"]:
        lines.append("The logs cannot reveal:")
    for name, why in b["not_identifiable"].items():
        effect = EFFECTS[name]
        fine = ", with a fine motor encoder" if effect.needs_fine_motor_encoder else ""
        lines.append(f"  {name}: {why} (the {effect.revealing_experiment!r} experiment reveals it{fine})")
    if result.replay.get("skipped"):
        lines.append(f"MuJoCo replay skipped: {result.replay['skipped']}")
    elif result.replay:
        r = result.replay
        lines.append(f"MuJoCo replay of the held-out part ({r['windows']} windows of {r['window_s']} s, re-initialised "
                     f"from the measured state), {r['signal']}: RMSE baseline {r['rmse_baseline']:.4g} {r['unit']}, "
                     f"extended {r['rmse_extended']:.4g} {r['unit']}")
        if r.get("skipped_samples"):
            lines.append(f"  {r['skipped_samples']} samples not replayed: window starts moved past slips of the gear")
    lines.append(f"Verdict: {result.verdict}")
    return "\n".join(lines)


def robust_limits(*series: np.ndarray) -> tuple[float, float] | None:
    """A y-range holding ``Y_PERCENTILES`` of the finite samples of ``series``, with a margin (None: none)."""
    values = np.concatenate([s[np.isfinite(s)] for s in series])
    if not len(values):
        return None
    low, high = np.percentile(values, Y_PERCENTILES)
    span = high - low or max(abs(high), 1e-12)
    return float(low - Y_MARGIN * span), float(high + Y_MARGIN * span)


def plot_result(result: DiscrepancyResult, directory: Path) -> list[Path]:
    """Residuals before/after, their autocorrelation, the signatures, the replay; PNG files in ``directory``."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    paths = []
    counted = result.fit | result.held
    channels = [c for c, r in result.residuals_baseline.items() if np.isfinite(r[counted]).any()]
    fig, axes = plt.subplots(max(len(channels), 1), 1, figsize=(10, 2.6 * max(len(channels), 1)), squeeze=False)
    for ax, c in zip(axes[:, 0], channels, strict=False):
        before = np.where(counted, result.residuals_baseline[c], np.nan)
        after = np.where(counted, result.residuals_final[c], np.nan)
        ax.plot(result.time, before, lw=0.6, label="baseline")
        ax.plot(result.time, after, lw=0.6, label="final model")
        if result.held.any():
            ax.axvspan(result.time[result.held][0], result.time[result.held][-1], color="0.9", zorder=0,
                       label="held out")
        limits = robust_limits(before, after)
        if limits:
            ax.set_ylim(*limits)
        ax.set_ylabel(f"{c} [{result.units[c]}]")
        ax.legend(loc="upper right", fontsize=7)
    axes[-1, 0].set_xlabel("time [s]")
    fig.suptitle("Residuals (measured - model) where they count (filter guards left out)")
    paths.append(save_figure(fig, directory, RESIDUALS_PNG))

    fig, ax = plt.subplots(figsize=(6, 3.5))
    step = float(result.time[1] - result.time[0]) if len(result.time) > 1 else 1.0
    for c in channels:
        r = result.residuals_baseline[c][result.held]
        r = r[np.isfinite(r)]
        if len(r) < 4:
            continue
        r = r - r.mean()
        lags = np.arange(0, min(int(MAX_LAG_S / step), len(r) // 2))
        ac = [float(r[: len(r) - k] @ r[k:]) / float(r @ r) if r @ r > 0 else 0.0 for k in lags]
        ax.plot(lags * step, ac, label=c)
    ax.set_xlabel("lag [s]")
    ax.set_ylabel("autocorrelation [1]")
    ax.set_title("Baseline residual autocorrelation (held out)")
    if channels:
        ax.legend()
    paths.append(save_figure(fig, directory, AUTOCORRELATION_PNG))

    sigs = result.baseline["signatures"][:10]
    fig, ax = plt.subplots(figsize=(7, 3.5))
    ax.barh([f"{s['signature']} ({s['channel']})" for s in sigs][::-1], [s["correlation"] for s in sigs][::-1])
    ax.set_xlabel("correlation with the baseline residual [1]")
    paths.append(save_figure(fig, directory, SIGNATURES_PNG))

    r = result.replay
    if r and not r.get("skipped"):
        fig, ax = plt.subplots(figsize=(10, 3.5))
        ax.plot(r["time"], r["measured"], "k.", ms=1, label="measured")
        ax.plot(r["time"], r["simulated_baseline"], ".", ms=1, label=f"baseline (RMSE {r['rmse_baseline']:.3g})")
        ax.plot(r["time"], r["simulated_extended"], ".", ms=1, label=f"extended (RMSE {r['rmse_extended']:.3g})")
        ax.set_xlabel("time [s]")
        ax.set_ylabel(f"{r['signal']} [{r['unit']}]")
        ax.set_title(f"MuJoCo replay, windows of {r['window_s']} s from the measured state")
        ax.legend(markerscale=8)
        paths.append(save_figure(fig, directory, REPLAY_PNG))
    return paths
