"""Every closed-loop experiment's command line runs in its short mode and writes what it promises; bad input is a
usage error before anything runs."""

import argparse
import json
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

from experiments.common import is_primary
from experiments.registry import COMMANDS, EXPERIMENTS
from sim.params import TestbedParams

ROOT = Path(__file__).resolve().parents[1]


def run(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", *args], cwd=ROOT, capture_output=True, text=True, timeout=600)


@pytest.mark.parametrize("module,figure", [("experiments.step", "step.png"),
                                           ("experiments.sinusoid", "sinusoid.png")])
def test_torque_experiment_short_mode_prints_paper_beside_sim_and_writes_json_and_figure(tmp_path, module, figure):
    """--feedback both --duration: the table names the paper's value beside the simulated one, the JSON rows
    carry table/quantity/unit/paper/sim/ratio, the figure is written, progress goes to stderr."""
    out = tmp_path / "r.json"
    result = run(module, "--feedback", "both", "--duration", "0.3", "--seed", "3", "--json", str(out),
                 "--plot", str(tmp_path))
    assert result.returncode == 0, result.stderr
    assert "paper" in result.stdout and "ratio" in result.stdout
    assert "%" in result.stderr  # progress indication
    rows = json.loads(out.read_text())["rows"]
    primary = [r for r in rows if is_primary(r)]
    assert primary and all(set(r) == {"table", "quantity", "unit", "paper", "sim", "ratio"} for r in primary)
    assert {r["quantity"].split(" feedback")[0].rsplit(", ", 1)[1] for r in rows} == {"current", "sensor"}
    alternatives = rows[len(primary):]  # after the primary rows, one per test (4 steps / 3 waveforms) and feedback
    assert len(alternatives) == (8 if module == "experiments.step" else 6)
    assert all(r["reading"] == "alternative" and r["reason"] for r in alternatives)
    assert "Alternative readings" in result.stdout
    assert (tmp_path / figure).stat().st_size > 10_000


def test_step_single_feedback_runs_only_that_feedback(tmp_path):
    """--feedback current runs no sensor-feedback case."""
    out = tmp_path / "r.json"
    result = run("experiments.step", "--feedback", "current", "--duration", "0.2", "--json", str(out),
                 "--plot", str(tmp_path))
    assert result.returncode == 0, result.stderr
    assert {c["feedback"] for c in json.loads(out.read_text())["cases"]} == {"current"}


def test_admittance_short_mode_reports_both_pushes(tmp_path):
    """experiments.admittance --duration: slow and fast push in the JSON (with the common, here empty, "rows":
    the paper gives no admittance figures), figure written in a directory it says it created."""
    out, plots = tmp_path / "a.json", tmp_path / "new" / "figures"
    result = run("experiments.admittance", "--duration", "0.4", "--json", str(out), "--plot", str(plots))
    assert result.returncode == 0, result.stderr
    data = json.loads(out.read_text())
    assert [p["name"] for p in data["pushes"]] == ["slow", "fast"] and data["rows"] == []
    assert f"creating the --plot directory {plots}" in result.stdout
    assert (plots / "admittance.png").stat().st_size > 10_000


def test_no_plot_writes_no_figure_and_out_of_band_figures_are_marked(tmp_path):
    """--no-plot: no figure, none announced; the step table marks the figures outside a factor 1.5, as every
    paper table does (at 0.2 s the current-feedback disturbance figure is far from the paper's)."""
    result = subprocess.run([sys.executable, "-m", "experiments.step", "--feedback", "current", "--duration", "0.2",
                             "--no-plot"], cwd=tmp_path, env={**os.environ, "PYTHONPATH": str(ROOT)},
                            capture_output=True, text=True, timeout=600)
    assert result.returncode == 0, result.stderr
    assert "figure:" not in result.stdout and not any(tmp_path.iterdir())
    assert "<- outside a factor 1.5" in result.stdout


def test_paper_short_mode_writes_a_report_whose_tables_parse_and_says_it_is_short(tmp_path):
    """experiments.paper --duration: every markdown table row has its header's number of cells (a '|' inside a
    cell is escaped), the report and the JSON say the run is short and carry its seed."""
    out = tmp_path / "p.json"
    result = run("experiments.paper", "--duration", "0.05", "--seed", "2", "--json", str(out), "--plot", str(tmp_path))
    assert result.returncode == 0, result.stderr
    assert "SHORT RUN" in result.stdout
    data = json.loads(out.read_text())
    assert data["run"] == {"seed": 2, "params": None, "duration_s": 0.05, "full_length": False}
    assert {"III", "IV", "V", "VI", "VII"} <= {r["table"] for r in data["rows"]}
    report = (tmp_path / "paper_report.md").read_text()
    assert "short run (0.05 s per test)" in report and "seed 2" in report
    columns = None
    for line in report.splitlines():
        if not line.startswith("|"):
            columns = None
            continue
        cells = len(line.replace("\\|", "").split("|")) - 2
        columns = columns or cells
        assert cells == columns, line
    for figure in ("step.png", "sinusoid.png", "admittance.png"):
        assert (tmp_path / figure).stat().st_size > 10_000


def test_a_control_period_the_admittance_controller_cannot_discretise_is_a_usage_error(tmp_path):
    """A 0.1 s control period (within simulation.control_period_s's range) makes T_s·B_d/M_d = 2: the
    admittance CLI names simulation.control_period_s and its range for admittance control, before any run."""
    params = tmp_path / "slow.toml"
    params.write_text("[simulation]\ncontrol_period_s = 0.1\n[backlash]\nstop_time_constant_s = 0.001\n"
                      "[friction]\nload_friction_time_constant_s = 0.001\n")
    result = run("experiments.admittance", "--duration", "2", "--params", str(params))
    assert result.returncode == 2 and "Traceback" not in result.stderr
    assert "simulation.control_period_s = 0.1 s" in result.stderr and "(0, 0.1) s" in result.stderr


@pytest.mark.parametrize("args,message", [(("--duration", "0"), "--duration"),
                                          (("--duration", "1e-4"), "valid range [0.01, 120] s"),
                                          (("--duration", "1e7"), "valid range [0.01, 120] s"),
                                          (("--duration", "abc"), "'abc' is not a number of seconds"),
                                          (("--seed", "-1"), "valid seeds are integers >= 0"),
                                          (("--feedback", "torque"), "--feedback")])
def test_bad_flags_are_usage_errors_naming_the_flag(args, message):
    """A duration outside [10 ms, 120 s], a negative seed or an unknown feedback exits with status 2, names the flag
    and its valid range, before anything runs."""
    result = run("experiments.step", *args)
    assert result.returncode == 2 and message in result.stderr and "Traceback" not in result.stderr


def test_outputs_that_would_overwrite_an_input_or_cannot_be_written_are_refused_before_the_run(tmp_path):
    """--json naming the --params file, or a directory; --plot naming a file: usage errors, the input untouched."""
    params = tmp_path / "rig.toml"
    params.write_text("[friction]\nbreakaway_torque_nm = 0.14\n")
    a_file = tmp_path / "note.txt"
    a_file.write_text("keep")
    for args, message in [(("--params", str(params), "--json", str(params)), "is an input of this run"),
                          (("--json", str(tmp_path)), "is a directory"),
                          (("--plot", str(a_file)), "exists and is not a directory")]:
        result = run("experiments.step", "--duration", "0.05", *args)
        assert result.returncode == 2 and message in result.stderr, result.stderr
        assert "running" not in result.stderr  # refused before the simulation started
    assert params.read_text() == "[friction]\nbreakaway_torque_nm = 0.14\n" and a_file.read_text() == "keep"


@pytest.mark.parametrize("module,what", [("experiments.discrepancy", "replay"),
                                         ("experiments.plant", "breakaway ramp"),
                                         ("experiments.identify_defaults", "not re-run")])
def test_analysis_commands_offer_rerun_and_say_what_they_record(module, what):
    """experiments.discrepancy, .plant and .identify_defaults take --rerun PATH.rrd and --rerun-spawn, and their
    help says what the recording holds."""
    result = run(module, "--help")
    assert result.returncode == 0, result.stderr
    text = " ".join(result.stdout.split())
    assert "--rerun PATH.rrd" in text and "--rerun-spawn" in text and what in text


# ---------------------------------------------------------------- bad input never crashes a command line
def usage_error(main, argv, capsys) -> str:
    """Run ``main(argv)`` in this process, expecting a usage error (exit status 2); its stderr."""
    with pytest.raises(SystemExit) as exc:
        main(argv)
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert "Traceback" not in err
    return err


@pytest.mark.parametrize("flag,path,message", [
    ("--rerun", "/proc/x.rrd", "--rerun: cannot write under /proc"),
    ("--rerun", "{tmp}", "--rerun {tmp} is a directory"),
    ("--rerun", "{tmp}/run.txt", "a rerun recording is a .rrd file"),
    ("--json", "/proc/x.json", "--json: cannot write under /proc"),
    ("--plot", "/proc/figures", "--plot: cannot write under /proc"),
])
def test_an_output_that_cannot_be_written_is_refused_before_the_run(tmp_path, capsys, flag, path, message):
    """A --rerun, --json or --plot that could not be written at the end (a read-only place, a directory where a
    file is expected, a recording without .rrd) is a usage error naming the flag, before anything runs."""
    from experiments import step

    path, message = path.format(tmp=tmp_path), message.format(tmp=tmp_path)
    err = usage_error(step.main, ["--duration", "0.05", flag, path], capsys)
    assert message in err and "running" not in err


def test_two_outputs_naming_the_same_file_are_refused(tmp_path, capsys):
    """--json and --rerun naming one file would overwrite each other: a usage error."""
    from experiments import step

    same = str(tmp_path / "run.rrd")
    err = usage_error(step.main, ["--duration", "0.05", "--json", same, "--rerun", same], capsys)
    assert "--json and --rerun name the same file" in err


@pytest.mark.parametrize("flag,path,message", [
    ("--save-rig", "/proc/extended.toml", "--save-rig: cannot write under /proc"),
    ("--save-rig", "{tmp}/rig.toml", "--save-rig {tmp}/rig.toml is an input of this run"),
    ("--save-rig", "{tmp}/note.txt/extended.toml", "--save-rig: cannot write under {tmp}/note.txt"),
    ("--rerun", "/proc/d.rrd", "--rerun: cannot write under /proc"),
])
def test_discrepancy_refuses_an_output_it_could_not_write_before_the_analysis(tmp_path, capsys, flag, path, message):
    """experiments.discrepancy checks --save-rig (its directory must exist or be creatable, and be writable) and
    --rerun before reading the log."""
    from experiments import discrepancy

    (tmp_path / "note.txt").write_text("keep")
    (tmp_path / "rig.toml").write_text('model = "testbed"\nfixture = "locked"\n')
    path, message = path.format(tmp=tmp_path), message.format(tmp=tmp_path)
    err = usage_error(discrepancy.main, [str(tmp_path / "log.csv"), "--rig", str(tmp_path / "rig.toml"), flag, path],
                      capsys)
    assert message in err


def test_discrepancy_refuses_a_rig_file_that_is_not_text(tmp_path, capsys):
    """A binary --rig file is a usage error naming the file and saying it is not UTF-8 text."""
    from experiments import discrepancy

    rig = tmp_path / "bin.toml"
    rig.write_bytes(b"model = \"testbed\"\n\xff\xfe\x00\x81")
    err = usage_error(discrepancy.main, [str(tmp_path / "log.csv"), "--rig", str(rig)], capsys)
    assert f"rig file {rig} is not UTF-8 text" in err


@pytest.mark.parametrize("args,message", [
    (["--out", "/proc/demo"], "--out: cannot write under /proc"),
    (["--out", "{tmp}/note.txt"], "--out {tmp}/note.txt exists and is not a directory"),
    (["--duration", "0.1"], "--duration 0.1 s: the analysis needs a log of at least 0.82 s"),
])
def test_discrepancy_demo_refuses_what_it_could_not_write_or_the_analysis_could_not_use(tmp_path, capsys, args,
                                                                                         message):
    """An --out that cannot hold the two files, or a log too short for the analysis (four times its filter guards,
    plus 20 samples), is a usage error before anything is simulated."""
    from experiments import discrepancy_demo

    (tmp_path / "note.txt").write_text("keep")
    argv = [a.format(tmp=tmp_path) for a in args]
    err = usage_error(discrepancy_demo.main, argv + ([] if "--out" in argv else ["--out", str(tmp_path / "d")]),
                      capsys)
    assert message.format(tmp=tmp_path) in err and "simulating" not in err
    assert not (tmp_path / "d").exists()


def test_the_shortest_demo_log_is_one_the_analysis_runs_on_and_its_extended_rig_goes_to_a_new_directory(tmp_path):
    """A demo log of the shortest accepted duration passes the analysis's length rule, and --save-rig into a
    directory that does not exist yet creates it."""
    from experiments import discrepancy, discrepancy_demo

    shortest = discrepancy_demo.shortest_analysable_duration_s()
    discrepancy_demo.main(["--duration", f"{shortest:g}", "--out", str(tmp_path)])
    saved = tmp_path / "new" / "dir" / "extended.toml"
    discrepancy.main([str(tmp_path / "demo_log.csv"), "--rig", str(tmp_path / "demo_rig.toml"), "--workers", "1",
                      "--no-replay", "--no-plot", "--save-rig", str(saved)])
    assert saved.read_text().startswith("#")


EXPERIMENTS_WITHOUT_FIGURES = ("identify_defaults", "discrepancy_demo")


def test_the_registry_lists_every_command_and_the_readme_every_entry():
    """COMMANDS holds every experiments module that runs as a command; the README's command table names each,
    and no other."""
    commands = {path.stem for path in (ROOT / "experiments").glob("*.py")
                if 'if __name__ == "__main__":' in path.read_text()}
    assert commands == set(COMMANDS)
    assert set(EXPERIMENTS) <= set(COMMANDS)
    readme = (ROOT / "README.md").read_text()
    table = {m for m in re.findall(r"^\| `python -m experiments\.(\w+)", readme, re.M)}
    mentioned = set(re.findall(r"python -m experiments\.(\w+)", readme))
    assert table == set(COMMANDS) and mentioned <= set(COMMANDS)


@pytest.mark.parametrize("name", COMMANDS)
def test_every_experiment_takes_no_plot_and_those_with_figures_take_plot(name, capsys):
    """README: every experiment takes --no-plot; those that draw figures take --plot DIR."""
    import importlib

    module = importlib.import_module(f"experiments.{name}")
    with pytest.raises(SystemExit) as exc:
        module.main(["--help"])
    assert exc.value.code == 0
    text = capsys.readouterr().out
    assert "--no-plot" in text
    assert ("--plot DIR" in text) == (name not in EXPERIMENTS_WITHOUT_FIGURES)


def test_plant_card_with_no_plot_draws_nothing(tmp_path, monkeypatch, capsys):
    """experiments.plant --no-plot prints the card and writes no figure (nor out/)."""
    from experiments import plant

    monkeypatch.chdir(tmp_path)
    plant.main(["--no-plot"])
    out = capsys.readouterr().out
    assert "Derived and simulated" in out and "figure:" not in out
    assert not any(tmp_path.iterdir())


def test_a_gear_ratio_the_defaults_cannot_simulate_names_it_the_file_and_the_values_to_set(tmp_path, capsys):
    """A file setting only motor.gear_ratio = 36 lengthens the physics step past what the default solver time
    constants resolve: the error names the file, the field it set, both time constants and the value they need
    over both fixtures; the file amended as the message says is accepted."""
    from experiments import step
    from experiments.common import load_params_arg
    from models.gim8108_testbed.derived import physics_timestep

    path = tmp_path / "my_rig.toml"
    path.write_text("[motor]\ngear_ratio = 36\n")
    err = " ".join(usage_error(step.main, ["--duration", "0.05", "--params", str(path)], capsys).split())
    params = TestbedParams().replace(motor={"gear_ratio": 36.0})
    needed = 2.0 * max(physics_timestep(params, fixture)[0] for fixture in ("locked", "free"))
    assert f"{path}: motor.gear_ratio = 36 (default 8)" in err
    for field in ("backlash.stop_time_constant_s = 0.000125 s", "friction.load_friction_time_constant_s = 0.000125 s"):
        assert field in err
    suggested = float(err.split("stop_time_constant_s = ")[-1].split()[0])
    assert needed <= suggested < 1.01 * needed and f"valid range [{suggested:g}, 1] s" in err
    path.write_text(f"[motor]\ngear_ratio = 36\n[backlash]\nstop_time_constant_s = {suggested:g}\n"
                    f"[friction]\nload_friction_time_constant_s = {suggested:g}\n")
    args = argparse.Namespace(params=path, json=None, plot=None)
    assert load_params_arg(argparse.ArgumentParser(), args).motor.gear_ratio == 36.0
