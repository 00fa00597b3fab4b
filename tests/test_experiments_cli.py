"""Every closed-loop experiment's command line runs in its short mode and writes what it promises."""

import json
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
    """experiments.admittance --duration: slow and fast push in the JSON, figure written."""
    out = tmp_path / "a.json"
    result = run("experiments.admittance", "--duration", "0.4", "--json", str(out), "--plot", str(tmp_path))
    assert result.returncode == 0, result.stderr
    data = json.loads(out.read_text())
    assert [p["name"] for p in data["pushes"]] == ["slow", "fast"]
    assert (tmp_path / "admittance.png").stat().st_size > 10_000


@pytest.mark.parametrize("args,message", [(("--duration", "0"), "--duration"),
                                          (("--feedback", "torque"), "--feedback")])
def test_bad_flags_are_usage_errors_naming_the_flag(args, message):
    """A non-positive duration or an unknown feedback exits with status 2 and names the flag."""
    result = run("experiments.step", *args)
    assert result.returncode == 2 and message in result.stderr


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
