"""The fidelity presets (``simulation.substeps_rule``): what 'fast' changes against 'accurate', in one process.

    python -m benchmarks.bench_fidelity [--duration 10] [--repeats 5] [--paper] [--fast-substeps N] [--cpu-time]

Prints, for the default parameters under each rule:

(a) speed: ``Plant.step`` ticks/s of a locked-fixture run at 1 kHz (the two rules' runs alternated, best of
    the repeats) and the ratio fast / accurate;
(b) the locked fixture's linearised modes under a 1 N·m preload (``sim.characterize.linearized_modes``): the
    drivetrain mode, and the lightly damped lever mode (the lever between flexure and load cell) with its
    free-vibration peak, under both rules and at a 16x finer step than accurate (the h -> 0 reference);
(c) what 'fast' relaxes at the backlash stops: the stop's penetration at the driver's limit (locked); the
    free fixture's hub settled on its stop (``sim.characterize.settle_against_stop``); in the admittance
    experiment's pushes the deepest penetration, the tick-to-tick roughness of the flexure torque (RMS of its
    second difference) and, while the stop is loaded, the hub's velocity against the gear beside the bound
    the stop's compliance sets; (c') the same settling and the locked lever ringing's damping under 'fast' at
    8-16 substeps with Euler's joint damping implicit and explicit;
(d) what MuJoCo would need for 8 substeps: the drivetrain mode at 8 and 16 substeps with the presliding
    friction integrated six ways (see :func:`presliding_scheme_mode`);
(e) with ``--paper``: every figure of ``experiments.paper`` under both rules, its relative change, the
    largest and the median change (about 1-2 minutes).

``--fast-substeps N`` measures 'fast' with ``simulation.fast_substeps_per_tick = N`` instead of its default;
``--cpu-time`` times (a) by the process's CPU time (steadier on a loaded machine).
"""

from __future__ import annotations

import argparse
import re
import statistics
import time
import types

import mujoco
import numpy as np

from benchmarks.bench_plant import best_rate
from experiments.admittance import run_admittance
from experiments.paper import run_paper
from models.gim8108_testbed.build import build_xml
from models.gim8108_testbed.derived import derive
from sim.characterize import (
    Mode,
    backlash_rate_rad_s,
    free_vibration_peak_hz,
    linearizable_plant,
    linearized_modes,
    settle_against_stop,
    stop_loaded,
)
from sim.motor_torque import CurrentToTorqueMap
from sim.params import TestbedParams
from sim.plant import Plant

REFINEMENT = 16  # the reference step is the accurate step / REFINEMENT
PRELOAD_NM = 1.0  # [N·m] the locked fixture's linearisation point, as in experiments.plant
SCHEME_REFERENCE_SUBSTEPS = 256  # the h -> 0 reference of (d)
SETTLE_TORQUE_NM, SETTLE_S, SETTLED_AFTER_S = 0.5, 0.6, 0.3  # (c): sim.characterize.settle_against_stop, window
EULERDAMP_OFF = int(mujoco.mjtDisableBit.mjDSBL_EULERDAMP)
# (d): how the linearised presliding friction σ0·z + σ1·ż (ż = gear velocity v while stuck) is integrated.
# bristle: 'explicit' z_{k+1} = z_k + h·v_k (MuJoCo's dcmotor), 'symplectic' z_{k+1} = z_k + h·v_{k+1};
# σ1 term: 'explicit' -σ1·v_k, 'implicit' -σ1·v_{k+1}, 'trapezoidal' -σ1·(v_k + v_{k+1})/2.
SCHEMES = (("explicit", "explicit"), ("symplectic", "explicit"), ("explicit", "implicit"),
           ("symplectic", "implicit"), ("explicit", "trapezoidal"), ("symplectic", "trapezoidal"))


def rules(fast_substeps: int | None = None) -> dict[str, TestbedParams]:
    """The default parameters under each rule (``fast_substeps``: 'fast' with that many substeps per tick)."""
    p = TestbedParams()
    fast = {"substeps_rule": "fast"}
    if fast_substeps is not None:
        fast["fast_substeps_per_tick"] = fast_substeps
    return {"accurate": p, "fast": p.replace(simulation=fast)}


def step_rates(duration_s: float, repeats: int, fast_substeps: int | None = None,
               clock=time.perf_counter) -> dict[str, tuple[float, int]]:
    """Best ``Plant.step`` ticks/s [1/s] and substeps per tick of each rule (locked), runs alternated; ``clock``
    as for :func:`benchmarks.bench_plant.best_rate`."""
    params = rules(fast_substeps)
    n = round(duration_s / TestbedParams().simulation.control_period_s)
    tau = 0.5 + 0.3 * np.sin(2 * np.pi * 0.2 * np.arange(n) * 1e-3)
    best = {name: 0.0 for name in params}
    for _ in range(repeats):
        for name, p in params.items():
            def stepped(p=p) -> None:
                plant = Plant(p, "locked")
                for u in tau:
                    plant.step(u)
            best[name] = max(best[name], best_rate(stepped, n, 1, clock))
    return {name: (best[name], Plant(p, "locked").n_substeps) for name, p in params.items()}


def locked_modes(fast_substeps: int | None = None) -> dict[str, dict[str, float]]:
    """Drivetrain and lever modes of the locked fixture [Hz, 1] under each rule and the fine reference."""
    params = rules(fast_substeps)
    plants = {name: linearizable_plant(p, "locked", PRELOAD_NM) for name, p in params.items()}
    plants["reference"] = linearizable_plant(params["accurate"], "locked", PRELOAD_NM,
                                             timestep_s=plants["accurate"].timestep_s / REFINEMENT)
    out = {}
    for name, plant in plants.items():
        drivetrain, lever = linearized_modes(plant)[:2]
        out[name] = {"drivetrain_hz": drivetrain.natural_frequency_hz, "drivetrain_zeta": drivetrain.damping_ratio,
                     "lever_hz": lever.natural_frequency_hz, "lever_zeta": lever.damping_ratio,
                     "lever_peak_hz": free_vibration_peak_hz(plant, duration_s=1.0),
                     "substeps": plant.n_substeps}
    return out


def stop_relaxation(fast_substeps: int | None = None) -> dict[str, dict[str, float]]:
    """Backlash-stop penetration [fraction of the gap] at the driver's limit (locked) and, in each admittance push
    (free), the deepest penetration, the flexure torque's roughness [N·m] and the peak lever velocity [rad/s]."""
    out = {}
    for name, p in rules(fast_substeps).items():
        gap = p.backlash.width_rad
        plant = Plant(p, "locked")
        limit = CurrentToTorqueMap.from_params(p).command_limit_nm
        for _ in range(500):
            plant.step(limit)
        out[name] = {"full_torque_penetration": (abs(plant.backlash_angle_rad) - 0.5 * gap) / gap}
        settle = settle_against_stop(Plant(p, "free"), SETTLE_TORQUE_NM, SETTLE_S)
        late = np.asarray(settle["time"]) >= SETTLED_AFTER_S
        out[name]["settled_rms_velocity_rad_s"] = float(np.sqrt(np.mean(np.asarray(settle["qd"])[late] ** 2)))
        compliance_rad_per_nm = 0.1 * gap / p.motor.peak_torque_nm  # the stop's bound, 10 % of the gap at 18 N·m
        for push, log in run_admittance(p, seed=0).logs().items():
            backlash, tau = np.abs(np.asarray(log["backlash_angle"])), np.asarray(log["tau_flexure"])
            loaded = stop_loaded(log)
            hand_rate = np.diff(np.asarray(log["tau_ext"])) / np.diff(np.asarray(log["time"]))
            out[name] |= {f"{push}_push_max_penetration": max(float(backlash.max()) - 0.5 * gap, 0.0) / gap,
                          f"{push}_push_tau_roughness_nm": float(np.sqrt(np.mean(np.diff(tau, 2) ** 2))),
                          f"{push}_push_peak_velocity_rad_s": float(np.max(np.abs(np.asarray(log["qd"])))),
                          f"{push}_push_loaded_backlash_rate_rad_s":
                              float(np.sqrt(np.mean(backlash_rate_rad_s(log)[loaded] ** 2))),
                          f"{push}_push_compliance_bound_rad_s":
                              compliance_rad_per_nm * float(np.sqrt(np.mean(hand_rate[loaded] ** 2)))}
    return out


def with_euler_damping(plant: Plant, implicit: bool) -> Plant:
    """``plant`` with MuJoCo's Euler implicit joint damping (the ``eulerdamp`` flag) switched on or off."""
    if implicit:
        plant.model.opt.disableflags &= ~EULERDAMP_OFF
    else:
        plant.model.opt.disableflags |= EULERDAMP_OFF
    return plant


def euler_damping_effect(substeps: tuple[int, ...] = (8, 10, 12, 16)) -> dict[tuple[int, bool], dict[str, float]]:
    """'fast' at each of ``substeps`` per tick, with Euler's joint damping implicit and explicit: the free
    fixture's settled lever velocity (as in :func:`stop_relaxation`) [rad/s] and the damping ratio of the
    locked fixture's lever ringing (closed stop, 1 N·m preload; ``lever_zeta``)."""
    out = {}
    for n in substeps:
        p = TestbedParams().replace(simulation={"substeps_rule": "fast", "fast_substeps_per_tick": n})
        for implicit in (True, False):
            settle = settle_against_stop(with_euler_damping(Plant(p, "free"), implicit), SETTLE_TORQUE_NM, SETTLE_S)
            late = np.asarray(settle["time"]) >= SETTLED_AFTER_S
            lever = linearized_modes(with_euler_damping(linearizable_plant(p, "locked", PRELOAD_NM), implicit))[1]
            settled = float(np.sqrt(np.mean(np.asarray(settle["qd"])[late] ** 2)))
            out[n, implicit] = {"settled_rms_velocity_rad_s": settled, "lever_zeta": lever.damping_ratio}
    return out


def presliding_scheme_mode(bristle: str, damping: str, substeps: int) -> Mode:
    """The locked drivetrain mode with the presliding friction integrated one way.

    The linearisable plant's model (no delay, no load-dependent friction, 1 N·m preload), its dcmotor's LuGre
    replaced by what it is while the gear is stuck, a spring σ0 and a damper σ1 on the gear joint, in MuJoCo
    elements whose integration is known under the Euler integrator: the LuGre bristle with σ1 = 0 ('explicit'
    bristle, MuJoCo's own update) or the joint's stiffness ('symplectic': the spring reads the position after
    the velocity update); an affine actuator bias -σ1·v ('explicit'), the joint's damping ('implicit': Euler
    integrates joint damping implicitly), or half of each ('trapezoidal'). ('explicit', 'explicit') is the
    dcmotor's own scheme: it reproduces the plant's mode.
    """
    p = TestbedParams().replace(motor={"command_delay_s": 0.0}, friction={"load_friction_coefficient": 0.0})
    sigma0, sigma1 = p.friction.presliding_stiffness_nm_per_rad, derive(p).presliding_damping_nms_per_rad
    xml = build_xml(p, "locked")
    lugre = re.search(r'lugre="([^"]+)"', xml).group(1).split()
    lugre[1] = "0"  # σ1 goes to the elements below
    joint = ""
    if bristle == "symplectic":
        lugre[0] = "0"  # no LuGre activation: σ0 becomes the joint's spring
        joint += f' stiffness="{sigma0:.9g}"'
    implicit_share = {"explicit": 0.0, "implicit": 1.0, "trapezoidal": 0.5}[damping]
    if implicit_share:
        joint += f' damping="{implicit_share * sigma1:.9g}"'
    xml = re.sub(r'lugre="[^"]+"', f'lugre="{" ".join(lugre)}"', xml)
    xml = xml.replace('<joint name="motor" type="hinge"', '<joint name="motor" type="hinge"' + joint)
    if implicit_share < 1.0:
        xml = xml.replace('<motor name="external"', f'<general name="sigma1" joint="motor" gaintype="fixed" '
                          f'gainprm="0" biastype="affine" biasprm="0 0 {-(1.0 - implicit_share) * sigma1:.9g}"/>\n'
                          f'    <motor name="external"')
    model = mujoco.MjModel.from_xml_string(xml)
    model.opt.timestep = p.simulation.control_period_s / substeps
    data = mujoco.MjData(model)
    half_gap, gear = 0.5 * p.backlash.width_rad, model.joint("motor").qposadr[0]
    data.qpos[gear], data.qpos[model.joint("backlash").qposadr[0]] = half_gap, -half_gap  # the stop closed
    model.qpos_spring[gear] = half_gap
    data.ctrl[model.actuator("motor").id] = CurrentToTorqueMap.from_params(p).delivered_nm(PRELOAD_NM) / \
        p.motor.gear_ratio
    mujoco.mj_step(model, data, round(0.5 / model.opt.timestep))
    return linearized_modes(types.SimpleNamespace(model=model, data=data))[0]


def paper_changes(fast_substeps: int | None = None) -> list[tuple[float, str, float, float]]:
    """(relative change fast / accurate - 1, figure, accurate value, fast value) of every simulated figure."""
    results = {name: run_paper(p).rows for name, p in rules(fast_substeps).items()}
    out = []
    for a, f in zip(results["accurate"], results["fast"], strict=True):
        if a["sim"] is not None and a["sim"] != 0:
            out.append((f["sim"] / a["sim"] - 1.0, f"{a['table']}: {a['quantity']}", a["sim"], f["sim"]))
    return out


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--duration", type=float, default=10.0, help="simulated seconds per speed run (default 10)")
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--paper", action="store_true", help="also run experiments.paper under both rules")
    parser.add_argument("--cpu-time", action="store_true",
                        help="time the speed runs by this process's CPU time instead of wall time")
    parser.add_argument("--fast-substeps", type=int, metavar="N",
                        help="simulation.fast_substeps_per_tick of 'fast' (default: the parameter's default)")
    args = parser.parse_args(argv)
    n = args.fast_substeps

    clock = time.process_time if args.cpu_time else time.perf_counter
    rates = step_rates(args.duration, args.repeats, n, clock)
    (acc, n_acc), (fast, n_fast) = rates["accurate"], rates["fast"]
    print(f"(a) Plant.step, locked, {args.duration:g} s at 1 kHz, best of {args.repeats} (alternated), "
          f"{'CPU' if args.cpu_time else 'wall'} time")
    print(f"  accurate ({n_acc} substeps) {acc:9.0f} ticks/s   fast ({n_fast} substeps) {fast:9.0f} ticks/s   "
          f"ratio {fast / acc:.2f}x")

    modes = locked_modes(n)
    ref = modes["reference"]
    print(f"(b) locked fixture, {PRELOAD_NM:g} N·m preload; reference: accurate step / {REFINEMENT} "
          f"({ref['substeps']} substeps)")
    for key, label in (("drivetrain_hz", "drivetrain mode f_n [Hz]"), ("drivetrain_zeta", "drivetrain mode ζ"),
                       ("lever_hz", "lever mode f_n [Hz]"), ("lever_zeta", "lever mode ζ"),
                       ("lever_peak_hz", "lever mode free-vibration peak [Hz]")):
        a, f, r = modes["accurate"][key], modes["fast"][key], ref[key]
        print(f"  {label:36s} accurate {a:9.4g} ({a / r - 1:+6.2%} vs ref)   fast {f:9.4g} ({f / r - 1:+6.2%} vs ref)"
              f"   fast vs accurate {f / a - 1:+6.2%}   ref {r:9.4g}")

    stops = stop_relaxation(n)
    print("(c) backlash stops")
    rows = [("full_torque_penetration", "penetration at the driver's limit, of the gap", "{:.2%}"),
            ("settled_rms_velocity_rad_s", f"hub settled on its stop: RMS lever velocity from {SETTLED_AFTER_S:g} s "
             "[rad/s]", "{:.2g}")]
    for push in ("slow", "fast"):
        rows += [(f"{push}_push_loaded_backlash_rate_rad_s",
                  f"admittance {push} push, stop loaded: RMS hub velocity against the gear [rad/s]", "{:.2g}"),
                 (f"{push}_push_compliance_bound_rad_s", "  its bound, the stop's compliance x RMS hand-torque rate",
                  "{:.2g}")]
    for push in ("slow", "fast"):
        rows += [(f"{push}_push_max_penetration", f"admittance {push} push: deepest penetration, of the gap", "{:.1%}"),
                 (f"{push}_push_tau_roughness_nm", f"admittance {push} push: RMS 2nd difference of τ_flexure [N·m]",
                  "{:.2g}"),
                 (f"{push}_push_peak_velocity_rad_s", f"admittance {push} push: peak lever velocity [rad/s]",
                  "{:.3f}")]
    for key, label, fmt in rows:
        print(f"  {label:62s} accurate {fmt.format(stops['accurate'][key]):>8s}   "
              f"fast {fmt.format(stops['fast'][key]):>8s}")

    print("(c') 'fast' at N substeps, Euler's joint damping implicit (MuJoCo's default) / explicit (the preset)")
    for (substeps, implicit), row in euler_damping_effect().items():
        print(f"  {substeps:2d} substeps, {'implicit' if implicit else 'explicit'}: settled RMS lever velocity "
              f"{row['settled_rms_velocity_rad_s']:.2g} rad/s, locked lever ringing ζ {row['lever_zeta']:.4f}")

    print(f"(d) drivetrain mode with the presliding friction integrated each way, vs {SCHEME_REFERENCE_SUBSTEPS} "
          f"substeps of MuJoCo's scheme")
    reference = presliding_scheme_mode("explicit", "explicit", SCHEME_REFERENCE_SUBSTEPS)
    for bristle, damping in SCHEMES:
        cells = []
        for substeps in (8, 16):
            mode = presliding_scheme_mode(bristle, damping, substeps)
            f_n = mode.natural_frequency_hz / reference.natural_frequency_hz - 1
            zeta = mode.damping_ratio / reference.damping_ratio - 1
            cells.append(f"{substeps:2d} substeps: f_n {f_n:+6.2%}, ζ {zeta:+6.2%}")
        mark = "  (MuJoCo's dcmotor)" if (bristle, damping) == ("explicit", "explicit") else ""
        print(f"  bristle {bristle:10s} σ1·ż {damping:11s} {'   '.join(cells)}{mark}")

    if args.paper:
        changes = paper_changes(n)
        size = sorted(abs(c[0]) for c in changes)
        print(f"(e) experiments.paper, {len(changes)} simulated figures: largest |change| {size[-1]:.2%}, "
              f"median {statistics.median(size):.3%}")
        for rel, name, a, f in sorted(changes, key=lambda c: -abs(c[0]))[:6]:
            print(f"  {rel:+7.2%}  {name}  ({a:.4g} -> {f:.4g})")


if __name__ == "__main__":
    main()
