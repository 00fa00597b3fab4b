"""Admittance control of the free lever pushed by a scripted hand (paper Sec. IV-C, Eqs. 30-34, Fig. 13).

    python -m experiments.admittance [--seed N] [--duration S] [--json PATH] [--plot DIR] [--params TOML]

The external torque comes from the torque sensor, as in the paper (the driver's current cannot see a torque
applied to the lever), so there is no --feedback choice here.

The hand (:data:`sim.protocols.PUSHES`, assumed; the paper gives no trajectory): a hand holding the lever is
an impedance, a spring and damper at the joint (5 N·m/rad, 500 N/m at the 0.1 m lever tip, a relaxed grip)
pulled along a minimum-jerk path of 0.5 rad, in 4 s (slow push) or 0.4 s (fast push). Through the virtual
damper B_d the slow push needs a low torque and the lever follows the hand; the fast push needs a high torque
and the lever lags: the controller resists it, as the paper's Fig. (a)/(b) show ("mild" against "pronounced" damping).

Figures: the lever's angle lag behind the hand at its largest, the peak hand torque and velocity, their ratio
(the damping felt by the hand, N·m·s/rad), and how closely the lever's velocity follows the virtual
dynamics' ω_r (RMS of ω - ω_r over the peak of ω_r).
"""

from __future__ import annotations

import sys
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path

import numpy as np

from controllers.admittance import (
    PAPER_DESIRED_DAMPING_NMS_PER_RAD,
    PAPER_DESIRED_INERTIA_KGM2,
    AdmittanceController,
)
from controllers.feedback import ControllerFactory, build_controller, loop_measurements, with_readout_meta
from experiments.common import (
    add_experiment_args,
    cli_parser,
    load_params_arg,
    record_rerun,
    run_errors,
    short_run_banner,
    write_outputs,
)
from sim.figures import save_figure
from sim.motor_torque import CurrentToTorqueMap
from sim.params import ParameterError, TestbedParams
from sim.plant import Plant
from sim.protocols import PUSH_ANGLE_RAD, PUSHES, Push
from sim.run import Controller, run_loop
from sim.runlog import RunLog

PLOT_FILES = ("admittance.png",)  # the files --plot writes


@dataclass(frozen=True)
class PushOutcome:
    """One push: how the lever moved and what the hand felt.

    Attributes
    ----------
    name : str
    push_s : float
        Duration of the hand's motion [s].
    peak_hand_torque_nm : float
    peak_velocity_rad_s : float
        Of the lever.
    felt_damping_nms_per_rad : float
        peak hand torque / peak lever velocity.
    max_lag_rad : float
        Largest hand angle minus lever angle.
    final_angle_rad : float
        Lever angle at the end [rad] (the hand ends at ``PUSH_ANGLE_RAD``).
    velocity_tracking : float
        RMS(ω - ω_r) / max |ω_r| [-]: how closely the lever follows the virtual mass-damper.
    """

    name: str
    push_s: float
    peak_hand_torque_nm: float
    peak_velocity_rad_s: float
    felt_damping_nms_per_rad: float
    max_lag_rad: float
    final_angle_rad: float
    velocity_tracking: float
    log: RunLog | None = field(default=None, repr=False, compare=False)
    hand: Push | None = field(default=None, repr=False, compare=False)  # the hand this push used

    def to_dict(self) -> dict:
        d = asdict(self)
        d.pop("log")
        d.pop("hand")
        return d


@dataclass(frozen=True)
class AdmittanceResult:
    """Slow and fast push. ``follows_slow``: the lever ends within 10 % of the hand's travel and lags it by
    less than 20 % of it; ``resists_fast``: the fast push needs a larger hand torque and leaves a larger lag."""

    pushes: list[PushOutcome]
    seed: int

    def logs(self) -> dict[str, RunLog]:
        """Push name -> its log."""
        return {p.name: p.log for p in self.pushes}

    @property
    def follows_slow(self) -> bool:
        slow = self.pushes[0]
        return (abs(slow.final_angle_rad - PUSH_ANGLE_RAD) < 0.1 * PUSH_ANGLE_RAD
                and slow.max_lag_rad < 0.2 * PUSH_ANGLE_RAD)

    @property
    def resists_fast(self) -> bool:
        slow, fast = self.pushes
        return fast.peak_hand_torque_nm > 3 * slow.peak_hand_torque_nm and fast.max_lag_rad > 3 * slow.max_lag_rad

    def plot(self, directory: Path) -> list[Path]:
        """The pushes' torque, angle and velocity, written to ``directory`` (paths)."""
        return [plot_admittance(self, directory)]

    def rows(self) -> list[dict]:
        """None: the paper gives no admittance figures (Fig. 13 is qualitative; see the behaviours)."""
        return []

    def to_dict(self) -> dict:
        return {"rows": self.rows(), "seed": self.seed, "pushes": [p.to_dict() for p in self.pushes],
                "follows_slow": self.follows_slow, "resists_fast": self.resists_fast}


def make_controller(params: TestbedParams) -> AdmittanceController:
    """The paper's admittance controller at the plant's control period, limited to the driver's current limit.

    Raises
    ------
    ParameterError
        If the control period is too long to discretise the paper's M_d, B_d (names
        ``simulation.control_period_s`` and its valid range).
    """
    dt = params.simulation.control_period_s
    limit_nm = CurrentToTorqueMap.from_params(params).command_limit_nm  # the driver's current limit
    try:
        return AdmittanceController(period_s=dt, output_limit_nm=limit_nm)
    except ValueError as exc:
        longest_s = 2.0 * PAPER_DESIRED_INERTIA_KGM2 / PAPER_DESIRED_DAMPING_NMS_PER_RAD
        raise ParameterError(f"simulation.control_period_s = {dt:g} s: the admittance controller cannot "
                             f"discretise the paper's M_d and B_d at this period ({exc}); valid range for "
                             f"admittance control (0, {longest_s:g}) s") from exc


def run_push(params: TestbedParams, push: Push, seed: int = 0, duration_s: float | None = None,
             progress: bool = False, controller: Controller | ControllerFactory | None = None) -> PushOutcome:
    """One push of the hand (:data:`sim.protocols.PUSHES`) on the free lever under admittance control
    (``controller``: as for :func:`run_admittance`)."""
    dt = params.simulation.control_period_s
    hand = push
    if duration_s is not None:  # short mode: the same push, cut short
        hand = replace(push, push_s=min(push.push_s, duration_s), before_s=min(push.before_s, duration_s / 4),
                       after_s=min(push.after_s, duration_s / 4))
    plant = Plant(params, "free")

    def hand_torque(k: int, plant: Plant) -> float:
        return hand.torque_nm(k * dt, plant.output_angle_rad, plant.output_velocity_rad_s)

    measurements = loop_measurements("sensor", params, seed)
    log = with_readout_meta(
        run_loop(plant, build_controller(controller, lambda p, _: make_controller(p), params, "sensor"),
                 round(hand.duration_s / dt), measurements=measurements, external=hand_torque,
                 progress_label=push.name if progress else None,
                 meta={"feedback": "sensor", "push_s": hand.push_s, "seed": seed}), measurements)
    hand_angle, _ = hand.path(log["time"])
    omega, omega_ref = log["qd_motor"], log["omega_ref"]
    peak_torque = float(np.abs(log["tau_ext"]).max())
    peak_velocity = float(np.abs(log["qd"]).max())
    return PushOutcome(push.name.split()[0], hand.push_s, peak_torque, peak_velocity,
                       peak_torque / peak_velocity if peak_velocity > 0 else float("inf"),
                       float(np.max(hand_angle - log["q"])), float(log["q"][-1]),
                       float(np.sqrt(np.mean((omega - omega_ref) ** 2)) / max(np.abs(omega_ref).max(), 1e-12)),
                       log=log, hand=hand)


def run_admittance(params: TestbedParams | None = None, seed: int = 0, duration_s: float | None = None,
                   progress: bool = False,
                   controller: Controller | ControllerFactory | None = None) -> AdmittanceResult:
    """The slow and the fast push (``duration_s`` caps each push: short mode).

    ``controller``: the controller of each push (:class:`sim.run.Controller`, reset before each), or a factory
    ``(params, "sensor") -> Controller``; by default the paper's admittance controller
    (:func:`make_controller`). It observes ``tau_sensor``, ``q_motor`` and ``qd_motor``; the hand's torque
    on the lever is ``tau_ext`` in the logs.
    """
    params = params or TestbedParams()
    return AdmittanceResult([run_push(params, push, seed, duration_s, progress, controller) for push in PUSHES],
                            seed)


def format_result(result: AdmittanceResult) -> str:
    lines = ["Admittance control (M_d = 0.03 kg·m², B_d = 0.6 N·m·s/rad, K_d = 0), free lever, scripted hand",
             f"{'push':5s} {'time [s]':>8s} {'peak hand torque [N·m]':>23s} {'peak velocity [rad/s]':>22s} "
             f"{'felt damping [N·m·s/rad]':>25s} {'max lag [rad]':>14s} {'final angle [rad]':>18s} "
             f"{'RMS(ω-ω_r)/max ω_r':>19s}"]
    for p in result.pushes:
        lines.append(f"{p.name:5s} {p.push_s:8.2f} {p.peak_hand_torque_nm:23.3f} {p.peak_velocity_rad_s:22.3f} "
                     f"{p.felt_damping_nms_per_rad:25.3f} {p.max_lag_rad:14.4f} {p.final_angle_rad:18.3f} "
                     f"{p.velocity_tracking:19.3f}")
    lines.append(f"paper: the lever follows a slow push (sim: {'yes' if result.follows_slow else 'NO'}) and resists "
                 f"a fast one (sim: {'yes' if result.resists_fast else 'NO'})")
    return "\n".join(lines)


def plot_admittance(result: AdmittanceResult, directory: Path) -> Path:
    """Figure like the paper's: per push, hand torque, lever angle and velocity against the hand's path."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(3, 2, figsize=(10, 7), sharex="col")
    for col, p in enumerate(result.pushes):
        log = p.log
        t = log["time"]
        hand_angle, hand_velocity = p.hand.path(t)
        axes[0][col].plot(t, log["tau_ext"], label="hand torque")
        axes[0][col].plot(t, -log["tau_sensor"], "--", lw=0.8, label="τ_ext from the sensor")
        axes[0][col].set(title=f"{p.name} push ({p.push_s:g} s)", ylabel="torque [N·m]")
        axes[1][col].plot(t, hand_angle, "k--", lw=0.8, label="hand path")
        axes[1][col].plot(t, log["q"], label="lever")
        axes[1][col].set(ylabel="angle [rad]")
        axes[2][col].plot(t, hand_velocity, "k--", lw=0.8, label="hand path")
        axes[2][col].plot(t, log["qd"], label="lever")
        axes[2][col].plot(t, log["omega_ref"], ":", label="ω_r (virtual)")
        axes[2][col].set(ylabel="velocity [rad/s]", xlabel="time [s]")
        for ax in axes[:, col]:
            ax.legend(fontsize=6)
    fig.suptitle("Admittance control, free lever (paper Fig. 13)", fontsize=9)
    return save_figure(fig, directory, PLOT_FILES[0])


def main(argv: list[str] | None = None) -> None:
    parser = cli_parser(__doc__, __spec__.name)
    add_experiment_args(parser, feedback=False, figures=PLOT_FILES)
    args = parser.parse_args(argv)
    params = load_params_arg(parser, args, checks=(make_controller,))
    print("running the slow and fast pushes (progress on stderr) ...", file=sys.stderr)
    with run_errors(parser):
        result = run_admittance(params, args.seed, args.duration, progress=True)
    short_run_banner(args)
    print(format_result(result))
    write_outputs(args, result.to_dict(), result.plot)
    record_rerun(args, result.logs(), params)


if __name__ == "__main__":
    main()
