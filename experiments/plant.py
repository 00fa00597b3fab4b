"""Model card: every parameter with unit and source, and the derived and simulated quantities.

    python -m experiments.plant [--params TOML] [--json PATH] [--plot DIR | --no-plot] [--rerun PATH.rrd]
                                [--rerun-spawn]

--plot DIR (default out/) saves ``plant.png``: the motor's current-to-torque map with its driver limit, and the
two measurements the card simulates (breakaway ramp, backlash reversal) beside their parameters.

--rerun / --rerun-spawn record the two measurements the card simulates tick by tick: the breakaway ramp (free
fixture) and the backlash reversal (locked fixture), as they ran for the card (no extra simulation).
"""

from __future__ import annotations

import argparse
import textwrap
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from experiments.common import (
    add_output_args,
    add_params_arg,
    add_rerun_args,
    load_params_arg,
    record_rerun,
    rerun_requested,
    write_outputs,
)
from models.gim8108_testbed.derived import (
    FIXTURES,
    derive,
    lumped_modes_hz,
    physics_timestep,
    substeps_by_rule,
)
from sim.characterize import (
    linearizable_plant,
    linearized_modes,
    measure_backlash,
    measure_breakaway,
)
from sim.figures import save_figure
from sim.motor_torque import CurrentToTorqueMap
from sim.params import TestbedParams, bound_source, bounded_fields, source_bound
from sim.runlog import RunLog

PLOT_FILES = ("plant.png",)  # the files --plot writes

PAPER_FLEXURE_MODE_ESTIMATE_HZ = 5975.0  # paper Sec. II, sqrt(k_z/J_z)/2π
PAPER_FLEXURE_MODE_FEA_HZ = 3407.0  # paper Sec. II and Table II, SolidWorks first mode
LOCKED_PRELOAD_NM = 1.0  # closes the backlash for the locked fixture's linearisation
CARD_WIDTH = 160  # characters per line of the printed card (sources wrap)


@dataclass(frozen=True)
class PlantCard:
    """Parameters (value, unit, source) and derived quantities (value, unit) of a parameter set; ``logs``:
    the run logs of the simulated measurements (run name -> RunLog) when asked for (not part of the card's
    JSON)."""

    parameters: dict[str, dict[str, Any]]
    derived: dict[str, dict[str, Any]]
    modes: dict[str, list[dict[str, float]]] = field(default_factory=dict)
    logs: dict[str, RunLog] = field(default_factory=dict, repr=False, compare=False)

    def to_dict(self) -> dict[str, Any]:
        return {"parameters": self.parameters, "derived": self.derived, "modes": self.modes}


BREAKAWAY_RUN = "breakaway ramp, free"
BACKLASH_RUN = "backlash reversal, locked"


def run_plant_card(params: TestbedParams | None = None, *, keep_logs: bool = False) -> PlantCard:
    """Compute the model card: closed forms, step rule, modes and simulated breakaway and backlash.

    Parameters
    ----------
    params : TestbedParams, optional
        The parameter set (defaults if None).
    keep_logs : bool
        Also keep the run logs of the breakaway ramp and the backlash reversal (``PlantCard.logs``, under
        ``BREAKAWAY_RUN`` and ``BACKLASH_RUN``); the card's figures are the same.
    """
    p = params or TestbedParams()
    d = derive(p)
    derived: dict[str, dict[str, Any]] = {}

    def put(name: str, value: float, unit: str) -> None:
        derived[name] = {"value": float(value), "unit": unit}

    put("flexure_stiffness", d.flexure_stiffness_nm_per_rad, "N·m/rad")
    put("flexure_youngs_modulus", p.flexure.youngs_modulus_pa, "Pa")
    put("flexure_shear_modulus", d.flexure_shear_modulus_pa, "Pa")
    put("spoke_stiffness", d.spoke_stiffness_n_per_m, "N/m")
    put("hub_inertia", d.hub_inertia_kgm2, "kg·m²")
    put("flexure_mode", d.flexure_mode_hz, "Hz")
    put("flexure_mode_paper_estimate", PAPER_FLEXURE_MODE_ESTIMATE_HZ, "Hz")
    put("flexure_mode_paper_fea", PAPER_FLEXURE_MODE_FEA_HZ, "Hz")
    put("reflected_rotor_inertia", d.reflected_rotor_inertia_kgm2, "kg·m²")
    put("output_flange_hub_inertia", d.output_inertia_kgm2, "kg·m²")
    put("lever_side_inertia", d.lever_side_inertia_kgm2, "kg·m²")
    put("tip_support_stiffness", d.tip_support_stiffness_n_per_m, "N/m")
    put("flexure_twist_per_torque", 1.0 / d.flexure_stiffness_nm_per_rad, "rad/(N·m)")
    put("sensing_surface_displacement_at_25nm",
        25.0 / d.flexure_stiffness_nm_per_rad * p.flexure.sensing_radius_m, "m")
    # the driver's current limit as a command: what delivers motor.peak_torque_nm through the torque droop
    put("driver_command_limit", CurrentToTorqueMap.from_params(p).command_limit_nm, "N·m")
    modes: dict[str, list[dict[str, float]]] = {}
    for fixture in FIXTURES:
        h, n = physics_timestep(p, fixture)
        put(f"physics_timestep_{fixture}", h, "s")
        put(f"substeps_{fixture}", n, "1")
        for rule, needed in substeps_by_rule(p, fixture).items():  # which rule sets the step (and the speed)
            put(f"substeps_{fixture}_{rule}_rule", needed, "1")
        closed = fixture == "locked"
        lumped = [f for f in lumped_modes_hz(p, fixture, closed, True) if f > 0]
        for i, f in enumerate(lumped):
            put(f"lumped_mode_{fixture}_{i + 1}", f, "Hz")
        preload = LOCKED_PRELOAD_NM if closed else 0.0
        modes[fixture] = [m.to_dict() for m in linearized_modes(linearizable_plant(p, fixture, preload))]
    control = modes["locked"][0]
    put("locked_control_mode_natural_frequency", control["natural_frequency_hz"], "Hz")
    put("locked_control_mode_damping_ratio", control["damping_ratio"], "1")
    breakaway = measure_breakaway(p, keep_log=keep_logs)
    backlash = measure_backlash(p, keep_log=keep_logs)
    put("breakaway_torque_measured", breakaway.torque_nm, "N·m")
    put("breakaway_torque_parameter", p.friction.breakaway_torque_nm, "N·m")
    put("backlash_width_measured", backlash.width_rad, "rad")
    put("backlash_width_parameter", p.backlash.width_rad, "rad")
    bounded = set(bounded_fields())
    parameters = {name: {"value": value, "unit": unit, "source": source}
                  | ({"bound": list(source_bound(name)), "bound_source": bound_source(name)} if name in bounded else {})
                  for name, value, unit, source in p.rows()}
    logs = {BREAKAWAY_RUN: breakaway.log, BACKLASH_RUN: backlash.log} if keep_logs else {}
    return PlantCard(parameters, derived, modes, logs)


def _bound_text(row: dict[str, Any]) -> str:
    """``[lo, hi]`` of a bounded parameter's row, ``!`` appended if its value lies outside; "" if unbounded."""
    if "bound" not in row:
        return ""
    lo, hi = row["bound"]
    return f"[{lo:g}, {hi:g}]" + ("" if lo <= row["value"] <= hi else " !")


def format_card(card: PlantCard) -> str:
    """The card as text tables, no line longer than :data:`CARD_WIDTH` characters (sources wrap)."""
    lines = ["Parameters (bound: what the source allows; ! a value outside it)",
             f"{'name':44s} {'value':>12s}  {'unit':10s} {'bound':22s} source", "-" * 110]
    for name, row in card.parameters.items():
        value = f"{row['value']:>12s}" if isinstance(row["value"], str) else f"{row['value']:12.6g}"  # a choice
        head = f"{name:44s} {value}  {row['unit']:10s} {_bound_text(row):22s} "
        source = textwrap.wrap(row["source"], CARD_WIDTH - len(head), break_on_hyphens=False) or [""]
        lines += [head + source[0]] + [" " * len(head) + rest for rest in source[1:]]
    lines += ["", "Derived and simulated", f"{'quantity':44s} {'value':>12s}  unit", "-" * 70]
    for name, row in card.derived.items():
        lines.append(f"{name:44s} {row['value']:12.6g}  {row['unit']}")
    lines += ["", "Linearised modes (mjd_transitionFD; locked under a 1 N·m preload, free at rest)"]
    for fixture, modes in card.modes.items():
        for m in modes:
            lines.append(f"  {fixture:6s} f_n = {m['natural_frequency_hz']:8.1f} Hz   ζ = {m['damping_ratio']:.3f}")
    d = card.derived
    ratio_fea = d["flexure_mode"]["value"] / PAPER_FLEXURE_MODE_FEA_HZ
    lines += ["", f"Flexure torsional mode sqrt(K_t/J_hub)/2π = {d['flexure_mode']['value']:.0f} Hz; paper: "
              f"{PAPER_FLEXURE_MODE_ESTIMATE_HZ:.0f} Hz estimate, {PAPER_FLEXURE_MODE_FEA_HZ:.0f} Hz FEA "
              f"(ratio to FEA {ratio_fea:.2f})"]
    return "\n".join(lines)


def plot_card(card: PlantCard, params: TestbedParams, directory: Path) -> Path:
    """Figure of the motor map and the simulated breakaway and backlash (``card.logs`` needed) [PNG path]."""
    import matplotlib.pyplot as plt
    import numpy as np

    motor = CurrentToTorqueMap.from_params(params)
    limit, peak = motor.command_limit_nm, params.motor.peak_torque_nm
    fig, (ax_map, ax_brk, ax_bl) = plt.subplots(1, 3, figsize=(14, 4))
    command = np.linspace(0.0, 1.15 * limit, 400)
    applied = np.minimum(command, limit)
    ax_map.plot(command, applied, "k--", lw=1, label="driver's estimate (linear in current)")
    ax_map.plot(command, motor.delivered_nm(applied), "C0", label="delivered torque")
    ax_map.axhline(peak, color="C3", lw=0.8, ls=":", label=f"peak {peak:g} N·m (paper Sec. II)")
    ax_map.axvline(limit, color="C2", lw=0.8, ls=":", label=f"driver limit {limit:.1f} N·m")
    ax_map.set(xlabel="torque command [N·m]", ylabel="torque [N·m]",
               title=f"motor: current-to-torque map\nα = {motor.saturation_per_nm:g} /(N·m), τ = c/(1 + α|c|)")
    ax_map.legend(fontsize=8)
    ramp = card.logs[BREAKAWAY_RUN].columns
    breakaway_nm = card.derived["breakaway_torque_measured"]["value"]
    ax_brk.plot(ramp["tau_cmd"], ramp["qd_motor"], "C0")
    ax_brk.axvline(breakaway_nm, color="C2", ls=":", label=f"measured {breakaway_nm:.3f} N·m")
    ax_brk.axvline(params.friction.breakaway_torque_nm, color="C3", ls="--", lw=0.8,
                   label=f"parameter {params.friction.breakaway_torque_nm:g} N·m (paper Sec. IV)")
    ax_brk.set(xlabel="torque command [N·m]", ylabel="motor velocity, output side [rad/s]",
               title="breakaway ramp, free lever\n(velocity sustained > 100 ms)")
    ax_brk.legend(fontsize=8)
    rev = card.logs[BACKLASH_RUN].columns
    width_mrad = card.derived["backlash_width_measured"]["value"] * 1e3
    ax_bl.plot(rev["force_loadcell"] * params.lever.length_m, rev["q_motor"] * 1e3, "C0", lw=0.8)
    ax_bl.set(xlabel="load-cell torque [N·m]", ylabel="motor angle, output side [mrad]",
              title=f"backlash reversal, locked lever\ndead band {width_mrad:.3f} mrad (parameter "
                    f"{params.backlash.width_rad * 1e3:g} mrad)")
    return save_figure(fig, directory, PLOT_FILES[0])


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(prog=f"python -m {__spec__.name}", description="Print the testbed's model card.")
    add_params_arg(parser)
    add_output_args(parser, "write the card as JSON to this path", PLOT_FILES)
    add_rerun_args(parser, "the breakaway ramp (free fixture) and backlash reversal (locked fixture) runs the "
                           "card simulates (kept while measuring, not re-run)")
    args = parser.parse_args(argv)
    params = load_params_arg(parser, args, uses_sensor=False)
    card = run_plant_card(params, keep_logs=rerun_requested(args) or bool(args.plot))
    print(format_card(card))
    write_outputs(args, card.to_dict(), lambda directory: plot_card(card, params, directory))
    record_rerun(args, card.logs, params)


if __name__ == "__main__":
    main()
