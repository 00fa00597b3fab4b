"""A run's outputs (--json, --plot and the files it writes, --rerun, --save-rig) are checked against each other and
against the inputs before anything runs: a clash is one usage error naming both flags, and nothing is written."""

import argparse
import importlib
import re
import subprocess
import sys
from pathlib import Path

import pytest

from experiments.common import add_experiment_args, check_output_paths
from experiments.registry import COMMANDS, EXPERIMENTS

ROOT = Path(__file__).resolve().parents[1]
COMMANDS_WITHOUT_FIGURES = ("identify_defaults", "discrepancy_demo")


def refused(module: str, argv: list[str], capsys) -> str:
    """Run ``python -m experiments.<module>`` in this process, expecting a usage error (exit status 2); its last
    stderr line, which must name the error and come before the run started."""
    main = importlib.import_module(f"experiments.{module}").main
    with pytest.raises(SystemExit) as exc:
        main(argv)
    err = capsys.readouterr().err
    assert exc.value.code == 2 and "Traceback" not in err
    assert "running" not in err and "simulating" not in err  # refused before the run
    return err.strip().splitlines()[-1]


def discrepancy_argv(tmp_path: Path, *flags: str) -> list[str]:
    """experiments.discrepancy on log.csv with rig.toml (neither read: the outputs are checked first)."""
    return [str(tmp_path / "log.csv"), "--rig", str(tmp_path / "rig.toml"), *flags]


# ---------------------------------------------------------------- each pair of outputs
@pytest.mark.parametrize("flags,message", [
    (["--json", "{tmp}/same.json", "--plot", "{tmp}/same.json"],
     "--json {tmp}/same.json and --plot {tmp}/same.json name the same path, --json a file and --plot a folder"),
    (["--json", "{tmp}/figs/step.png", "--plot", "{tmp}/figs"],
     "--json {tmp}/figs/step.png is the file --plot {tmp}/figs writes step.png to"),
    (["--json", "{tmp}/r.json", "--plot", "{tmp}/r.json/figs"],
     "--plot {tmp}/r.json/figs is inside --json {tmp}/r.json, which is a file"),
])
def test_json_and_plot(tmp_path, capsys, flags, message):
    """--json and --plot at one path, --json where --plot writes its figure, --plot inside the --json file."""
    err = refused("step", ["--duration", "0.05", *[f.format(tmp=tmp_path) for f in flags]], capsys)
    assert message.format(tmp=tmp_path) in err
    assert not any(tmp_path.iterdir())


@pytest.mark.parametrize("flags,message", [
    (["--json", "{tmp}/run.rrd", "--rerun", "{tmp}/run.rrd"], "--json and --rerun name the same file, {tmp}/run.rrd"),
    (["--json", "{tmp}/a", "--rerun", "{tmp}/a/run.rrd"], "--rerun {tmp}/a/run.rrd is inside --json {tmp}/a"),
])
def test_json_and_rerun(tmp_path, capsys, flags, message):
    err = refused("step", ["--duration", "0.05", *[f.format(tmp=tmp_path) for f in flags]], capsys)
    assert message.format(tmp=tmp_path) in err


@pytest.mark.parametrize("flags,message", [
    (["--rerun", "{tmp}/r.rrd", "--plot", "{tmp}/r.rrd"],
     "--rerun {tmp}/r.rrd and --plot {tmp}/r.rrd name the same path, --rerun a file and --plot a folder"),
    (["--rerun", "{tmp}/r.rrd", "--plot", "{tmp}/r.rrd/figs"], "--plot {tmp}/r.rrd/figs is inside --rerun {tmp}/r.rrd"),
])
def test_plot_and_rerun(tmp_path, capsys, flags, message):
    err = refused("step", ["--duration", "0.05", *[f.format(tmp=tmp_path) for f in flags]], capsys)
    assert message.format(tmp=tmp_path) in err


@pytest.mark.parametrize("flags,message", [
    (["--json", "{tmp}/out.toml", "--save-rig", "{tmp}/out.toml"], "--json and --save-rig name the same file"),
    (["--plot", "{tmp}/d", "--save-rig", "{tmp}/d/discrepancy_residuals.png"],
     "--save-rig {tmp}/d/discrepancy_residuals.png is the file --plot {tmp}/d writes discrepancy_residuals.png to"),
    (["--plot", "{tmp}/d", "--save-rig", "{tmp}/d/discrepancy_replay.png", "--no-replay"],
     "is the file --plot {tmp}/d writes discrepancy_replay.png to"),
    (["--rerun", "{tmp}/x.rrd", "--save-rig", "{tmp}/x.rrd"], "--rerun and --save-rig name the same file"),
])
def test_save_rig_and_the_other_outputs(tmp_path, capsys, flags, message):
    """experiments.discrepancy's --save-rig against --json, a figure of --plot (the replay's too: it is written
    whenever the replay runs) and --rerun, before the rig or the log is read."""
    err = refused("discrepancy", discrepancy_argv(tmp_path, *[f.format(tmp=tmp_path) for f in flags]), capsys)
    assert message.format(tmp=tmp_path) in err
    assert not any(tmp_path.iterdir())


# ---------------------------------------------------------------- an output that is an input
def test_an_output_that_is_the_params_file_is_refused_and_the_file_kept(tmp_path, capsys):
    """--json naming the --params file, and --plot whose figure would be the --params file."""
    params = tmp_path / "figs" / "step.png"
    params.parent.mkdir()
    params.write_text("[friction]\nbreakaway_torque_nm = 0.14\n")
    err = refused("step", ["--duration", "0.05", "--params", str(params), "--json", str(params)], capsys)
    assert f"--json {params} is an input of this run (--params)" in err
    err = refused("step", ["--duration", "0.05", "--params", str(params), "--plot", str(params.parent)], capsys)
    assert f"--plot {params.parent} would write step.png over --params {params}, an input of this run" in err
    assert params.read_text() == "[friction]\nbreakaway_torque_nm = 0.14\n"


@pytest.mark.parametrize("flags,message", [
    (["--json", "{tmp}/log.csv"], "--json {tmp}/log.csv is an input of this run (LOG)"),
    (["--rerun", "{tmp}/v.rrd", "--validate", "{tmp}/v.rrd"],
     "--rerun {tmp}/v.rrd is an input of this run (--validate)"),
    (["--save-rig", "{tmp}/rig.toml"], "--save-rig {tmp}/rig.toml is an input of this run (--rig)"),
])
def test_a_discrepancy_output_that_is_an_input_is_refused(tmp_path, capsys, flags, message):
    """The measured log, a validation log and the rig file are inputs no output may name."""
    err = refused("discrepancy", discrepancy_argv(tmp_path, *[f.format(tmp=tmp_path) for f in flags]), capsys)
    assert message.format(tmp=tmp_path) in err


# ---------------------------------------------------------------- every command, its declared files
def test_paper_checks_every_experiments_figures_and_its_report(tmp_path, capsys):
    """experiments.paper's --plot writes each experiment's figures and paper_report.md: each is checked."""
    for name in ("calibration_channels.png", "admittance.png", "paper_report.md"):
        err = refused("paper", ["--duration", "0.05", "--json", str(tmp_path / name), "--plot", str(tmp_path)],
                      capsys)
        assert f"is the file --plot {tmp_path} writes {name} to" in err


def test_qp_gain_checks_its_outputs_before_the_draws(tmp_path, capsys):
    err = refused("qp_gain", ["--draws", "1", "--json", str(tmp_path / "qp_gain.png"), "--plot", str(tmp_path)],
                  capsys)
    assert "--plot" in err and "--json" in err and "draws in" not in err


def test_outputs_that_do_not_clash_are_accepted():
    """--json, --rerun and --plot in one folder, each with its own file name, pass the check."""
    parser = argparse.ArgumentParser()
    add_experiment_args(parser, figures=("step.png",))
    args = parser.parse_args(["--json", "figs/result.json", "--rerun", "figs/run.rrd", "--plot", "figs"])
    check_output_paths(parser, args, inputs={"--params": Path("figs/params.toml")})


@pytest.mark.parametrize("name", COMMANDS)
def test_every_command_with_plot_names_the_files_it_writes(name, capsys):
    """Each command's --plot help names the files the check knows it writes: its module's PLOT_FILES (for
    experiments.paper, every paper experiment's and its report)."""
    module = importlib.import_module(f"experiments.{name}")
    with pytest.raises(SystemExit):
        module.main(["--help"])
    text = " ".join(capsys.readouterr().out.split())
    if name in COMMANDS_WITHOUT_FIGURES:
        assert "--plot DIR" not in text
        return
    assert module.PLOT_FILES and f"--plot DIR write {', '.join(module.PLOT_FILES)} in DIR" in text
    if name == "paper":
        assert all(set(e.plot_files) <= set(module.PLOT_FILES) for e in EXPERIMENTS.values())


def test_every_figure_is_saved_under_a_declared_name():
    """No save_figure call names its file by a literal: every name comes from a PLOT_FILES tuple, so the check
    and the figures cannot drift apart."""
    sources = [*ROOT.glob("experiments/*.py"), *ROOT.glob("sim/**/*.py")]
    literal = re.compile(r"save_figure\([^)]*[\"'][^\"']+\.(png|pdf|svg)[\"']")
    assert not [path.name for path in sources if literal.search(path.read_text())]


@pytest.mark.parametrize(("argv", "named"), [
    (["experiments.discrepancy", "{tmp}/missing.csv", "--rig", "{tmp}/rig.toml"], "missing.csv"),
    (["experiments.discrepancy", "{tmp}", "--rig", "{tmp}/rig.toml"], "is a directory"),
    (["experiments.discrepancy", "{tmp}/short.csv", "--rig", "{tmp}/rig.toml"], "short.csv"),
    (["experiments.discrepancy", "{tmp}/short.csv", "--rig", "{tmp}/typo.toml"], "typo.toml"),
    (["experiments.step", "--params", "{tmp}/typo_params.toml", "--duration", "0.05", "--no-plot"],
     "typo_params.toml"),
])
def test_a_file_or_data_error_is_one_line_naming_the_file_once_without_the_usage(argv, named, tmp_path):
    """Only a mistyped command line gets the usage text; an input's error is the command's one line."""
    (tmp_path / "rig.toml").write_text('model = "rigid-joint"\njoint = "hinge"\ninertia_kgm2 = 1\neffort_gain = 1\n')
    (tmp_path / "typo.toml").write_text('model = "rigid-joint"\njiont = "hinge"\n')
    (tmp_path / "typo_params.toml").write_text("[friction]\nbreakaway_torqe_nm = 0.1\n")
    (tmp_path / "short.csv").write_text("time,tau_cmd,q\n0,1,0\n")
    args = [a.format(tmp=tmp_path) for a in argv]
    done = subprocess.run([sys.executable, "-m", *args], capture_output=True, text=True, timeout=120, cwd=ROOT)
    lines = done.stderr.strip().splitlines()
    assert done.returncode == 2 and len(lines) == 1, done.stderr
    assert lines[0].startswith(f"python -m {args[0]}: error: ") and "usage" not in done.stderr
    assert lines[0].count(named) == 1, lines[0]


def test_identify_defaults_refuses_a_params_file_its_out_folder_would_overwrite(tmp_path):
    from experiments import identify_defaults

    params = tmp_path / "best_params.toml"
    params.write_text("[friction]\nbreakaway_torque_nm = 0.2\n")
    with pytest.raises(SystemExit) as exc:
        identify_defaults.main(["--params", str(params), "--out", str(tmp_path), "--resume", "--duration", "0.05"])
    assert exc.value.code == 2 and params.read_text() == "[friction]\nbreakaway_torque_nm = 0.2\n"
