"""A battery of rigid-joint logs from the independent simulator, each with the baseline rig and the truth.

``python -m tests.independent.battery --out DIR [--only PATTERN] [--duration S] [--analyse] [--workers N]``
writes ``DIR/<case>/log.csv``, ``DIR/<case>/rig.toml`` (the true baseline rig the analysis is told, model
"rigid-joint") and ``DIR/<case>/truth.json`` (the hidden effects, their parameters in the analysis library's
names, ``in_library``: the effect is one the analysis library is meant to carry, :data:`IN_LIBRARY`; whether the
current library has it is checked when analysing), and with ``--analyse`` runs the discrepancy analysis on each
case and prints a table and a summary (also ``DIR/summary.json``).

Cases (30 s at 1 kHz by default; EMPS-like 25 s):

- ``clean-*``: hinge and slide × multisine, chirp, point_to_point × 3 seeds: nothing hidden;
- ``<effect>-*``: one in-library effect, hinge and slide × multisine and point_to_point (transport_delay also
  chirp), values drawn from :data:`RANGES` relative to the rig or to the clean run's command (see :func:`draw`);
- ``outside-<effect>-*``: an effect outside the library (backlash, position-dependent inertia, position-varying
  friction, friction warm-up): the analysis should leave it unexplained;
- ``misspec-<parameter>-*``: nothing hidden, but the rig file's Coulomb level 30 % or its mass 25 % off the truth;
- ``pair-<a>+<b>-*``: two in-library effects at once;
- ``emps-estimation``, ``emps-validation``: an EMPS-like drive (:func:`emps_case`), rig with mass only.

The baseline rigs: hinge inertia 0.05 kg·m², Coulomb 0.3 N·m, viscous 0.05 N·m·s/rad, peak 10 N·m; slide 2 kg,
3 N, 8 N·s/m, peak 100 N; each value times a factor in [0.8, 1.25] drawn from the case's seed. Controller: the
position PID of :class:`~tests.independent.rigsim.PID` tuned at 5 Hz for the rig's mass, limited at the peak.
"""

from __future__ import annotations

import argparse
import fnmatch
import json
import math
import sys
import time
import zlib
from concurrent.futures import ProcessPoolExecutor
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from tests.independent.rigsim import (
    PID,
    CascadePPI,
    Plant,
    Reference,
    Run,
    chirp,
    multisine,
    point_to_point,
    simulate,
)

DT = 1e-3
DEFAULT_DURATION_S = 30.0
EMPS_DURATION_S = 25.0
BANDWIDTH_HZ = 5.0  # position loop
G = 9.81  # [m/s²]

BASE = {"hinge": {"mass": 0.05, "coulomb": 0.3, "viscous": 0.05, "peak_effort": 10.0},
        "slide": {"mass": 2.0, "coulomb": 3.0, "viscous": 8.0, "peak_effort": 100.0}}
BASE_SPREAD = (0.8, 1.25)  # factor on each baseline value, per seed
# excitation sizes: multisine slowest-tone amplitude, chirp velocity amplitude, point-to-point half range and
# top speed, the typical speed (v_stick = 1e-4 of it)
MOTION = {"hinge": {"span": 1.0, "chirp_speed": 1.5, "p2p_span": 1.5, "p2p_speed": 3.0, "typical_speed": 1.0},
          "slide": {"span": 0.1, "chirp_speed": 0.2, "p2p_span": 0.2, "p2p_speed": 0.4, "typical_speed": 0.2}}
EXCITATIONS = ("multisine", "chirp", "point_to_point")

# Hidden values: (low, high) ranges; "rig" scales by the rig's value, "rms" by the clean run's command RMS.
RANGES = {
    "coulomb_friction": "F_c × 1.25-1.5 or × 0.5-0.75 (breakaway = F_c)",
    "viscous_friction": "σ2 × 1.5-2.5 or × 0.3-0.6",
    "stribeck_friction": "F_s = F_c × 1.3-1.8; v_s 0.02-0.1 rad/s (hinge), 0.005-0.02 m/s (slide)",
    "asymmetric_friction": "|Δ| = F_c × 0.2-0.4, either sign",
    "cogging": "A_c = F_c × 0.1-0.3, P = 2π/N rad, N in {24, 36, 48, 72} (hinge); A_c = F_c × 0.15-0.4, "
               "P 10-40 mm (slide); φ uniform",
    "torque_constant_nonlinearity": "c 0.05-0.2; the rig's peak effort set to 1.3 × the clean run's largest "
                                    "command (so commands reach ~75 % of it)",
    "transport_delay": "d 2-8 ms",
    "gravity": "hinge A = F_c × 1.5-4 N·m, q0 uniform; slide A = m·g·sin(2°-10°), either sign",
    "effort_gain": "g 0.85-0.95 or 1.05-1.15",
    "quadratic_drag": "c_q·v_top² = 10-30 % of the command RMS (v_top: 95th percentile of |v| of the clean run)",
    "position_spring": "k_s·RMS(q − q_rest) = 10-30 % of the command RMS; q_rest = ±0.3 × the excitation span",
    "periodic_disturbance": "A_d = 5-15 % of the command RMS, f 2-10 Hz, φ uniform",
    "drivetrain_compliance": "φ 0.2-0.5, f_r 8-20 Hz, ζ 0.02-0.1",
    "backlash": "w 1-4 mrad (hinge), 0.05-0.2 mm (slide), in a two-mass drivetrain φ 0.2-0.4, f_r 15-30 Hz, "
                "ζ 0.05-0.1",
    "position_dependent_inertia": "α ±0.2-0.4; slide L = 0.5 m",
    "friction_varying_with_position": "β 0.2-0.4, P_long 1-3 rad (hinge), 0.1-0.3 m (slide)",
    "friction_warmup": "γ 0.3-0.6, T_w 5-15 s",
}
IN_LIBRARY = ("coulomb_friction", "viscous_friction", "stribeck_friction", "asymmetric_friction", "cogging",
              "torque_constant_nonlinearity", "transport_delay", "gravity", "effort_gain", "quadratic_drag",
              "position_spring", "periodic_disturbance", "drivetrain_compliance")
OUTSIDE = ("backlash", "position_dependent_inertia", "friction_varying_with_position", "friction_warmup")
PAIRS = (("coulomb_friction", "transport_delay"), ("gravity", "viscous_friction"),
         ("stribeck_friction", "cogging"), ("effort_gain", "transport_delay"))
ANGLES = {"gravity_angle", "cogging_phase", "disturbance_phase"}  # compared as angles, not relative values

# EMPS (Janot, Gautier, Brunot 2019; parameters identified by IDIM-LS, as in public EMPS simulators)
EMPS = {"mass": 95.1089, "viscous": 203.5034, "coulomb": 20.3935, "offset": -3.1648, "gtau": 35.15,
        "volt_limit": 10.0, "kp": 160.18, "kv": 243.45, "velocity_integral_time": 0.1, "encoder_step": 1e-6,
        "span": 0.1, "low": 0.0}


@dataclass(frozen=True)
class Case:
    """One log of the battery: what it hides and how it is excited."""

    name: str
    kind: str  # 'clean', 'effect', 'outside', 'misspecified', 'pair', 'emps'
    joint: str
    excitation: str
    seed: int
    effects: tuple[str, ...] = ()
    misspecify: str = ""  # 'coulomb' or 'mass'


def cases() -> list[Case]:
    """The battery's case list."""
    out = []
    for joint in ("hinge", "slide"):
        for excitation in EXCITATIONS:
            for seed in (1, 2, 3):
                out.append(Case(f"clean-{joint}-{excitation}-s{seed}", "clean", joint, excitation, seed))
    seed = 100
    for effect in IN_LIBRARY:
        for joint in ("hinge", "slide"):
            excitations = EXCITATIONS if effect == "transport_delay" else ("multisine", "point_to_point")
            for excitation in excitations:
                seed += 1
                out.append(Case(f"{effect}-{joint}-{excitation}-s{seed}", "effect", joint, excitation, seed,
                                (effect,)))
    for effect in OUTSIDE:
        for joint in ("hinge", "slide"):
            seed += 1
            out.append(Case(f"outside-{effect}-{joint}-multisine-s{seed}", "outside", joint, "multisine", seed,
                            (effect,)))
    for parameter in ("coulomb", "mass"):
        for joint in ("hinge", "slide"):
            for excitation in ("multisine", "point_to_point"):
                seed += 1
                out.append(Case(f"misspec-{parameter}-{joint}-{excitation}-s{seed}", "misspecified", joint,
                                excitation, seed, misspecify=parameter))
    for a, b in PAIRS:
        for joint in ("hinge", "slide"):
            seed += 1
            out.append(Case(f"pair-{a}+{b}-{joint}-multisine-s{seed}", "pair", joint, "multisine", seed, (a, b)))
    out.append(Case("emps-estimation", "emps", "slide", "emps_estimation", 1))
    out.append(Case("emps-validation", "emps", "slide", "emps_validation", 2))
    return out


# ------------------------------------------------------------------------------------------------ generation


def baseline(joint: str, seed: int) -> dict[str, float]:
    """The baseline rig's values (the clean truth): mass, coulomb, viscous, peak_effort, effort_gain."""
    rng = np.random.default_rng([seed, 7])
    values = {k: float(f"{v * rng.uniform(*BASE_SPREAD):.3g}") for k, v in BASE[joint].items()}
    values["peak_effort"] = BASE[joint]["peak_effort"]
    values["effort_gain"] = 1.0
    return values


def reference(joint: str, excitation: str, seed: int, n: int) -> Reference:
    """The position reference of a case [rad | m]."""
    mo = MOTION[joint]
    if excitation == "multisine":
        return multisine(n, mo["span"], seed)
    if excitation == "chirp":
        return chirp(n, mo["chirp_speed"])
    if excitation == "point_to_point":
        return point_to_point(n, mo["p2p_span"], mo["p2p_speed"], seed)
    raise ValueError(f"excitation = {excitation!r}; expected one of {EXCITATIONS}")


def plant_of(joint: str, values: dict[str, float], **changes) -> Plant:
    """The true plant: baseline ``values`` with ``changes`` (Plant fields)."""
    fields = {k: values[k] for k in ("mass", "coulomb", "viscous", "peak_effort", "effort_gain")}
    fields["stick_velocity"] = 1e-4 * MOTION[joint]["typical_speed"]
    fields.update(changes)
    return Plant(joint, **fields)


def run_closed_loop(plant: Plant, rig_mass: float, ref: Reference, seed: int) -> Run:
    """The case's run: the PID tuned for the rig's (stated) mass, limited at the plant's peak effort."""
    controller = PID.tuned(ref, rig_mass, BANDWIDTH_HZ, plant.peak_effort)
    return simulate(plant, controller, len(ref.position), seed=seed)


def clean_stats(joint: str, values: dict[str, float], ref: Reference, seed: int) -> dict[str, float]:
    """Command RMS and maximum [N·m | N], 95th-percentile speed [rad/s | m/s] and position RMS of the clean run."""
    run = run_closed_loop(plant_of(joint, values), values["mass"], ref, seed)
    return {"command_rms": float(np.sqrt(np.mean(run.tau_cmd**2))), "command_max": float(np.max(np.abs(run.tau_cmd))),
            "speed_p95": float(np.percentile(np.abs(run.v_true), 95)), "q": run.q_true}


def _signed(rng: np.random.Generator, up: tuple[float, float], down: tuple[float, float]) -> float:
    return float(rng.uniform(*up) if rng.random() < 0.5 else rng.uniform(*down))


def draw(effect: str, joint: str, values: dict[str, float], stats: dict, rng: np.random.Generator
         ) -> tuple[dict[str, float], dict[str, float], dict[str, float], dict[str, dict[str, float]]]:
    """A hidden effect's values.

    Returns
    -------
    plant : dict
        Plant field overrides of the truth.
    rig : dict
        Baseline values the rig file states differently (peak effort of the roll-off case).
    truth : dict
        The hidden parameters in the analysis library's names (SI).
    equivalent : dict
        Other effects that give the same physics, with their parameters (asymmetric friction and a slide's
        gravity: a constant effort).
    """
    u = rng.uniform
    hinge = joint == "hinge"
    fc, rms = values["coulomb"], stats["command_rms"]
    sign = 1.0 if rng.random() < 0.5 else -1.0
    if effect == "coulomb_friction":
        level = fc * _signed(rng, (1.25, 1.5), (0.5, 0.75))
        return {"coulomb": level}, {}, {"coulomb": level}, {}
    if effect == "viscous_friction":
        sigma2 = values["viscous"] * _signed(rng, (1.5, 2.5), (0.3, 0.6))
        return {"viscous": sigma2}, {}, {"viscous": sigma2}, {}
    if effect == "stribeck_friction":
        fs, vs = fc * u(1.3, 1.8), u(0.02, 0.1) if hinge else u(0.005, 0.02)
        return {"breakaway": fs, "stribeck_velocity": vs}, {}, {"breakaway": fs, "stribeck_velocity": vs}, {}
    if effect == "asymmetric_friction":
        delta = sign * fc * u(0.2, 0.4)
        same = {"constant_effort": {"constant_effort": delta / 2}}
        return {"asymmetry": delta}, {}, {"asymmetry": delta}, same
    if effect == "cogging":
        if hinge:
            amp, period = fc * u(0.1, 0.3), 2 * math.pi / float(rng.choice([24, 36, 48, 72]))
        else:
            amp, period = fc * u(0.15, 0.4), u(0.01, 0.04)
        p = {"cogging_amplitude": amp, "cogging_period": period, "cogging_phase": u(-math.pi, math.pi)}
        return p, {}, p, {}
    if effect == "torque_constant_nonlinearity":
        c = u(0.05, 0.2)
        peak = float(f"{1.3 * stats['command_max']:.2g}")
        return {"torque_rolloff": c, "peak_effort": peak}, {"peak_effort": peak}, {"torque_rolloff": c}, {}
    if effect == "transport_delay":
        d = u(2e-3, 8e-3)
        return {"delay": d}, {}, {"delay": d}, {}
    if effect == "gravity":
        if hinge:
            amp, angle = fc * u(1.5, 4.0), u(-math.pi, math.pi)
        else:
            amp, angle = sign * values["mass"] * G * math.sin(math.radians(u(2.0, 10.0))), 0.0
        same = {} if hinge else {"constant_effort": {"constant_effort": amp}}
        return ({"gravity_amplitude": amp, "gravity_angle": angle}, {},
                {"gravity_amplitude": amp, "gravity_angle": angle}, same)
    if effect == "effort_gain":
        g = values["effort_gain"] * _signed(rng, (1.05, 1.15), (0.85, 0.95))
        return {"effort_gain": g}, {}, {"effort_gain": g}, {}
    if effect == "quadratic_drag":
        cq = u(0.1, 0.3) * rms / stats["speed_p95"] ** 2
        return {"drag_coefficient": cq}, {}, {"drag_coefficient": cq}, {}
    if effect == "position_spring":
        rest = u(-0.3, 0.3) * MOTION[joint]["span"]
        k = u(0.1, 0.3) * rms / float(np.sqrt(np.mean((stats["q"] - rest) ** 2)))
        return ({"spring_stiffness": k, "spring_rest_position": rest}, {},
                {"spring_stiffness": k, "spring_rest_position": rest}, {})
    if effect == "periodic_disturbance":
        p = {"disturbance_amplitude": u(0.05, 0.15) * rms, "disturbance_frequency": u(2.0, 10.0),
             "disturbance_phase": u(-math.pi, math.pi)}
        return p, {}, p, {}
    if effect == "drivetrain_compliance":
        p = {"compliant_fraction": u(0.2, 0.5), "resonance_frequency": u(8.0, 20.0), "damping_ratio": u(0.02, 0.1)}
        return p, {}, p, {}
    if effect == "backlash":
        width = u(1e-3, 4e-3) if hinge else u(0.05e-3, 0.2e-3)
        p = {"backlash_width": width, "compliant_fraction": u(0.2, 0.4), "resonance_frequency": u(15.0, 30.0),
             "damping_ratio": u(0.05, 0.1)}
        return p, {}, p, {}
    if effect == "position_dependent_inertia":
        p = {"inertia_variation": sign * u(0.2, 0.4), "inertia_length": 0.5}
        return p, {}, p if not hinge else {"inertia_variation": p["inertia_variation"]}, {}
    if effect == "friction_varying_with_position":
        p = {"friction_variation": u(0.2, 0.4), "friction_period": u(1.0, 3.0) if hinge else u(0.1, 0.3)}
        return p, {}, p, {}
    if effect == "friction_warmup":
        p = {"friction_warmup": u(0.3, 0.6), "warmup_time": u(5.0, 15.0)}
        return p, {}, p, {}
    raise KeyError(f"unknown effect {effect!r}")


def canonical_truth(effect: str, joint: str, params: dict[str, float]) -> dict[str, float]:
    """A hinge's gravity A·sin(q − q0) kept with A ≥ 0 and q0 in [−π, π) (the analysis library's form)."""
    if effect == "gravity" and joint == "hinge" and params["gravity_amplitude"] < 0:
        return {"gravity_amplitude": -params["gravity_amplitude"],
                "gravity_angle": (params["gravity_angle"] + 2 * math.pi) % (2 * math.pi) - math.pi}
    return params


def build(case: Case, duration_s: float) -> tuple[Run, dict, dict]:
    """The case's run, its rig (values the analysis is told) and its truth."""
    if case.kind == "emps":
        return emps_case(case, min(duration_s, EMPS_DURATION_S))
    n = int(round(duration_s / DT))
    values = baseline(case.joint, case.seed)
    ref = reference(case.joint, case.excitation, case.seed, n)
    rng = np.random.default_rng([case.seed, zlib.crc32(case.name.encode())])
    plant_changes: dict[str, float] = {}
    rig_values = dict(values)
    hidden = []
    stats = clean_stats(case.joint, values, ref, case.seed) if case.effects else None
    for effect in case.effects:
        plant, rig, truth, same = draw(effect, case.joint, values, stats, rng)
        plant_changes.update(plant)
        rig_values.update(rig)
        hidden.append({"effect": effect, "in_library": effect in IN_LIBRARY,
                       "parameters": canonical_truth(effect, case.joint, truth), "equivalent": same})
    if case.misspecify == "coulomb":
        factor = 1.3 if case.seed % 2 else 0.7
        rig_values["coulomb"] = float(f"{values['coulomb'] * factor:.4g}")
        hidden.append({"effect": "coulomb_friction", "in_library": True, "parameters": {"coulomb": values["coulomb"]},
                       "equivalent": {}, "rig_states": rig_values["coulomb"]})
    elif case.misspecify == "mass":
        factor = 1.25 if case.seed % 2 else 0.75
        rig_values["mass"] = float(f"{values['mass'] * factor:.4g}")
        hidden.append({"effect": "inertia", "in_library": False, "parameters": {"inertia": values["mass"]},
                       "equivalent": {}, "rig_states": rig_values["mass"]})
    plant = plant_of(case.joint, values, **plant_changes)
    run = run_closed_loop(plant, rig_values["mass"], ref, case.seed)
    truth = {"case": case.name, "kind": case.kind, "joint": case.joint, "excitation": case.excitation,
             "seed": case.seed, "duration_s": n * DT, "hidden": hidden, "plant": asdict(plant),
             "controller": {"type": "PID (s + ω)³", "bandwidth_hz": BANDWIDTH_HZ, "tuned_for_mass": rig_values["mass"],
                            "limit": plant.peak_effort, "derivative_cutoff_hz": 150.0},
             "ranges": {e: RANGES[e] for e in case.effects}}
    rig = {"joint": case.joint, "mass": rig_values["mass"], "effort_gain": rig_values["effort_gain"],
           "peak_effort": rig_values["peak_effort"], "coulomb": rig_values["coulomb"], "viscous": rig_values["viscous"]}
    return run, rig, truth


def emps_reference(case: Case, n: int) -> Reference:
    """Point-to-point carriage moves in [0, 0.2] m: estimation at 0.1-0.25 m/s peak, validation at 0.08-0.3."""
    speeds = (0.4, 1.0) if case.excitation == "emps_estimation" else (0.27, 1.0)
    dwell = (0.3, 1.0) if case.excitation == "emps_estimation" else (0.2, 0.6)
    return point_to_point(n, EMPS["span"], 0.25 if case.excitation == "emps_estimation" else 0.3, case.seed,
                          speed_range=speeds, dwell_s=dwell, low=EMPS["low"])


def emps_case(case: Case, duration_s: float) -> tuple[Run, dict, dict]:
    """An EMPS-like prismatic drive: M = 95.1089 kg, Fv = 203.5034 N·s/m, Fc = 20.3935 N, offset force
    OF = −3.1648 N (M·a = F − Fv·v − Fc·sign(v) − OF: the slide's constant force, gravity_amplitude = OF),
    F = gtau·vir with gtau = 35.15 N/V and vir within ±10 V; cascaded P position (kp = 160.18 1/s) / PI velocity
    (kv = 243.45 V·s/m, integral kv/0.1 s) loop at 1 kHz on the position quantised at 1 µm."""
    n = int(round(duration_s / DT))
    e = EMPS
    peak = e["gtau"] * e["volt_limit"]
    plant = Plant("slide", e["mass"], coulomb=e["coulomb"], viscous=e["viscous"], gravity_amplitude=e["offset"],
                  peak_effort=peak, stick_velocity=1e-5)
    ref = emps_reference(case, n)
    controller = CascadePPI(ref, e["kp"], e["kv"], e["kv"] / e["velocity_integral_time"], e["gtau"],
                            e["volt_limit"])
    run = simulate(plant, controller, n, seed=case.seed, encoder_step=e["encoder_step"])
    hidden = [{"effect": "coulomb_friction", "in_library": True, "parameters": {"coulomb": e["coulomb"]},
               "equivalent": {}},
              {"effect": "viscous_friction", "in_library": True, "parameters": {"viscous": e["viscous"]},
               "equivalent": {}},
              {"effect": "gravity", "in_library": True,
               "parameters": {"gravity_amplitude": e["offset"], "gravity_angle": 0.0},
               "equivalent": {"constant_effort": {"constant_effort": e["offset"]}}}]
    truth = {"case": case.name, "kind": "emps", "joint": "slide", "excitation": case.excitation, "seed": case.seed,
             "duration_s": n * DT, "hidden": hidden, "plant": asdict(plant),
             "controller": {"type": "cascaded P position / PI velocity", "kp_per_s": e["kp"], "kv_v_s_per_m": e["kv"],
                            "ki_v_per_m": e["kv"] / e["velocity_integral_time"], "gtau_n_per_v": e["gtau"],
                            "volt_limit": e["volt_limit"], "derivative_cutoff_hz": 150.0},
             "encoder_step_m": e["encoder_step"]}
    rig = {"joint": "slide", "mass": e["mass"], "effort_gain": 1.0, "peak_effort": peak, "coulomb": 0.0,
           "viscous": 0.0}
    return run, rig, truth


def rig_toml(rig: dict, header: str) -> str:
    """The project's rigid-joint rig file for ``rig`` (joint, mass, effort_gain, peak_effort, coulomb, viscous)."""
    slide = rig["joint"] == "slide"
    inertia = f"mass_kg = {rig['mass']!r}" if slide else f"inertia_kgm2 = {rig['mass']!r}"
    unit = ("N", "N·s/m") if slide else ("N·m", "N·m·s/rad")
    return "\n".join([
        f"# {header}", 'model = "rigid-joint"', f'joint = "{rig["joint"]}"', inertia,
        f"effort_gain = {rig['effort_gain']!r}", f"peak_effort = {rig['peak_effort']!r}  # {unit[0]}", "",
        "[friction]", f"coulomb = {rig['coulomb']!r}  # {unit[0]}", f"viscous = {rig['viscous']!r}  # {unit[1]}", ""])


def as_log_and_rig(run: Run, rig: dict, joint: str):
    """The case's log and the project's rig description of ``rig``, in memory (RunLog, Rig)."""
    import tomllib

    from sim.discrepancy.rig import rig_from_dict

    return run.to_log(), rig_from_dict(tomllib.loads(rig_toml(rig, "battery case")), source=f"battery {joint} rig")


def write_case(case: Case, out: Path, duration_s: float) -> dict:
    """Simulate ``case`` and write its log, rig and truth under ``out/<case>``; returns the truth."""
    from sim.logio import write_log

    t0 = time.perf_counter()
    run, rig, truth = build(case, duration_s)
    folder = out / case.name
    folder.mkdir(parents=True, exist_ok=True)
    write_log(run.to_log(), folder / "log.csv", overwrite=True)
    (folder / "rig.toml").write_text(rig_toml(rig, f"baseline rig of battery case {case.name}"), encoding="utf-8")
    truth["generation_s"] = time.perf_counter() - t0
    (folder / "truth.json").write_text(json.dumps(truth, indent=1, default=float), encoding="utf-8")
    return truth


# -------------------------------------------------------------------------------------------------- analysis


def run_analysis(log_path: Path, rig_path: Path, joint: str, workers: int = 1):
    """The discrepancy analysis of one case (the project's current API)."""
    from sim.discrepancy.analysis import analyse
    from sim.discrepancy.rig import load_rig
    from sim.discrepancy.signals import AnalysisConfig
    from sim.logio import read_log

    return analyse(read_log(log_path, joint=joint), load_rig(rig_path), AnalysisConfig(workers=workers))


def _current_library() -> set[str]:
    from sim.discrepancy.effects import EFFECTS

    return set(EFFECTS)


def _error(truth: dict[str, float], found: dict[str, float]) -> tuple[float | None, dict[str, float]]:
    """Largest relative error over the shared non-angle parameters, and every shared parameter's error
    (angles: wrapped absolute difference [rad])."""
    errors = {}
    for key, true in truth.items():
        if key not in found:
            continue
        if key in ANGLES:
            errors[key] = abs((found[key] - true + math.pi) % (2 * math.pi) - math.pi)
        else:
            errors[key] = abs(found[key] - true) / abs(true) if true else math.inf
    relative = [v for k, v in errors.items() if k not in ANGLES]
    return (max(relative) if relative else None), errors


def judge(truth: dict, findings: list[dict], library: set[str], verdict_text: str = "",
          tolerance: float = 0.2) -> dict:
    """Compare the findings (and the analysis's verdict) with the truth: verdict, the first finding's matched
    effect and errors. A clean log must end with no finding and not 'unexplained'; an outside-library effect
    with no finding and 'unexplained'."""
    names = [f["effect"] for f in findings]
    first = findings[0] if findings else None
    row = {"found": names, "first": None, "first_values": {}, "first_error": None, "errors": {}, "gain": None}
    if first:
        row["first_values"] = {k: v["value"] for k, v in first["parameters"].items()}
        row["gain"] = first["gain"]
    kind = truth["kind"]
    unexplained = "unexplained" in verdict_text
    if kind == "clean":
        row["verdict"] = ("SPURIOUS" if names else "SPURIOUS (unexplained)" if unexplained else "ok (nothing found)")
        return row
    if kind == "outside":
        row["verdict"] = ("WRONG NAME (outside-library effect named)" if names else
                          "ok (unexplained)" if unexplained else "MISSED (no finding, not unexplained)")
        return row
    targets = {}
    for h in truth["hidden"]:
        targets[h["effect"]] = (h["effect"], h["parameters"])
        for other, params in h.get("equivalent", {}).items():
            targets[other] = (h["effect"], params)
    hidden_names = [h["effect"] for h in truth["hidden"]]
    named = {targets[n][0] for n in names if n in targets}
    if first and first["effect"] in targets:
        row["first"] = targets[first["effect"]][0]
        row["first_error"], row["errors"] = _error(targets[first["effect"]][1], row["first_values"])
    if not names:
        verdict = "MISSED"
    elif row["first"] is None:
        verdict = "WRONG NAME"
    elif row["first_error"] is not None and row["first_error"] <= tolerance:
        verdict = "right"
    else:
        verdict = "named, value off"
    if kind in ("pair", "emps"):
        verdict += f" ({len(named)}/{len(hidden_names)} named)"
    row["verdict"] = verdict
    row["in_current_library"] = all(h["effect"] in library or any(e in library for e in h.get("equivalent", {}))
                                    for h in truth["hidden"])
    return row


def analyse_case(folder: Path, workers: int = 1) -> dict:
    """Analyse one written case and judge it."""
    truth = json.loads((folder / "truth.json").read_text(encoding="utf-8"))
    t0 = time.perf_counter()
    try:
        result = run_analysis(folder / "log.csv", folder / "rig.toml", truth["joint"], workers)
        findings = [f.to_dict() for f in result.findings]
        analysis = {"verdict": result.verdict, "unexplained": result.structure.description,
                    "remainder_fraction": result.structure.remainder_fraction,
                    "whiteness_p": result.structure.whiteness.get("p_value"),
                    "generic_gain": result.structure.generic_gain,
                    "rejected": result.rejected, "logs": result.logs}
        error = None
    except Exception as err:  # a case the analysis refuses is a result too
        findings, error, analysis = [], f"{type(err).__name__}: {err}", {}
    row = judge(truth, findings, _current_library(), analysis.get("verdict", ""))
    row["analysis"] = analysis
    row.update(case=truth["case"], kind=truth["kind"], hidden=[h["effect"] for h in truth["hidden"]],
               truth={h["effect"]: h["parameters"] for h in truth["hidden"]}, seconds=time.perf_counter() - t0,
               error=error, findings=findings)
    if error:
        row["verdict"] = "ERROR"
    return row


def _fmt(values: dict[str, float]) -> str:
    return ", ".join(f"{k}={v:.4g}" for k, v in values.items())


def print_table(rows: list[dict], stream=sys.stdout) -> None:
    """One line per case."""
    print("| case | hidden | truth | found (in order) | first finding | rel. err | gain | verdict | s |",
          file=stream)
    print("|---|---|---|---|---|---|---|---|---|", file=stream)
    for r in rows:
        truth = "; ".join(_fmt(p) for p in r["truth"].values()) or "-"
        err = "-" if r["first_error"] is None else f"{100 * r['first_error']:.1f} %"
        gain = "-" if r["gain"] is None else f"{100 * r['gain']:.0f} %"
        print(f"| {r['case']} | {'+'.join(r['hidden']) or '-'} | {truth} | {', '.join(r['found']) or '-'} | "
              f"{_fmt(r['first_values']) or '-'} | {err} | {gain} | {r['verdict']} | {r['seconds']:.0f} |",
              file=stream)


def summarise(rows: list[dict]) -> dict:
    """The battery's score."""
    def count(kind: str, ok) -> str:
        subset = [r for r in rows if kind(r)]
        return f"{sum(1 for r in subset if ok(r))}/{len(subset)}"

    single = lambda r: r["kind"] == "effect"  # noqa: E731
    return {
        "in_library_named_first_within_20pct (all planned effects)": count(single, lambda r: r["verdict"] == "right"),
        "in_library_named_first_within_20pct (effects in the current library)": count(
            lambda r: single(r) and r.get("in_current_library", False), lambda r: r["verdict"] == "right"),
        "in_library_named_first (any value)": count(single, lambda r: r["first"] is not None),
        "clean_logs_with_a_finding": count(lambda r: r["kind"] == "clean", lambda r: bool(r["found"])),
        "clean_logs_called_unexplained": count(lambda r: r["kind"] == "clean",
                                               lambda r: r["verdict"] == "SPURIOUS (unexplained)"),
        "outside_library_with_a_confident_name": count(lambda r: r["kind"] == "outside", lambda r: bool(r["found"])),
        "outside_library_unexplained": count(lambda r: r["kind"] == "outside",
                                             lambda r: r["verdict"] == "ok (unexplained)"),
        "misspecified_named_right": count(lambda r: r["kind"] == "misspecified", lambda r: r["verdict"] == "right"),
        "pairs_first_right": count(lambda r: r["kind"] == "pair", lambda r: r["verdict"].startswith("right")),
        "errors": count(lambda r: True, lambda r: r["verdict"] == "ERROR"),
        "analysis_seconds_total": sum(r["seconds"] for r in rows),
    }


def write_summary(rows: list[dict], summary: dict, out: Path) -> None:
    """Print ``summary`` and write it with every row to ``out/summary.json``."""
    print("\nsummary:")
    for key, value in summary.items():
        print(f"  {key}: {value}")
    (out / "summary.json").write_text(json.dumps({"summary": summary, "cases": rows}, indent=1, default=float),
                                      encoding="utf-8")


# ------------------------------------------------------------------------------------------------------- CLI


def _generate(args: tuple[Case, str, float]) -> tuple[str, float]:
    case, out, duration = args
    truth = write_case(case, Path(out), duration)
    return case.name, truth["generation_s"]


def _analyse(args: tuple[str, int]) -> dict:
    folder, workers = args
    return analyse_case(Path(folder), workers)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--out", required=True, type=Path, help="folder for the cases (outside the repository)")
    parser.add_argument("--only", default="*", help="fnmatch pattern of case names (default: all)")
    parser.add_argument("--duration", type=float, default=DEFAULT_DURATION_S, help="log length [s] (EMPS: ≤ 25)")
    parser.add_argument("--analyse", action="store_true", help="run the discrepancy analysis on each case")
    parser.add_argument("--workers", type=int, default=1, help="processes over cases (the analysis runs with 1)")
    parser.add_argument("--no-generate", action="store_true", help="analyse the cases already in --out")
    parser.add_argument("--list", action="store_true", help="print the case names and exit")
    args = parser.parse_args(argv)
    chosen = [c for c in cases() if fnmatch.fnmatch(c.name, args.only)]
    if args.list:
        print("\n".join(c.name for c in chosen))
        return 0
    args.out.mkdir(parents=True, exist_ok=True)
    pool = ProcessPoolExecutor(args.workers) if args.workers > 1 else None
    mapper = pool.map if pool else map
    try:
        if not args.no_generate:
            for name, seconds in mapper(_generate, [(c, str(args.out), args.duration) for c in chosen]):
                print(f"generated {name} ({seconds:.1f} s)", file=sys.stderr, flush=True)
        if args.analyse:
            rows = []
            for row in mapper(_analyse, [(str(args.out / c.name), 1) for c in chosen]):
                print(f"analysed {row['case']}: {row['verdict']} ({row['seconds']:.0f} s)", file=sys.stderr,
                      flush=True)
                rows.append(row)
            print_table(rows)
            write_summary(rows, summarise(rows), args.out)
    finally:
        if pool:
            pool.shutdown()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
