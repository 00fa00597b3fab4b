"""Plant speed against pure MuJoCo stepping and a Gymnasium peer, measured in one process.

    python -m benchmarks.bench_plant [--duration 10] [--repeats 3]

Prints control ticks per second of a locked-fixture run at 1 kHz (with and without recording a run log),
the same model's pure stepping (mj_step with nstep, no Python per tick), Gymnasium's InvertedPendulum-v5
env steps per second, the Python overhead and the ratio to the peer, and the fidelity check: the locked
fixture's control-relevant mode at the rule's step against a 16x finer step.
"""

from __future__ import annotations

import argparse
import time

import mujoco
import numpy as np

from sim.characterize import linearizable_plant, linearized_modes
from sim.params import TestbedParams
from sim.plant import Plant
from sim.run import run_open_loop

PEER_ENV = "InvertedPendulum-v5"
REFINEMENT = 16


def best_rate(fn, count: int, repeats: int, clock=time.perf_counter) -> float:
    """Highest count/second over repeats (the least disturbed run on a shared machine); ``clock`` is wall
    time by default, ``time.process_time`` counts only this process's CPU time."""
    rates = []
    for _ in range(repeats):
        start = clock()
        fn()
        rates.append(count / (clock() - start))
    return max(rates)


def plant_rates(duration_s: float, repeats: int) -> dict[str, float]:
    p = TestbedParams()
    n = round(duration_s / p.simulation.control_period_s)
    tau = 0.5 + 0.3 * np.sin(2 * np.pi * 0.2 * np.arange(n) * p.simulation.control_period_s)

    def logged() -> None:
        run_open_loop(Plant(p, "locked"), tau, progress=False)

    def stepped() -> None:
        plant = Plant(p, "locked")
        for u in tau:
            plant.step(u)

    plant = Plant(p, "locked")
    model, data = plant.model, mujoco.MjData(plant.model)
    data.ctrl[0] = 0.5 / p.motor.gear_ratio

    def pure() -> None:
        mujoco.mj_step(model, data, n * plant.n_substeps)

    return {"logged": best_rate(logged, n, repeats), "stepped": best_rate(stepped, n, repeats),
            "pure": best_rate(pure, n, repeats), "substeps": plant.n_substeps, "ticks": n}


def env_step_rate(env, action, steps: int, repeats: int, clock=time.perf_counter) -> float:
    """Best ``env.step`` rate [steps/s] of a Gymnasium env under a constant ``action`` (reset when an episode ends)."""
    env.reset(seed=0)

    def run() -> None:
        for _ in range(steps):
            _, _, terminated, truncated, _ = env.step(action)
            if terminated or truncated:
                env.reset()

    return best_rate(run, steps, repeats, clock)


def require_peer() -> None:
    """Exit, before any measurement, with how to install the peer's dependencies if it cannot be made."""
    import gymnasium as gym

    try:
        gym.make(PEER_ENV).close()
    except (ImportError, gym.error.DependencyNotInstalled) as exc:
        raise SystemExit(f"{PEER_ENV}, the peer of this benchmark, needs Gymnasium's MuJoCo extras: "
                         f'pip install -e ".[bench]" ({exc})') from None


def peer_rate(steps: int, repeats: int, clock=time.perf_counter) -> float:
    import gymnasium as gym

    env = gym.make(PEER_ENV)
    return env_step_rate(env, np.zeros(env.action_space.shape, dtype=env.action_space.dtype), steps, repeats, clock)


def fidelity() -> tuple[object, object]:
    coarse = linearizable_plant(None, "locked", 1.0)
    fine = linearizable_plant(None, "locked", 1.0, timestep_s=coarse.timestep_s / REFINEMENT)
    return linearized_modes(coarse)[0], linearized_modes(fine)[0]


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--duration", type=float, default=10.0, help="simulated seconds per run (default 10)")
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args(argv)
    require_peer()
    r = plant_rates(args.duration, args.repeats)
    peer = peer_rate(r["ticks"], args.repeats)
    coarse, fine = fidelity()
    print(f"locked fixture, {args.duration:g} s at 1 kHz, {r['substeps']} physics substeps per tick")
    print(f"  run with log (run_open_loop)  {r['logged']:9.0f} ticks/s   real-time factor {r['logged'] / 1000:6.1f}"
          f"   wall {r['ticks'] / r['logged']:.2f} s")
    print(f"  Plant.step only               {r['stepped']:9.0f} ticks/s   real-time factor {r['stepped'] / 1000:6.1f}")
    print(f"  pure mj_step(nstep)           {r['pure']:9.0f} ticks/s")
    print(f"  {PEER_ENV} env.step  {peer:9.0f} steps/s")
    print(f"  Python overhead vs pure: run {r['pure'] / r['logged'] - 1:6.1%}, "
          f"step {r['pure'] / r['stepped'] - 1:6.1%}")
    print(f"  ratio to peer: run {r['logged'] / peer:.2f}x, step {r['stepped'] / peer:.2f}x")
    print(f"fidelity, control-relevant mode of the locked fixture (h vs h/{REFINEMENT}):")
    print(f"  natural frequency {coarse.natural_frequency_hz:8.2f} Hz vs {fine.natural_frequency_hz:8.2f} Hz "
          f"({coarse.natural_frequency_hz / fine.natural_frequency_hz - 1:+.2%})")
    print(f"  damping ratio     {coarse.damping_ratio:8.4f}    vs {fine.damping_ratio:8.4f}    "
          f"({coarse.damping_ratio / fine.damping_ratio - 1:+.2%})")


if __name__ == "__main__":
    main()
