"""Record finished runs (:class:`sim.runlog.RunLog`) to rerun: the testbed in 3D and the time series, with a
blueprint that lays them out.

Every run is recorded under ``/<run>/`` (a slug of its name; see :func:`entity_name`):

=================================  ===========================================================  ==========
entity                             what                                                         samples
=================================  ===========================================================  ==========
``/<run>/testbed/motor``           GIM8108 housing (static cylinder from the MJCF)              static
``/<run>/testbed/hub``             gear output flange + sensor hub, turns with q_motor + backlash  decimated
``/<run>/testbed/flexure``         flexure ring + lever + lever tip, turns with the lever angle q  decimated
``/<run>/testbed/loadcell``        load cell at the lever tip (locked fixture only)             static
``/<run>/testbed/torque``          arrow at the lever tip: load-cell force (10 mm per N·m of     decimated
                                   torque), red when pushing positive, blue negative
``/<run>/torque/<signal>``         reference, sensor, feedback, loadcell, command, flexure [N·m]  every tick
                                   (rig records: mini85, applied, sensor)
``/<run>/voltages/v1`` ... ``v8``  photo-reflector channel voltages [V] (sensor-feedback runs)  every tick
``/<run>/temperature/board``       TMP117 board temperature [°C]                                every tick
``/<run>/<group>/<name>``          extra series given with the run (``series``: e.g. a replay   their own
                                   of measured against simulated signals), each with its unit   time column
=================================  ===========================================================  ==========

on the timeline ``time`` (the run's simulated time). The geometry (sizes, positions, colours) is read from the
compiled :class:`mujoco.MjModel` of the run's parameters and fixture; the 3D pose is sent at
``pose_rate_hz`` (default 50 Hz, every 20th tick of a 1 kHz run) to keep recording cheap, the time series
at every tick, all in bulk with ``rerun.send_columns``. Angles are drawn to scale unless
``angle_exaggeration`` > 1: in the locked fixture the lever turns micro-radians, so the arrow carries the
load. A run's extra series are :class:`sim.runlog.RunLog` s too (one per group, any columns with units,
on their own time column); the blueprint gives each group a time-series view in that run's tab, and leaves
out the views a run has no data for (no 3D view for a record without mechanics).

A spawned viewer (``spawn=True``) is one already listening on the port, else the one shipped with the installed
rerun-sdk (:func:`viewer_executable`), started detached with its output kept off the terminal. Every wait on it is
bounded; a viewer that cannot open (no display, no executable, one that exits as it starts or does not take the
recording) raises :class:`ViewerError`, and rerun disabled by the environment (``RERUN=off``) raises
:class:`RecordingError`, each with the reason in one line.
"""

from __future__ import annotations

import importlib.util
import math
import os
import re
import shutil
import socket
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

import mujoco
import numpy as np
import rerun as rr
import rerun.blueprint as rrb

from models.gim8108_testbed.build import build_model
from sim.params import TestbedParams
from sim.runlog import VOLTAGE_COLUMNS, RunLog

DEFAULT_POSE_RATE_HZ = 50.0  # [Hz] rate of the 3D pose and arrow samples
ARROW_M_PER_NM = 0.01  # [m] arrow length per N·m of load-cell torque
ARROW_HEIGHT_M = 0.01  # [m] the arrow's base above the lever plane (drawn clear of the lever)
TIMELINE = "time"
# body of the MJCF -> entity under /<run>/testbed
BODY_ENTITIES = {"stator": "motor", "output": "hub", "lever": "flexure", "loadcell": "loadcell"}
TORQUE_SIGNALS = (("reference", "tau_ref"), ("sensor", "tau_sensor"), ("feedback", "tau_feedback"),
                  ("command", "tau_cmd"), ("flexure", "tau_flexure"),
                  ("mini85", "tau_mini85"), ("applied", "tau_applied"))  # the calibration rig's records
FIXED_VIEWS = (  # group, view title, row share, log columns whose presence gives the view something to show
    ("torque", "torque [N·m]", 3, tuple(c for _, c in TORQUE_SIGNALS) + ("force_loadcell",)),
    ("voltages", "channel voltages [V]", 2, VOLTAGE_COLUMNS),
    ("temperature", "temperature [°C]", 1, ("temperature",)))
FIXED_GROUPS = ("testbed",) + tuple(group for group, *_ in FIXED_VIEWS)  # entity groups of the fixed layout

VIEWER_PORT = 9876  # the viewer's gRPC port, rerun's default (a viewer already listening there is reused)
VIEWER_START_TIMEOUT_S = 10.0  # [s] longest wait for a started viewer to listen on its port
VIEWER_SETTLE_S = 0.5  # [s] a viewer that cannot open its window exits within this of starting to listen
VIEWER_FLUSH_TIMEOUT_S = 120.0  # [s] longest wait for the viewer to take a recording (~100 MB: a few seconds)
DISPLAY_VARIABLES = ("DISPLAY", "WAYLAND_DISPLAY", "WAYLAND_SOCKET")  # one is needed for a window on Linux
RERUN_OFF = ("0", "false", "off")  # values of the RERUN variable that disable the rerun SDK (any case)
HTTP2_PREFACE = b"PRI * HTTP/2.0\r\n\r\nSM\r\n\r\n"  # a client's first bytes (RFC 9113, 3.4)
HTTP2_SETTINGS = b"\x04"  # the type of a server's first frame, its SETTINGS (RFC 9113, 6.5)


class RecordingError(RuntimeError):
    """Nothing can be recorded where asked; the message says why, in one line."""


class ViewerError(RecordingError):
    """No rerun viewer could be opened or fed; the message says why, in one line."""


@dataclass(frozen=True)
class RecordingSummary:
    """What was recorded.

    Attributes
    ----------
    path : Path or None
        The .rrd file written (None when only spawned).
    runs : dict of str to int
        Entity name of each run -> its number of time-series samples.
    pose_samples : dict of str to int
        Entity name of each run -> number of 3D pose samples.
    series : dict of str to dict of str to int
        Entity name of each run with extra series -> group entity name -> its number of samples.
    viewer : str or None
        The address of the viewer the runs were sent to (None when not spawned).
    """

    path: Path | None
    runs: dict[str, int]
    pose_samples: dict[str, int]
    series: dict[str, dict[str, int]] = field(default_factory=dict)
    viewer: str | None = None


def entity_name(name: str) -> str:
    """A run name as one entity-path part: runs of characters other than letters, digits, '.', '-' and '_'
    become '_' ('step 0.05 N·m, sensor' -> 'step_0.05_N_m_sensor')."""
    slug = re.sub(r"[^A-Za-z0-9._-]+", "_", name).strip("_")
    return slug or "run"


def _z_quaternions(angles_rad: np.ndarray) -> np.ndarray:
    """Quaternions (x, y, z, w) of rotations by the angles about the joint axis z."""
    half = 0.5 * np.asarray(angles_rad, dtype=float)
    return np.column_stack([np.zeros_like(half), np.zeros_like(half), np.sin(half), np.cos(half)])


def _log_geometry(rec: rr.RecordingStream, root: str, params: TestbedParams, fixture: str) -> None:
    """The visual geoms of each body, static, at the pose of zero joint angles (the body frames)."""
    model = build_model(params, fixture)
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    for body, entity in BODY_ENTITIES.items():
        body_id = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, body)
        if body_id < 0:
            continue  # no load cell in the free fixture
        cylinders, boxes = [], []
        for g in np.flatnonzero(model.geom_bodyid == body_id):
            center, size = data.geom_xpos[g].copy(), model.geom_size[g]
            colour = (np.clip(model.geom_rgba[g], 0.0, 1.0) * 255).astype(np.uint8)
            if model.geom_type[g] == mujoco.mjtGeom.mjGEOM_CYLINDER:
                cylinders.append((center, size[0], 2.0 * size[1], colour))
            elif model.geom_type[g] == mujoco.mjtGeom.mjGEOM_BOX:
                boxes.append((center, size[:3].copy(), colour))
        path = f"{root}/testbed/{entity}"
        if cylinders:
            centers, radii, lengths, colours = zip(*cylinders, strict=True)
            rec.log(f"{path}/cylinders", rr.Cylinders3D(centers=centers, radii=radii, lengths=lengths, colors=colours),
                    static=True)
        if boxes:
            rec.log(f"{path}/boxes", rr.Boxes3D(centers=[b[0] for b in boxes], half_sizes=[b[1] for b in boxes],
                                                colors=[b[2] for b in boxes]), static=True)


def _send_scalar(rec: rr.RecordingStream, path: str, times: rr.TimeColumn, values: np.ndarray, name: str) -> None:
    rec.log(path, rr.SeriesLines(names=name), static=True)
    rec.send_columns(path, indexes=[times], columns=rr.Scalars.columns(scalars=np.asarray(values, dtype=float)))


def record_run(rec: rr.RecordingStream, name: str, log: RunLog, params: TestbedParams | None = None, *,
               pose_rate_hz: float = DEFAULT_POSE_RATE_HZ, angle_exaggeration: float = 1.0) -> tuple[int, int]:
    """Send one run log to ``rec`` under ``/<entity_name(name)>``; returns (time-series samples, pose samples).

    Parameters
    ----------
    rec : rerun.RecordingStream
    name : str
        The run's name (shown in the blueprint).
    log : RunLog
        A run with ``time`` and the plant's signals (``q``, ``q_motor``, ``backlash_angle``,
        ``force_loadcell``, ...); columns it lacks are not recorded.
    params : TestbedParams, optional
        The run's parameters (geometry); defaults if None.
    pose_rate_hz : float
        Rate of the 3D pose and arrow samples [Hz] (> 0).
    angle_exaggeration : float
        Factor on the drawn angles (>= 1; 1 = to scale).
    """
    if not (math.isfinite(pose_rate_hz) and pose_rate_hz > 0):
        raise ValueError(f"pose_rate_hz = {pose_rate_hz!r}: valid range (0, inf) Hz")
    if not (math.isfinite(angle_exaggeration) and angle_exaggeration >= 1.0):
        raise ValueError(f"angle_exaggeration = {angle_exaggeration!r}: valid range [1, inf)")
    params = params or TestbedParams()
    root = "/" + entity_name(name)
    fixture = log.meta.get("fixture", "locked")
    cols = log.columns
    t = np.asarray(cols["time"], dtype=float)
    n = len(t)
    times = rr.TimeColumn(TIMELINE, duration=t)
    lever_m = log.meta.get("lever_length_m", params.lever.length_m)
    # the load cell's torque [N·m]: only the locked fixture has one
    loadcell_nm = (np.asarray(cols["force_loadcell"]) * lever_m
                   if "force_loadcell" in cols and fixture == "locked" else None)
    for label, column in TORQUE_SIGNALS:
        if column in cols:
            _send_scalar(rec, f"{root}/torque/{label}", times, cols[column], f"{label} [N·m]")
    if loadcell_nm is not None:
        _send_scalar(rec, f"{root}/torque/loadcell", times, loadcell_nm, "load cell [N·m]")
    for name in VOLTAGE_COLUMNS:
        if name in cols:
            _send_scalar(rec, f"{root}/voltages/{name}", times, cols[name], f"{name} [V]")
    if "temperature" in cols:
        _send_scalar(rec, f"{root}/temperature/board", times, cols["temperature"], "board (TMP117) [°C]")

    if not _has_mechanics(log):
        return n, 0  # a record without mechanics (calibration rig, chamber): no 3D testbed
    _log_geometry(rec, root, params, fixture)
    dt = float(np.median(np.diff(t))) if n > 1 else params.simulation.control_period_s
    every = max(1, round(1.0 / (pose_rate_hz * dt)))
    idx = np.arange(0, n, every)
    pose_times = rr.TimeColumn(TIMELINE, duration=t[idx])
    lever = angle_exaggeration * np.asarray(cols["q"])[idx]
    hub = np.asarray(cols["q_motor"])[idx] if "q_motor" in cols else np.zeros(len(idx))
    if "backlash_angle" in cols:
        hub = hub + np.asarray(cols["backlash_angle"])[idx]
    for entity, angle in (("hub", angle_exaggeration * hub), ("flexure", lever)):
        rec.send_columns(f"{root}/testbed/{entity}", indexes=[pose_times],
                         columns=rr.Transform3D.columns(quaternion=_z_quaternions(angle)))
    if loadcell_nm is not None:
        tau = loadcell_nm[idx]
        tip = np.column_stack([lever_m * np.cos(lever), lever_m * np.sin(lever), np.full(len(idx), ARROW_HEIGHT_M)])
        normal = np.column_stack([-np.sin(lever), np.cos(lever), np.zeros(len(idx))])
        colours = np.where((tau >= 0)[:, None], [[220, 50, 40, 255]], [[40, 90, 220, 255]]).astype(np.uint8)
        rec.send_columns(f"{root}/testbed/torque", indexes=[pose_times],
                         columns=rr.Arrows3D.columns(origins=tip, vectors=normal * (ARROW_M_PER_NM * tau)[:, None],
                                                     colors=colours))
    return n, len(idx)


def record_series(rec: rr.RecordingStream, name: str, group: str, log: RunLog) -> int:
    """Send a run's extra series to ``rec``: every column of ``log`` but ``time`` under
    ``/<entity_name(name)>/<entity_name(group)>/<entity_name(column)>``, labelled with its unit; returns the
    number of samples.

    Parameters
    ----------
    rec : rerun.RecordingStream
    name : str
        The run the series belong to.
    group : str
        The group (one time-series view); not one of the fixed layout's ``FIXED_GROUPS``.
    log : RunLog
        The series on their own ``time`` [s] column (any names and units).
    """
    _check_group(name, group)
    path = f"/{entity_name(name)}/{entity_name(group)}"
    times = rr.TimeColumn(TIMELINE, duration=np.asarray(log["time"], dtype=float))
    for column, values in log.columns.items():
        if column != "time":
            _send_scalar(rec, f"{path}/{entity_name(column)}", times, values, f"{column} [{log.units[column]}]")
    return len(log)


def _check_group(name: str, group: str) -> None:
    if entity_name(group) in FIXED_GROUPS:
        raise ValueError(f"series group {group!r} of run {name!r} clashes with the fixed layout's "
                         f"{', '.join(FIXED_GROUPS)}; choose another group name")


def _group_title(group: str, log: RunLog) -> str:
    """'replay [N·m]' when every series of the group has one unit, else the group's name."""
    units = {u for c, u in log.units.items() if c != "time" and c in log.columns}
    return f"{group} [{units.pop()}]" if len(units) == 1 else group


def _has_mechanics(log: RunLog) -> bool:
    """Whether a run drives the 3D testbed: a plant fixture and the lever angle ``q``."""
    return log.meta.get("fixture", "locked") in ("locked", "free") and "q" in log.columns


def _run_tab(name: str, log: RunLog | None, groups: dict[str, RunLog]) -> rrb.Container:
    """A run's tab: the 3D testbed (if the run has mechanics) beside the time-series views stacked (the fixed
    ones the run has data for, then one per extra series group). Without ``log`` every fixed view is shown."""
    root = "/" + entity_name(name)
    views, shares = [], []
    for group, title, share, columns in FIXED_VIEWS:
        if log is None or any(c in log.columns for c in columns):
            views.append(rrb.TimeSeriesView(origin=f"{root}/{group}", name=title))
            shares.append(share)
    for group, extra in groups.items():
        views.append(rrb.TimeSeriesView(origin=f"{root}/{entity_name(group)}", name=_group_title(group, extra)))
        shares.append(2)
    if log is not None and not _has_mechanics(log):
        return rrb.Vertical(*views, row_shares=shares, name=name)
    return rrb.Horizontal(rrb.Spatial3DView(origin=f"{root}/testbed", name="testbed"),
                          rrb.Vertical(*views, row_shares=shares), column_shares=[2, 3], name=name)


def blueprint(names: list[str], series: dict[str, dict[str, RunLog]] | None = None,
              logs: dict[str, RunLog] | None = None) -> rrb.Blueprint:
    """One tab per run: the 3D testbed on the left, torques, voltages and temperature stacked on the right,
    then one time-series view per group of the run's extra ``series`` (run name -> group -> RunLog).

    With the runs' ``logs`` (run name -> RunLog) a run without mechanics (a rig record, a rigid joint) has no
    3D view, and a fixed view is left out when the run has none of its columns.
    """
    series, logs = series or {}, logs or {}
    tabs = [_run_tab(name, logs.get(name), series.get(name, {})) for name in names]
    return rrb.Blueprint(rrb.Tabs(*tabs) if len(tabs) > 1 else tabs[0], collapse_panels=False)


def record_logs(logs: dict[str, RunLog], params: TestbedParams | None = None, *, path: str | Path | None = None,
                spawn: bool = False, application_id: str = "torquebed",
                series: dict[str, dict[str, RunLog]] | None = None, port: int = VIEWER_PORT,
                **kwargs) -> RecordingSummary:
    """Record runs to an .rrd file (``path``) and/or a spawned viewer (``spawn``).

    Parameters
    ----------
    logs : dict of str to RunLog
        Run name -> its log (names become entity paths: give distinct names).
    params : TestbedParams, optional
        The runs' parameter set (geometry).
    path : str or Path, optional
        Write the recording here (parent folders created).
    spawn : bool
        Stream to a rerun viewer on ``port`` (:func:`open_viewer`: the one listening there or one started).
    series : dict of str to dict of str to RunLog, optional
        Extra series of some runs: run name (a key of ``logs``) -> group -> the group's series (see
        :func:`record_series`).
    port : int
        The viewer's gRPC port.
    **kwargs
        ``pose_rate_hz`` and ``angle_exaggeration`` of :func:`record_run`.

    Raises
    ------
    RecordingError
        When rerun is disabled by the environment (:func:`rerun_disabled`: nothing would be recorded).
    ViewerError
        With ``spawn``, when no viewer opens (before anything is recorded) or it does not take the recording
        within ``VIEWER_FLUSH_TIMEOUT_S``.
    """
    if path is None and not spawn:
        raise ValueError("record_logs needs path (an .rrd file) or spawn=True")
    if rerun_disabled():
        raise RecordingError(f"{rerun_disabled()}: nothing would be recorded; unset RERUN to record")
    names = list(logs)
    slugs = [entity_name(n) for n in names]
    if len(set(slugs)) != len(slugs):
        raise ValueError(f"run names must differ as entity paths: {slugs}")
    series = series or {}
    _check_series(names, series)
    viewer = open_viewer(port) if spawn else None
    rec = rr.RecordingStream(application_id, recording_id=f"{application_id}-{'-'.join(slugs)}"[:200])
    bp = blueprint(names, series, logs)
    sinks = []
    if path is not None:
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        sinks.append(rr.FileSink(str(path)))
    if viewer is not None:
        sinks.append(rr.GrpcSink(viewer))
    rec.set_sinks(*sinks, default_blueprint=bp)
    runs, poses = {}, {}
    for name, slug in zip(names, slugs, strict=True):
        runs[slug], poses[slug] = record_run(rec, name, logs[name], params, **kwargs)
    extra = {entity_name(name): {entity_name(group): record_series(rec, name, group, log)
                                 for group, log in groups.items()} for name, groups in series.items()}
    try:
        _flush(rec, viewer)
    finally:
        rec.disconnect()
    return RecordingSummary(path, runs, poses, extra, viewer)


def _check_series(names: list[str], series: dict[str, dict[str, RunLog]]) -> None:
    """Extra series belong to recorded runs, in groups apart from the fixed layout and from each other."""
    for name, groups in series.items():
        if name not in names:
            raise ValueError(f"series for run {name!r}, which is not among the recorded runs {names}")
        for group in groups:
            _check_group(name, group)
        slugs = [entity_name(g) for g in groups]
        if len(set(slugs)) != len(slugs):
            raise ValueError(f"series groups of run {name!r} must differ as entity paths: {slugs}")


# ---------------------------------------------------------------- the viewer
def rerun_disabled() -> str | None:
    """Why the rerun SDK records nothing in this environment (the ``RERUN`` variable set to off, 0 or false, as
    the SDK reads it), in a line; None when it records."""
    value = os.environ.get("RERUN", "")
    return f"rerun is disabled by the environment (RERUN={value})" if value.lower() in RERUN_OFF else None


def viewer_executable() -> str | None:
    """The rerun viewer to start: ``$RERUN_CLI_PATH`` (as the ``rerun`` script reads it), else the binary of the
    rerun_cli package (installed with rerun-sdk, so of the SDK's version), else ``rerun`` on PATH; None if none."""
    if os.environ.get("RERUN_CLI_PATH"):
        return os.environ["RERUN_CLI_PATH"]
    spec = importlib.util.find_spec("rerun_cli")
    if spec is not None and spec.origin is not None:
        binary = Path(spec.origin).parent / ("rerun.exe" if sys.platform == "win32" else "rerun")
        if binary.is_file():
            return str(binary)
    return shutil.which("rerun")


def viewer_listening(port: int = VIEWER_PORT) -> bool:
    """Whether a viewer answers on ``port`` of this machine: a server that replies to the HTTP/2 preface (gRPC's
    transport) with its settings within a second. A listener that does not (another program, a stopped viewer)
    is not taken for one: the rerun SDK would wait on it forever when it disconnects."""
    try:
        with socket.create_connection(("127.0.0.1", port), timeout=1.0) as connection:
            connection.sendall(HTTP2_PREFACE)
            return connection.recv(9)[3:4] == HTTP2_SETTINGS  # the type byte of the server's first frame header
    except OSError:
        return False


def viewer_unavailable(port: int = VIEWER_PORT) -> str | None:
    """Why no rerun viewer can open here, in a line (rerun disabled by the environment; else, unless a viewer
    already listens on ``port``: no display on Linux, no viewer executable); None when one can."""
    disabled = rerun_disabled()
    if disabled or viewer_listening(port):
        return disabled
    if sys.platform not in ("darwin", "win32") and not any(os.environ.get(v) for v in DISPLAY_VARIABLES):
        return "no display to open the rerun viewer on (DISPLAY and WAYLAND_DISPLAY are unset)"
    if viewer_executable() is None:
        return "no rerun viewer executable (neither rerun-sdk's rerun_cli package nor `rerun` on PATH)"
    return None


def open_viewer(port: int = VIEWER_PORT) -> str:
    """The gRPC address of a rerun viewer on ``port``: the one listening there, else one started detached (its
    output kept in a temporary file, off the terminal). Waits at most ``VIEWER_START_TIMEOUT_S`` +
    ``VIEWER_SETTLE_S``; raises :class:`ViewerError` (the reason in a line) if none can open or it exits."""
    reason = viewer_unavailable(port)
    if reason:
        raise ViewerError(reason)
    if not viewer_listening(port):
        with tempfile.TemporaryFile() as output:  # the viewer keeps writing to it once closed here
            process = subprocess.Popen([viewer_executable(), f"--port={port}", "--expect-data-soon"],
                                       stdin=subprocess.DEVNULL, stdout=output, stderr=output,
                                       start_new_session=True, env={**os.environ, "RERUN_APP_ONLY": "true"})
            _wait_listening(process, port, output)
    return f"rerun+http://127.0.0.1:{port}/proxy"


def _wait_listening(process: subprocess.Popen, port: int, output) -> None:
    """Return once the started viewer listens on ``port`` and is still running ``VIEWER_SETTLE_S`` later; raise
    :class:`ViewerError` if it exits, or (stopping it) if it does not listen within ``VIEWER_START_TIMEOUT_S``."""
    deadline = time.monotonic() + VIEWER_START_TIMEOUT_S
    while not viewer_listening(port):
        if process.poll() is not None:
            raise ViewerError(_exit_reason(process, output))
        if time.monotonic() > deadline:
            process.kill()
            process.wait()
            raise ViewerError(f"the rerun viewer did not listen on port {port} within {VIEWER_START_TIMEOUT_S:g} "
                              f"s; it was stopped")
        time.sleep(0.1)
    time.sleep(VIEWER_SETTLE_S)
    if process.poll() is not None:
        raise ViewerError(_exit_reason(process, output))


def _exit_reason(process: subprocess.Popen, output) -> str:
    """One line on a viewer that exited: its status and the last error line of its output."""
    output.seek(0)
    lines = [re.sub(r"\x1b\[[0-9;]*m| at \S+\.rs:\d+", "", line).strip()
             for line in output.read().decode(errors="replace").splitlines()]
    errors = [line for line in lines if re.search(r"error|panicked", line, re.IGNORECASE)] or lines or [""]
    said = f": {errors[-1][:300]}" if errors[-1] else ""
    return f"the rerun viewer exited as it started (exit status {process.returncode}){said}"


def _flush(rec: rr.RecordingStream, viewer: str | None) -> None:
    """Flush ``rec``'s sinks; with a viewer, within ``VIEWER_FLUSH_TIMEOUT_S`` (else :class:`ViewerError`)."""
    if viewer is None:
        rec.flush()
        return
    try:
        rec.flush(timeout_sec=VIEWER_FLUSH_TIMEOUT_S)
    except RuntimeError as exc:
        raise ViewerError(f"the viewer at {viewer} did not take the recording within {VIEWER_FLUSH_TIMEOUT_S:g} s "
                          f"({' '.join(str(exc).split())})") from None
