"""--rerun-spawn opens a rerun viewer or says in one line why it cannot, and never waits forever: refused before
the run where the machine cannot show one (no display, no viewer executable, rerun disabled by the environment);
a viewer that fails as it starts is said in one line and the run's other outputs are still written."""

import contextlib
import importlib
import io
import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from experiments.common import record_log
from experiments.registry import COMMANDS
from sim import recording
from sim.recording import ViewerError, record_logs, viewer_executable, viewer_listening

ROOT = Path(__file__).resolve().parents[1]
TIMEOUT_S = 60  # [s] a command that waits on a viewer longer than this has hung
UNSET = ("DISPLAY", "WAYLAND_DISPLAY", "WAYLAND_SOCKET", "RERUN", "RERUN_CLI_PATH")
REQUIRED_ARGS = {"discrepancy": ["log.csv", "--rig", "rig.toml"]}  # never read: the flags are checked first

pytestmark = pytest.mark.skipif(viewer_listening(), reason="a rerun viewer already listens on the default port")


def headless_env(**extra: str) -> dict[str, str]:
    """This environment without a display or rerun settings, plus ``extra``."""
    return {**{k: v for k, v in os.environ.items() if k not in UNSET}, **extra}


def commands_with_viewer() -> list[str]:
    """Every command whose help offers --rerun-spawn."""
    found = []
    for name in COMMANDS:
        text = io.StringIO()
        with contextlib.redirect_stdout(text), pytest.raises(SystemExit):
            importlib.import_module(f"experiments.{name}").main(["--help"])
        if "--rerun-spawn" in text.getvalue():
            found.append(name)
    return found


def run(module: str, *args: str, env: dict[str, str], cwd: Path) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", f"experiments.{module}", *args], cwd=cwd, env=env,
                          capture_output=True, text=True, timeout=TIMEOUT_S)


def fake_viewer(tmp_path: Path, body: str) -> Path:
    """An executable standing in for the viewer: writes its pid to ``viewer.pid``, then runs ``body``."""
    script = tmp_path / "viewer.sh"
    script.write_text(f"#!/bin/sh\necho $$ > {tmp_path / 'viewer.pid'}\n{body}\n")
    script.chmod(0o755)
    return script


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def small_log():
    t = np.arange(1, 41) * 0.1
    return record_log(t, np.full((40, 8), 1.65), tau_sensor_nm=np.zeros(40))


# ---------------------------------------------------------------- refused before the run
def test_rerun_spawn_without_a_display_ends_at_once_in_one_line(tmp_path):
    """Headless (no DISPLAY), `experiments.step --rerun-spawn` exits with status 2 before anything runs, with one
    line saying there is no display and what to do instead; no traceback, no usage text, nothing written."""
    result = run("step", "--duration", "0.05", "--feedback", "sensor", "--no-plot", "--rerun-spawn",
                 env=headless_env(), cwd=tmp_path)
    lines = result.stderr.strip().splitlines()
    assert result.returncode == 2 and len(lines) == 1, result.stderr
    assert lines[0].startswith("python -m experiments.step: error: --rerun-spawn: no display to open the rerun "
                               "viewer on (DISPLAY and WAYLAND_DISPLAY are unset)")
    assert "--rerun PATH.rrd" in lines[0] and "Traceback" not in result.stderr and not result.stdout
    assert not any(tmp_path.iterdir())


@pytest.mark.parametrize("name", commands_with_viewer())
def test_every_commands_viewer_flag_is_checked_before_the_run(name, tmp_path, monkeypatch, capsys):
    """Every command offering --rerun-spawn checks it before it runs: headless, one line and exit status 2."""
    for variable in UNSET:
        monkeypatch.delenv(variable, raising=False)
    monkeypatch.chdir(tmp_path)
    with pytest.raises(SystemExit) as exc:
        importlib.import_module(f"experiments.{name}").main([*REQUIRED_ARGS.get(name, []), "--rerun-spawn"])
    err = capsys.readouterr().err.strip().splitlines()
    assert exc.value.code == 2 and len(err) == 1 and "--rerun-spawn: no display" in err[0]
    assert not any(tmp_path.iterdir())


@pytest.mark.parametrize("flag", ["--rerun-spawn", "--rerun"])
def test_rerun_disabled_by_the_environment_is_said_in_one_line(flag, tmp_path, monkeypatch, capsys):
    """RERUN=off makes the rerun SDK record nothing: --rerun-spawn and --rerun are refused before the run."""
    from experiments import step

    monkeypatch.setenv("RERUN", "off")
    argv = ["--duration", "0.05", flag] + ([str(tmp_path / "r.rrd")] if flag == "--rerun" else [])
    with pytest.raises(SystemExit) as exc:
        step.main(argv)
    err = capsys.readouterr().err.strip().splitlines()
    assert exc.value.code == 2 and len(err) == 1
    assert f"{flag}: rerun is disabled by the environment (RERUN=off)" in err[0] and "unset RERUN" in err[0]


def test_no_viewer_executable_is_said_in_one_line(monkeypatch, capsys):
    from experiments import step

    monkeypatch.setenv("DISPLAY", ":0")
    monkeypatch.setattr(recording, "viewer_executable", lambda: None)
    with pytest.raises(SystemExit) as exc:
        step.main(["--duration", "0.05", "--rerun-spawn"])
    err = capsys.readouterr().err.strip().splitlines()
    assert exc.value.code == 2 and len(err) == 1 and "--rerun-spawn: no rerun viewer executable" in err[0]


# ---------------------------------------------------------------- a viewer that fails after the run
def test_a_viewer_that_exits_as_it_starts_is_said_in_one_line_and_the_outputs_are_written(tmp_path):
    """A display is set but the viewer exits at once (an X server that is gone): the run finishes, one stderr
    line says why (the viewer's own error line), the JSON and the --rerun file are written, exit status 0."""
    viewer = fake_viewer(tmp_path, 'echo "Error: Failed to open connection to X server" >&2\nexit 1')
    result = run("step", "--duration", "0.05", "--feedback", "sensor", "--no-plot", "--rerun-spawn",
                 "--rerun", "r.rrd", "--json", "r.json", env=headless_env(DISPLAY=":99", RERUN_CLI_PATH=str(viewer)),
                 cwd=tmp_path)
    said = [line for line in result.stderr.splitlines() if "viewer" in line]
    assert result.returncode == 0 and "Traceback" not in result.stderr, result.stderr
    assert len(said) == 1 and said[0].startswith("--rerun-spawn: no rerun viewer: the rerun viewer exited as it "
                                                 "started (exit status 1): Error: Failed to open connection")
    assert (tmp_path / "r.json").stat().st_size > 0 and (tmp_path / "r.rrd").stat().st_size > 1000


def test_a_viewer_that_never_listens_is_stopped_within_the_bound(tmp_path, monkeypatch):
    """A viewer that neither listens nor exits is waited on VIEWER_START_TIMEOUT_S, then stopped."""
    monkeypatch.setenv("DISPLAY", ":99")
    monkeypatch.setenv("RERUN_CLI_PATH", str(fake_viewer(tmp_path, "exec sleep 60")))
    monkeypatch.setattr(recording, "VIEWER_START_TIMEOUT_S", 1.0)
    start = time.monotonic()
    with pytest.raises(ViewerError, match="did not listen on port .* within 1 s; it was stopped"):
        record_logs({"chamber": small_log()}, spawn=True, port=free_port())
    assert time.monotonic() - start < 5
    assert not Path(f"/proc/{(tmp_path / 'viewer.pid').read_text().strip()}").exists()  # stopped and reaped


@pytest.mark.skipif(viewer_executable() is None, reason="no rerun executable")
def test_a_listening_viewer_takes_the_recording(tmp_path, monkeypatch):
    """A started viewer that listens (rerun's own gRPC server standing in for the window) takes every run."""
    monkeypatch.setenv("DISPLAY", ":99")
    monkeypatch.setenv("RERUN_CLI_PATH", str(fake_viewer(tmp_path, f'exec {viewer_executable()} --serve-grpc "$@"')))
    port = free_port()
    try:
        summary = record_logs({"chamber": small_log()}, path=tmp_path / "r.rrd", spawn=True, port=port)
    finally:
        pid_file = tmp_path / "viewer.pid"
        if pid_file.exists():
            os.kill(int(pid_file.read_text()), signal.SIGTERM)
    assert summary.viewer == f"rerun+http://127.0.0.1:{port}/proxy" and summary.runs == {"chamber": 40}
    assert (tmp_path / "r.rrd").stat().st_size > 1000


def test_a_listener_that_does_not_answer_is_not_taken_for_a_viewer():
    """A program that accepts connections on the port but never answers (a stopped viewer, another program)
    would make the rerun SDK wait forever as it disconnects: it is not taken for a viewer."""
    with socket.socket() as silent:
        silent.bind(("127.0.0.1", 0))
        silent.listen()
        assert not viewer_listening(silent.getsockname()[1])
