"""Speed of the Gymnasium environment against Gymnasium's InvertedPendulum-v5 in the same process, vectorised
across two cores, batched (``gymnasium.make_vec``), and the cost of recording a run to rerun.

    python -m benchmarks.bench_env [--steps 4000] [--repeats 3] [--record-s 5] [--cpu-time]
    python -m benchmarks.bench_env --vector [--sizes 1,8,32,128] [--steps 4000] [--repeats 3]

Prints env steps per second of ``torquebed/TorqueTracking-v0`` through ``gymnasium.make`` (its wrappers
included, like the peer's), with the breakdown of one step (``Plant.step`` alone; plus the sensor readout;
per tick in µs: physics, the Python around it in ``Plant.step``, the sensor read, environment and wrappers),
``AsyncVectorEnv`` and ``SyncVectorEnv`` with 2 environments (total env steps per second), the peer's
``env.step`` rate, and the slow-down of a closed-loop run (``controllers.tracking.run_tracking``, sensor
feedback) by writing its rerun recording (``sim.recording.record_logs`` to an .rrd). ``--cpu-time`` times the in-process
measurements by this process's CPU time instead of wall time (steadier on a loaded shared machine; the
AsyncVectorEnv, whose work is in its workers, is then not measured).

``--vector``: the batched vector environment (``vectorization_mode="vector_entry_point"``, one thread) at each
N of ``--sizes``: env steps per CPU-second and per wall-second against the single env (``gymnasium.make``) and
the peer's (single and ``SyncVectorEnv`` of N) in the same process; the ceiling, physics alone (MuJoCo's batch
step against N ``mj_step`` calls of N single plants, the same ticks); the part of one batched env step each
stage takes; and wall-clock on two threads over one.
"""

from __future__ import annotations

import argparse
import contextlib
import math
import os
import tempfile
import time
from pathlib import Path

import gymnasium as gym
import mujoco
import numpy as np

import sim.plant
import torquebed  # noqa: F401  (registers the environment)
from benchmarks.bench_plant import PEER_ENV, best_rate, env_step_rate, peer_rate, require_peer
from controllers.feedback import make_feedback
from controllers.pi import PITorqueController
from controllers.tracking import run_tracking
from envs import ENV_ID
from sensor.readout import factory_calibration
from sim.batched import BatchedPlant
from sim.motor_torque import CurrentToTorqueMap
from sim.params import TestbedParams
from sim.plant import Plant
from sim.recording import DEFAULT_POSE_RATE_HZ, record_logs

ACTION_NM = 0.3  # [N·m] a constant command: the rig loaded, the gear stuck or creeping
VECTOR_SIZES = (1, 8, 32, 128)  # numbers of environments of the batched vector env
CEILING_N = 32  # N of the physics-alone ceiling, the per-part breakdown and the two-thread wall-clock
RECORD_AMPLITUDE_NM, RECORD_FREQUENCY_HZ = 0.5, 0.2  # the recorded run's reference sine [N·m], [Hz]


def env_rate(steps: int, repeats: int, clock=time.perf_counter) -> float:
    return env_step_rate(gym.make(ENV_ID), np.full(1, ACTION_NM, np.float32), steps, repeats, clock)


def breakdown_rates(steps: int, repeats: int, clock=time.perf_counter) -> dict[str, float]:
    p = TestbedParams()
    plant = Plant(p, "locked")
    sensor = make_feedback("sensor", p, 0)

    def plant_only() -> None:
        plant.reset()
        for _ in range(steps):
            plant.step(ACTION_NM)

    def with_sensor() -> None:
        plant.reset()
        for _ in range(steps):
            sensor.read(plant)
            plant.step(ACTION_NM)

    return {"plant": best_rate(plant_only, steps, repeats, clock),
            "plant+sensor": best_rate(with_sensor, steps, repeats, clock)}


class _NoPhysics:
    """Stands in for the ``mujoco`` module inside :mod:`sim.plant`: ``mj_step`` only advances the clock."""

    def __getattr__(self, name):
        return getattr(mujoco, name)

    @staticmethod
    def mj_step(model, data, nstep=1) -> None:
        data.time += nstep * model.opt.timestep


@contextlib.contextmanager
def _no_physics():
    """``Plant.step`` without its physics (the Python around ``mj_step`` only), within the block."""
    sim.plant.mujoco = _NoPhysics()
    try:
        yield
    finally:
        sim.plant.mujoco = mujoco


def tick_breakdown_us(steps: int, repeats: int, clock=time.perf_counter) -> dict[str, float]:
    """Per-tick µs of the parts of one env step (best of repeats each): the Python of ``Plant.step`` (its
    ``mj_step`` stubbed), the sensor read, and the environment with its wrappers (an env step with the
    physics stubbed, minus those two). The physics is the env step's time minus all three."""
    p = TestbedParams()
    plant = Plant(p, "locked")
    sensor = make_feedback("sensor", p, 0)
    env = gym.make(ENV_ID, episode_duration_s=(steps * repeats + 1) * p.simulation.control_period_s)
    action = np.full(1, ACTION_NM, np.float32)
    us = 1e6 / steps

    def plant_steps() -> None:
        for _ in range(steps):
            plant.step(ACTION_NM)

    def sensor_reads() -> None:
        for _ in range(steps):
            sensor.read(plant)

    def env_steps() -> None:  # one episode across the repeats: no reset timed
        for _ in range(steps):
            env.step(action)

    plant.step(ACTION_NM)
    env.reset(seed=0)
    sensor_us = us / best_rate(sensor_reads, 1, repeats, clock)
    with _no_physics():
        plant_us = us / best_rate(plant_steps, 1, repeats, clock)
        env_us = us / best_rate(env_steps, 1, repeats, clock)
    return {"plant_python": plant_us, "sensor": sensor_us, "env": env_us - plant_us - sensor_us}


def vector_rate(cls, n_envs: int, steps: int, repeats: int, clock=time.perf_counter, **kwargs) -> float:
    """Total env steps per second of ``n_envs`` environments in a vector env (autoreset on truncation)."""
    vec = cls([lambda: gym.make(ENV_ID) for _ in range(n_envs)], **kwargs)
    try:
        vec.reset(seed=0)
        action = np.full((n_envs, 1), ACTION_NM, np.float32)
        per_env = steps // n_envs

        def run() -> None:
            for _ in range(per_env):
                vec.step(action)

        return best_rate(run, per_env * n_envs, repeats, clock)
    finally:
        vec.close()


def make_vector(n: int, nthread: int = 1) -> gym.vector.VectorEnv:
    """The batched vector environment of N testbeds, reset."""
    vec = gym.make_vec(ENV_ID, num_envs=n, vectorization_mode="vector_entry_point", nthread=nthread)
    vec.reset(seed=0)
    return vec


def interleaved_rates(runs: dict, repeats: int, clock=time.perf_counter) -> dict[str, float]:
    """Best rate [count/s] of each ``name: (fn, count)``, the functions run in turn once per round: on a shared
    machine every one sees the same spells of load, so their ratios hold better than separate bests."""
    best = dict.fromkeys(runs, 0.0)
    for _ in range(repeats):
        for name, (fn, count) in runs.items():
            start = clock()
            fn()
            best[name] = max(best[name], count / (clock() - start))
    return best


def stepping(env, steps: int, value: float = ACTION_NM):
    """(fn, env steps) of about ``steps`` env steps (a vector env's in all) under a constant action of ``value``;
    a single env is reset when its episode ends, as a vector env autoresets."""
    n = getattr(env, "num_envs", None)
    space = env.single_action_space if n else env.action_space
    action = np.full(((n,) if n else ()) + space.shape, value, space.dtype)
    count = max(steps // (n or 1), 20)

    def run() -> None:
        for _ in range(count):
            _, _, terminated, truncated, _ = env.step(action)
            if n is None and (terminated or truncated):
                env.reset()

    return run, count * (n or 1)


def physics_runs(n: int, steps: int) -> dict:
    """Physics alone, the same testbed ticks: N single plants' ``mj_step`` (``n_substeps`` each) against one
    batch step of N testbeds (one thread); and with the plants' per-tick Python (``Plant.step`` against
    ``BatchedPlant.step``)."""
    p = TestbedParams()
    plants = [Plant(p, "locked") for _ in range(n)]
    batched = BatchedPlant([Plant(p, "locked") for _ in range(n)], nthread=1)
    batched.reset(range(n))
    for plant in plants:
        plant.step(ACTION_NM)  # the command's ctrl stays in place for the raw steps
    commands = np.full(n, ACTION_NM)
    batched.step(commands)
    count = max(steps // n, 20)

    def singles() -> None:
        for _ in range(count):
            for plant in plants:
                mujoco.mj_step(plant.model, plant.data, plant.n_substeps)

    def batch() -> None:
        for _ in range(count):
            batched.batch.step(None, batched.n_substeps)

    def plant_steps() -> None:
        for _ in range(count):
            for plant in plants:
                plant.step(ACTION_NM)

    def batched_steps() -> None:
        for _ in range(count):
            batched.step(commands)

    return {"mj_step": (singles, count * n), "batch": (batch, count * n), "Plant.step": (plant_steps, count * n),
            "BatchedPlant.step": (batched_steps, count * n)}


def batched_breakdown_us(n: int, steps: int, repeats: int, clock=time.perf_counter) -> dict[str, float]:
    """µs per env step of the parts of a batched step of N envs (best of repeats, in turn): the physics (the
    batch step alone), the Python of ``BatchedPlant.step`` around it, the sensor read, and the rest of the
    vector env (observation, load cell, reward, info)."""
    vec = make_vector(n).unwrapped
    action = np.full((n, 1), ACTION_NM, np.float32)
    commands = np.full(n, ACTION_NM)
    count = max(steps // n, 20)

    def loop(fn):
        def run() -> None:
            for _ in range(count):
                fn()
        return run, count * n

    rates = interleaved_rates({"total": loop(lambda: vec.step(action)),
                               "physics": loop(lambda: vec.plant.batch.step(None, vec.plant.n_substeps)),
                               "plant": loop(lambda: vec.plant.step(commands)),
                               "sensor": loop(lambda: vec._sensor.read(vec.plant))}, repeats, clock)
    us = {name: 1e6 / rate for name, rate in rates.items()}
    return {"physics": us["physics"], "plant_python": us["plant"] - us["physics"], "sensor": us["sensor"],
            "env": us["total"] - us["plant"] - us["sensor"], "total": us["total"]}


def vector_report(sizes: list[int], steps: int, repeats: int) -> None:
    """Print the batched vector environment's measurements (see the module docstring)."""
    cpu = time.process_time
    load = ", ".join(f"{x:.1f}" for x in os.getloadavg())
    print(f"{ENV_ID} batched (make_vec, vector_entry_point, 1 thread), locked fixture, constant {ACTION_NM} N·m, "
          f"best of {repeats} taken in turn with the single env and the peer ({os.cpu_count()} CPUs, load average "
          f"{load}); env steps per CPU-second, per wall-second")
    print(f"  {'N':>4s} {'single':>8s} {'batched':>8s} {'x single':>9s} {'wall':>7s} {'peer':>7s} "
          f"{'peer Sync':>10s} {'x peer Sync':>12s}")
    single_env = gym.make(ENV_ID)
    single_env.reset(seed=0)
    peer = gym.make(PEER_ENV)
    peer.reset(seed=0)
    for n in sizes:
        vec = make_vector(n)
        peer_vec = gym.make_vec(PEER_ENV, num_envs=n, vectorization_mode="sync")
        peer_vec.reset(seed=0)
        runs = {"single": stepping(single_env, steps), "batched": stepping(vec, steps),
                "peer": stepping(peer, steps, 0.0), "peer_sync": stepping(peer_vec, steps, 0.0)}
        r = interleaved_rates(runs, repeats, cpu)
        wall = interleaved_rates({"batched": stepping(vec, steps)}, repeats)["batched"]
        vec.close()
        peer_vec.close()
        print(f"  {n:4d} {r['single']:8,.0f} {r['batched']:8,.0f} {r['batched'] / r['single']:9.2f} {wall:7,.0f} "
              f"{r['peer']:7,.0f} {r['peer_sync']:10,.0f} {r['batched'] / r['peer_sync']:12.2f}")
    n = CEILING_N
    phys = interleaved_rates(physics_runs(n, steps), repeats, cpu)
    print(f"  ceiling, physics alone at N = {n} (testbed ticks per CPU-s): {phys['mj_step']:,.0f} by mj_step on "
          f"{n} plants, {phys['batch']:,.0f} by one batch step: {phys['batch'] / phys['mj_step']:.2f}x; with the "
          f"plants' Python: Plant.step {phys['Plant.step']:,.0f}, BatchedPlant.step {phys['BatchedPlant.step']:,.0f}"
          f" ({phys['BatchedPlant.step'] / phys['Plant.step']:.2f}x)")
    parts = batched_breakdown_us(n, steps, repeats, cpu)
    print(f"  one env step at N = {n}, CPU µs: physics {parts['physics']:.1f}, BatchedPlant.step Python "
          f"{parts['plant_python']:.2f}, sensor read {parts['sensor']:.2f}, rest of the env {parts['env']:.2f} "
          f"(total {parts['total']:.1f})")
    for n in sorted({CEILING_N, max(sizes)}):
        one, two = make_vector(n, 1), make_vector(n, 2)
        r = interleaved_rates({"one": stepping(one, steps), "two": stepping(two, steps)}, repeats)
        phys_one, phys_two = (BatchedPlant([Plant(TestbedParams(), "locked") for _ in range(n)], k) for k in (1, 2))
        count = max(steps // n, 20)

        def raw(batched, count=count, n=n):
            def run() -> None:
                for _ in range(count):
                    batched.batch.step(None, batched.n_substeps)
            return run, count * n

        for b in (phys_one, phys_two):
            b.reset(range(n))
        q = interleaved_rates({"one": raw(phys_one), "two": raw(phys_two)}, repeats)
        print(f"  wall-clock at N = {n}, 2 threads over 1: env {r['two'] / r['one']:.2f}x ({r['one']:,.0f} -> "
              f"{r['two']:,.0f} env steps/s), physics alone {q['two'] / q['one']:.2f}x ({q['one']:,.0f} -> "
              f"{q['two']:,.0f} ticks/s)")


def recording_overhead(duration_s: float, repeats: int) -> dict[str, float]:
    """Wall time of a closed-loop run and of recording its log to an .rrd [s] (best of repeats each)."""
    p = TestbedParams()
    dt = p.simulation.control_period_s
    n = round(duration_s / dt)
    reference = RECORD_AMPLITUDE_NM * np.sin(2 * np.pi * RECORD_FREQUENCY_HZ * np.arange(n) * dt)
    runs, records = [], []
    with tempfile.TemporaryDirectory() as tmp:
        for i in range(repeats):
            plant = Plant(p, "locked")
            start = time.perf_counter()
            controller = PITorqueController(CurrentToTorqueMap.from_params(p).command_limit_nm)
            log = run_tracking(p, plant, controller, "sensor", 0, reference)
            runs.append(time.perf_counter() - start)
            start = time.perf_counter()
            record_logs({"sine": log}, p, path=Path(tmp) / f"r{i}.rrd")
            records.append(time.perf_counter() - start)
            size = (Path(tmp) / f"r{i}.rrd").stat().st_size
    return {"run_s": min(runs), "record_s": min(records), "duration_s": duration_s, "rrd_bytes": size}


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--steps", type=int, default=4000, help="env steps per measurement (default 4000)")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--record-s", type=float, default=5.0, help="simulated seconds of the recorded run")
    parser.add_argument("--cpu-time", action="store_true",
                        help="time by this process's CPU time, not wall time (skips the AsyncVectorEnv)")
    parser.add_argument("--vector", action="store_true", help="measure the batched vector env only")
    parser.add_argument("--sizes", default=",".join(map(str, VECTOR_SIZES)),
                        help="numbers of environments of --vector (default %(default)s)")
    args = parser.parse_args(argv)
    clock = time.process_time if args.cpu_time else time.perf_counter
    require_peer()
    factory_calibration(TestbedParams())  # once, before timing (and inherited by the forked workers)
    if args.vector:
        vector_report([int(n) for n in args.sizes.split(",")], args.steps, args.repeats)
        return
    single = env_rate(args.steps, args.repeats, clock)
    parts = breakdown_rates(args.steps, args.repeats, clock)
    tick = tick_breakdown_us(args.steps, args.repeats, clock)
    peer = peer_rate(args.steps, args.repeats, clock)
    async2 = (math.nan if args.cpu_time else
              vector_rate(gym.vector.AsyncVectorEnv, 2, args.steps, args.repeats, context="fork"))
    sync2 = vector_rate(gym.vector.SyncVectorEnv, 2, args.steps, args.repeats, clock)
    rec = recording_overhead(args.record_s, args.repeats)
    load = ", ".join(f"{x:.1f}" for x in os.getloadavg())
    print(f"{ENV_ID}, locked fixture, constant {ACTION_NM} N·m command, best of {args.repeats}, "
          f"{'CPU' if args.cpu_time else 'wall'} time ({os.cpu_count()} CPUs, load average {load})")
    print(f"  single env (gymnasium.make)         {single:9.0f} steps/s")
    print(f"    Plant.step alone                  {parts['plant']:9.0f} ticks/s")
    print(f"    Plant.step + sensor readout       {parts['plant+sensor']:9.0f} ticks/s")
    physics_us = 1e6 / single - tick["plant_python"] - tick["sensor"] - tick["env"]
    print(f"    per env step: physics {physics_us:.1f} µs, Plant.step Python {tick['plant_python']:.1f} µs, "
          f"sensor read {tick['sensor']:.1f} µs, env + wrappers {tick['env']:.1f} µs")
    if args.cpu_time:
        print("  AsyncVectorEnv, 2 envs (2 cores)    not measured (its workers' CPU time is not this process's)")
    else:
        print(f"  AsyncVectorEnv, 2 envs (2 cores)    {async2:9.0f} env steps/s ({async2 / single:.2f}x single)")
    print(f"  SyncVectorEnv, 2 envs               {sync2:9.0f} env steps/s")
    print(f"  {PEER_ENV} env.step       {peer:9.0f} steps/s")
    async_ratio = "" if args.cpu_time else f", async 2 envs {async2 / peer:.2f}x"
    print(f"  ratio to peer: single {single / peer:.2f}x{async_ratio}")
    print(f"rerun recording of a {rec['duration_s']:g} s closed-loop run (sensor feedback, "
          f"{DEFAULT_POSE_RATE_HZ:g} Hz 3D pose):")
    print(f"  run {rec['run_s']:.2f} s, recording {rec['record_s']:.3f} s ({rec['rrd_bytes'] / 1e6:.1f} MB): "
          f"slow-down {rec['record_s'] / rec['run_s']:.1%} (target < 30 %)")


if __name__ == "__main__":
    main()
