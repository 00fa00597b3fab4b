"""Every closed-loop experiment's command line runs in its short mode and writes what it promises."""

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

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
    assert rows and all(set(r) == {"table", "quantity", "unit", "paper", "sim", "ratio"} for r in rows)
    assert {r["quantity"].split(" feedback")[0].rsplit(", ", 1)[1] for r in rows} == {"current", "sensor"}
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


def test_a_parameter_set_the_model_cannot_be_built_from_is_a_usage_error_naming_the_field(tmp_path):
    """A gear ratio whose physics step outgrows the backlash stops' time constant names that field and its range."""
    params = tmp_path / "rig.toml"
    params.write_text("[motor]\ngear_ratio = 36\n")
    result = run("experiments.step", "--duration", "0.05", "--params", str(params))
    assert result.returncode == 2 and "Traceback" not in result.stderr
    assert "backlash.stop_time_constant_s = 0.000125 s is below two physics steps; valid range" in result.stderr


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
