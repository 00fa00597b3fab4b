"""The worked examples of the documentation, made and run here so that the pages cannot go stale.

    python -m tests.doc_examples [--write] [--out DIR]

``docs/discrepancy.md``: the demo (``experiments.discrepancy_demo``, viscous friction hidden in a log of the
testbed's free lever) analysed by ``experiments.discrepancy``, its report shortened, and what it says.

``docs/own_logs.md``: three records as drives write them, each analysed straight from its file through a rig's
``[log]`` table:

- ``emps``: the EMPS benchmark's estimation record as it is (``../shared/data/emps/DATA_EMPS.mat``; the force is
  ``gtau * vir``), validated on its pulses record; left out where the records are absent.
- ``servo``: a hobby servo's JSON log: a header object and a list of records (a host clock in ms, position in
  degrees, a 16-bit PWM register in two's complement with 885 counts = 100 % duty, ``torque_enable``), read
  every 5.3 ms ± 35 %. Made by the independent simulator (``tests/independent``): a servo whose Coulomb
  friction is 1.3 times what its rig file states.
- ``robot``: a robot joint's CSV log with its own column names and units (ms, degrees, mN·m, the effort's sign
  reversed), at 1 kHz. Made by the independent simulator: a joint whose viscous friction is twice the rig's.

Each example is a set of text blocks (a rig file, a command, the head of a record, what a command prints); a
page holds each block between ``<!-- example: NAME -->`` and ``<!-- end -->``. With ``--write`` the pages'
blocks are replaced by what the examples give now; without it, the stale blocks are named. ``--out DIR`` keeps
the records and rig files, to run the pages' commands in ``DIR``. ``tests/test_doc_examples.py`` checks that
the pages hold what the examples give.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import math
import re
import sys
import textwrap
from collections.abc import Callable
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"
EMPS = ROOT.parent / "shared" / "data" / "emps"
EMPS_SHOWN = "../shared/data/emps"  # the records' folder as the page's command names it, from the project's root
DURATION_S = 20.0
SEED = 3
SERVO_DERIVATIVE_HZ = 8.0  # the servo's velocity filter: a narrow one keeps its duty's noise out of the logger's band
BLOCK = re.compile(r"(<!-- example: (?P<name>[\w-]+) -->\n)(?P<body>.*?)(\n<!-- end -->)", re.S)

EMPS_RIG = """model = "rigid-joint"
joint = "slide"
mass_kg = 95.1
effort_gain = 1.0
free = []

[friction]
viscous = 203.5

[log]
columns = {time = "t", tau_cmd = "vir * gtau", q = "qm", q_ref = "qg"}
"""

SERVO_RIG = """model = "rigid-joint"
joint = "hinge"
inertia_kgm2 = 0.01           # servo rotor and arm
effort_gain = 3.0             # N·m per unit duty: the datasheet's stall torque
peak_effort = 1.0             # 100 % duty, in the units of tau_cmd

[friction]
coulomb = 0.1                 # N·m
viscous = 0.37                # N·m·s/rad

[log]
enable = "torque_enable"      # keep the rows where the torque is on
resample = "5 ms"             # the logger's clock jitters: put the record on a 5 ms grid
interpolation = "linear"
columns = {time = "timestamp", tau_cmd = "pwm / header.pwm_full_scale", q = "position", q_ref = "goal_position"}
units = {time = "ms", q = "deg", q_ref = "deg"}
twos_complement = {pwm = 16}  # the PWM register: an unsigned 16-bit count
"""

ROBOT_RIG = """model = "rigid-joint"
joint = "hinge"
inertia_kgm2 = 1.2
effort_gain = 1.0
peak_effort = 80.0            # N·m

[friction]
coulomb = 2.0                 # N·m
viscous = 3.0                 # N·m·s/rad
"""

ROBOT_OPTIONS = ["--log", "columns.time=time_ms", "--log", "columns.tau_cmd=-tau2_cmd", "--log", "columns.q=q2",
                 "--log", "units.time=ms", "--log", "units.tau_cmd=mN·m", "--log", "units.q=deg"]


# ------------------------------------------------------------------------------------------------- the records


def servo_record(path: Path) -> None:
    """A servo's JSON log (module docstring), written to ``path``."""
    from tests.independent import realistic as r
    from tests.independent.rigsim import PID, Plant, QuantisedCommand, multisine, simulate

    n = int(round(DURATION_S / r.DT))
    inertia, gain = r.SERVO["inertia"] + r.ARM["inertia"], r.SERVO["torque_per_duty"]
    plant = Plant("hinge", inertia, coulomb=1.3 * r.SERVO["coulomb"], viscous=r.SERVO["viscous"], effort_gain=gain,
                  peak_effort=1.0, stick_velocity=1e-4)
    reference = multisine(n, 0.4, SEED)
    pid = PID.tuned(reference, inertia / gain, r.BANDWIDTH_HZ, 1.0, derivative_cutoff_hz=SERVO_DERIVATIVE_HZ)
    run = simulate(plant, QuantisedCommand(pid, 1.0 / r.PWM_FULL_SCALE, 1.0), n, seed=SEED,
                   encoder_step=r._encoder(r.SERVO["encoder_counts"]))
    rng = np.random.default_rng(SEED)
    stamps = r.logger_stamps(DURATION_S - 2 * r.DT, rng)
    ticks = np.floor(stamps / r.DT + 1e-9).astype(int)
    position = r.measured_at_ticks(run)[ticks]
    enabled = (stamps > 0.4) & (stamps < DURATION_S - 0.3)
    registers = [r.duty_to_register(u) if on else 0 for u, on in zip(run.tau_cmd[ticks], enabled, strict=True)]
    counts = np.round(position / r._encoder(r.SERVO["encoder_counts"]))
    records = [{"timestamp": round(1000.0 * t + 1532.0, 3), "position": round(float(c) * 360.0 / 4096, 5),
                "pwm": int(reg), "input_volts": round(12.0 + 0.05 * float(rng.standard_normal()), 2),
                "goal_position": round(math.degrees(float(reference.position[k])), 4), "torque_enable": bool(on)}
               for t, c, reg, k, on in zip(stamps, counts, registers, ticks, enabled, strict=True)]
    header = {"servo": "hobby servo, 12-bit encoder", "arm_length_m": 0.2, "supply_v": 12.0, "pwm_full_scale": 885,
              "gains": {"kp": 32, "kd": 6}}
    path.write_text(json.dumps({"header": header, "records": records}, indent=1) + "\n", encoding="utf-8")


def robot_record(path: Path) -> None:
    """A robot joint's CSV log (module docstring), written to ``path``."""
    from tests.independent import realistic as r
    from tests.independent.rigsim import PID, Plant, multisine, simulate

    n = int(round(DURATION_S / r.DT))
    plant = Plant("hinge", r.ROBOT["inertia"], coulomb=r.ROBOT["coulomb"], viscous=2 * r.ROBOT["viscous"],
                  peak_effort=r.ROBOT["peak_effort"], stick_velocity=1e-4)
    reference = multisine(n, 0.8, SEED)
    run = simulate(plant, PID.tuned(reference, r.ROBOT["inertia"], r.BANDWIDTH_HZ, r.ROBOT["peak_effort"]), n,
                   seed=SEED, encoder_step=r._encoder(r.ROBOT["encoder_counts"]))
    velocity = np.gradient(run.q, run.time)
    with path.open("w", encoding="utf-8") as fh:
        fh.write("time_ms,q2,dq2,tau2_cmd,temp2\n")
        for t, q, v, u in zip(run.time, run.q, velocity, run.tau_cmd, strict=True):
            fh.write(f"{1000 * t:.1f},{math.degrees(q):.6f},{math.degrees(v):.4f},{-1000 * u:.2f},31.5\n")


# ------------------------------------------------------------------------------------------------ the examples


def _head(path: Path, lines: int) -> str:
    with path.open(encoding="utf-8") as fh:
        return "".join(next(fh) for _ in range(lines)).rstrip("\n")


def _json_head(path: Path) -> str:
    data = json.loads(path.read_text(encoding="utf-8"))
    shown = {"header": data["header"], "records": data["records"][100:102]}
    text = json.dumps(shown, indent=1)
    return text.replace("\n ]\n}", ",\n  ...\n ]\n}")


SHOWN = ("Findings", "Tentative", "Final model", "Unexplained", "Relative effort", "Verdict")


def _printed(argv: list[str], shown: tuple[str, ...] = SHOWN) -> str:
    """What ``python -m experiments.discrepancy ARGV`` prints of the mapping and of the sections ``shown`` (the
    report's unindented lines that start so, with their indented lines)."""
    from experiments import discrepancy

    out = io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(io.StringIO()):
        discrepancy.main(argv)
    keep, inside = [], False
    for line in out.getvalue().splitlines():
        if not line.startswith(" "):
            inside = line.startswith(shown)
        mapping = re.match(r"[\w.]+ ?(\[span \d+ of \d+\])?: ", line) and not line.startswith(("Verdict", "wrote"))
        if inside or mapping:
            keep.append(line)
    return "\n".join(keep)


def _command(argv: list[str]) -> str:
    quoted = [f"'{a}'" if any(c in a for c in " *·()") else a for a in argv]
    return "python -m experiments.discrepancy " + " ".join(quoted)


def discrepancy_blocks(folder: Path) -> dict[str, str]:
    """docs/discrepancy.md's worked example: the demo's log analysed, made in ``folder``."""
    from experiments import discrepancy_demo

    out = io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(io.StringIO()):
        discrepancy_demo.main(["--effect", "viscous_friction", "--out", str(folder / "demo")])
    hidden = next(line for line in out.getvalue().splitlines() if line.startswith("hidden:"))
    saved = folder / "demo" / "extended.toml"
    report = _printed([str(folder / "demo" / "demo_log.csv"), "--rig", str(folder / "demo" / "demo_rig.toml"),
                       "--save-rig", str(saved), "--json", str(folder / "demo" / "result.json"), "--no-plot",
                       "--workers", "1"],
                      ("Baseline held-out", "Findings", "Final model", "Residual left", "Relative effort",
                       "The logs cannot", "MuJoCo replay", "Verdict"))
    commands = ("python -m experiments.discrepancy_demo --effect viscous_friction --out demo/\n"
                f"# {hidden}\n"
                "python -m experiments.discrepancy demo/demo_log.csv --rig demo/demo_rig.toml --save-rig "
                "demo/extended.toml")
    return {"demo-commands": commands, "demo-output": report.replace(str(saved), "demo/extended.toml"),
            "demo-summary": _demo_summary(json.loads((folder / "demo" / "result.json").read_text(encoding="utf-8")),
                                          hidden)}


def _demo_summary(result: dict, hidden: str) -> str:
    """What the worked example shows, in figures of its result."""
    truth = float(re.search(r"= (\S+)", hidden).group(1))
    found = result["findings"][0]["parameters"]["viscous"]["value"]
    errors = result["logs"][0]["relative_effort_error"]
    replay = result["baseline"]["replay"]
    return textwrap.fill(
            f"The viscous coefficient comes back within {100 * abs(found / truth - 1):.2g} %, as a re-fit of the "
            f"rig's own value; the effort prediction error on the held-out part falls from "
            f"{100 * errors['baseline']:.3g} % to {100 * errors['final']:.2g} % of the command, and that is the "
            f"figure of `demo/extended.toml` as an analysis of it reads it. The replay confirms the saved rig: the "
            f"lever's angle follows the log to {1e3 * replay['rmse_extended']:.2g} mrad instead of "
            f"{1e3 * replay['rmse_baseline']:.3g} mrad.", width=115)


def own_logs_blocks(folder: Path) -> dict[str, str]:
    """Every block of docs/own_logs.md, made in ``folder`` (the EMPS blocks only where its records are present)."""
    blocks: dict[str, str] = {}
    runs: list[tuple[str, str, Callable[[Path], None] | None, str, list[str]]] = [
        ("servo", "servo.json", servo_record, SERVO_RIG, []),
        ("robot", "robot.csv", robot_record, ROBOT_RIG, ROBOT_OPTIONS),
    ]
    if (EMPS / "DATA_EMPS.mat").exists():  # shown as run from the project's root, beside ../shared
        runs.insert(0, ("emps", f"{EMPS_SHOWN}/DATA_EMPS.mat", None, EMPS_RIG,
                        ["--validate", f"{EMPS_SHOWN}/DATA_EMPS_PULSES.mat"]))
    for name, record, make, rig, options in runs:
        rig_path = folder / f"{name}.toml"
        rig_path.write_text(rig, encoding="utf-8")
        if make is None:
            record_arg, extra = str(ROOT / record), ["--validate", str(ROOT / options[1])]
        else:
            make(folder / record)
            record_arg, extra = str(folder / record), options
        argv = [record, "--rig", rig_path.name, *options]
        run = [record_arg, "--rig", str(rig_path), *extra, "--no-plot", "--no-replay", "--workers", "1"]
        blocks[f"{name}-rig"] = rig.rstrip("\n")
        blocks[f"{name}-command"] = _command(argv)
        if name == "servo":
            blocks["servo-record"] = _json_head(folder / record)
        elif name == "robot":
            blocks["robot-record"] = _head(folder / record, 4)
        blocks[f"{name}-output"] = _printed(run)
    return blocks


PAGES: dict[str, Callable[[Path], dict[str, str]]] = {"discrepancy.md": discrepancy_blocks,
                                                      "own_logs.md": own_logs_blocks}


def page_blocks(text: str) -> dict[str, str]:
    """The page's example blocks: name -> text inside its code fence."""
    return {m["name"]: _unfenced(m["body"]) for m in BLOCK.finditer(text)}


def _unfenced(body: str) -> str:
    lines = body.splitlines()
    return "\n".join(lines[1:-1]) if lines and lines[0].startswith("```") else body


def _fence(name: str, body: str) -> str:
    if name.endswith("-summary"):
        return body
    kind = ("toml" if name.endswith("-rig") else "json" if name == "servo-record" else
            "bash" if name.endswith("-commands") else "text")
    return f"```{kind}\n{body}\n```"


def written(text: str, blocks: dict[str, str]) -> str:
    """The page ``text`` with every example block replaced by ``blocks``' (blocks not made are left)."""
    def replace(m: re.Match) -> str:
        name = m["name"]
        body = _fence(name, blocks[name]) if name in blocks else m["body"]
        return f"{m.group(1)}{body}{m.group(4)}"

    return BLOCK.sub(replace, text)


NUMBER = re.compile(r"[-+]?\d+(?:\.\d+)?(?:[eE][-+]?\d+)?")


def same(a: str, b: str, rel: float = 2e-3) -> bool:
    """Texts equal but for the last digits of their numbers (a run on another machine may round otherwise)."""
    if NUMBER.sub("#", a) != NUMBER.sub("#", b):
        return False
    return all(math.isclose(float(x), float(y), rel_tol=rel, abs_tol=1e-9)
               for x, y in zip(NUMBER.findall(a), NUMBER.findall(b), strict=True))


def main(argv: list[str] | None = None) -> int:
    import tempfile

    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--write", action="store_true", help="rewrite the pages' example blocks")
    parser.add_argument("--out", type=Path, help="keep the example records and rig files in this folder")
    args = parser.parse_args(argv)
    stale = []
    for page, make in PAGES.items():
        with tempfile.TemporaryDirectory() as temporary:
            folder = args.out / page.removesuffix(".md") if args.out else Path(temporary)
            folder.mkdir(parents=True, exist_ok=True)
            blocks = make(folder)
        text = (DOCS / page).read_text(encoding="utf-8")
        if args.write:
            (DOCS / page).write_text(written(text, blocks), encoding="utf-8")
            print(f"wrote {len(blocks)} blocks to docs/{page}")
        else:
            shown = page_blocks(text)
            stale += [f"{page}: {name}" for name, body in blocks.items() if not same(shown.get(name, ""), body)]
    if not args.write:
        print("stale: " + ", ".join(stale) if stale else "the pages hold what the examples give")
    return 1 if stale else 0


if __name__ == "__main__":
    sys.exit(main())
