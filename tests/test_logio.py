"""Run-log files: round trips in CSV, Parquet and .mat; every validation rule names its column and row."""

import csv
import decimal
import hashlib
import importlib.machinery
import json
import math
import re
import struct
import sys
import types
import warnings
import zlib

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest
from scipy.io import loadmat, savemat

import sim.logio
from sim.logio import (
    MIN_SAMPLES,
    SLIDE_UNITS,
    LogError,
    LogWarning,
    SlideRunLog,
    read_log,
    read_variables,
    sidecar_path,
    write_log,
)
from sim.plant import Plant
from sim.run import run_open_loop
from sim.runlog import STANDARD_UNITS, RunLog
from tests.logio_fuzzing import ChildReader

FORMATS = ("csv", "parquet", "mat")
EDGE_FLOATS = [0.1, 1 / 3, -0.0, 5e-324, 1.7976931348623157e308, -2.2250738585072014e-308, 1e-17]


def small_log(seed: int = 0, n: int = 40) -> RunLog:
    """Every standard column, two extra ones, nested meta; awkward floats in 'tau_ref'."""
    rng = np.random.default_rng(seed)
    columns = {"time": 0.5 + 1e-3 * np.arange(1, n + 1)}
    for name in STANDARD_UNITS:
        if name != "time":
            columns[name] = rng.normal(0.0, 1.0, n)
    columns["tau_ref"][:len(EDGE_FLOATS)] = EDGE_FLOATS
    columns["tau_flexure"] = rng.normal(0.0, 2.0, n)
    columns["current"] = rng.normal(0.0, 3.0, n)
    units = {**STANDARD_UNITS, "tau_flexure": "N·m", "current": "A"}
    return RunLog(columns, units, {"fixture": "locked", "seed": seed, "gains": {"kp": 2.5, "ki": [1, 2]}})


def assert_same(a: RunLog, b: RunLog, *, meta: bool = True) -> None:
    assert type(a) is type(b)
    assert list(a.columns) == list(b.columns)
    for name in a.columns:
        assert b[name].dtype == np.float64, name
        assert np.array_equal(a[name].view(np.uint64), b[name].view(np.uint64)), name  # bits, so -0.0 counts
    assert a.units == b.units
    if meta:
        assert a.meta == b.meta


def minimal_rows(n: int = 10) -> list[list[str]]:
    """Header plus n samples at 1 kHz of time, tau_cmd, q, as CSV cells."""
    return [["time", "tau_cmd", "q"]] + [[repr(1e-3 * k), repr(0.1 * k), repr(0.01 * k)] for k in range(n)]


def write_rows(path, rows) -> None:
    with path.open("w", newline="") as fh:
        csv.writer(fh, lineterminator="\n").writerows(rows)


def digest(path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


@pytest.fixture(scope="module")
def simulated_log() -> RunLog:
    tau = np.random.default_rng(3).normal(0.0, 0.5, 200)
    return run_open_loop(Plant(fixture="locked"), tau, progress=False, meta={"seed": 3})


# ----------------------------------------------------------------------------------------------- round trips


@pytest.mark.parametrize("fmt", FORMATS)
def test_round_trip_is_bit_identical_in_each_format(tmp_path, fmt):
    """A log written and read back has the same columns (to the bit), order and units; meta except in CSV."""
    log = small_log(seed=1)
    back = read_log(write_log(log, tmp_path / f"run.{fmt}"))
    assert_same(log, back, meta=fmt != "csv")
    if fmt == "csv":
        assert back.meta == {}  # plain CSV has no place for meta (see docs/run_log_format.md)


@pytest.mark.parametrize("fmt", FORMATS)
def test_simulated_run_round_trips_in_each_format(tmp_path, simulated_log, fmt):
    """A 200-tick simulated run, with its extra columns (qd_motor, current, ...), survives every format."""
    with warnings.catch_warnings():
        warnings.simplefilter("error", LogWarning)
        back = read_log(write_log(simulated_log, tmp_path / f"sim.{fmt}"))
    assert_same(simulated_log, back, meta=fmt != "csv")


def test_csv_floats_are_the_shortest_text_that_reads_back_exactly(tmp_path):
    """CSV cells are Python's repr of each double: 0.1 is written '0.1', and every value reads back exactly."""
    path = write_log(small_log(), tmp_path / "run.csv")
    with path.open() as fh:
        rows = list(csv.reader(fh))
    column = rows[0].index("tau_ref")
    assert [row[column] for row in rows[1:len(EDGE_FLOATS) + 1]] == [repr(x) for x in EDGE_FLOATS]
    assert rows[1][column] == "0.1"


def test_csv_sidecar_holds_only_the_units_of_non_standard_columns(tmp_path):
    """run.csv gets run.units.json with the extra columns' units and nothing for the standard ones."""
    write_log(small_log(), tmp_path / "run.csv")
    assert json.loads((tmp_path / "run.units.json").read_text(encoding="utf-8")) == {
        "tau_flexure": "N·m", "current": "A"}


def test_csv_of_standard_columns_only_has_no_sidecar(tmp_path):
    """A log with only standard columns is a single CSV file."""
    log = RunLog({"time": np.arange(1.0, 6.0), "tau_cmd": np.zeros(5), "q": np.ones(5)},
                 {"time": "s", "tau_cmd": "N·m", "q": "rad"})
    write_log(log, tmp_path / "run.csv")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["run.csv"]


def test_parquet_keeps_units_and_meta_in_the_schema_metadata(tmp_path):
    """The Parquet schema metadata holds units and meta as JSON; columns are float64."""
    log = small_log()
    table = pq.read_table(write_log(log, tmp_path / "run.parquet"))
    assert json.loads(table.schema.metadata[b"torquebed.units"]) == log.units
    assert json.loads(table.schema.metadata[b"torquebed.meta"]) == log.meta
    assert all(field.type == pa.float64() for field in table.schema)


def test_mat_holds_one_column_variable_per_signal_a_units_struct_and_meta(tmp_path):
    """In the .mat every signal is an N x 1 double, 'units' a struct of char arrays, 'meta' JSON text."""
    log = small_log(n=12)
    raw = loadmat(str(write_log(log, tmp_path / "run.mat")), simplify_cells=False)
    assert all(raw[name].shape == (12, 1) and raw[name].dtype == np.float64 for name in log.columns)
    assert raw["units"].dtype.names == tuple(log.columns)
    assert raw["units"]["tau_cmd"][0, 0][0] == "N·m"
    assert json.loads(raw["meta"][0]) == log.meta


def test_mat_from_a_user_may_give_units_as_a_cell_array_with_ascii_spellings(tmp_path):
    """An N x 2 cell {column, unit} works as 'units', and 'Nm' / 'degC' read as 'N·m' / '°C'."""
    n = 8
    units = np.empty((3, 2), dtype=object)
    units[:] = [["tau_cmd", "Nm"], ["temperature", "degC"], ["tau_motor_est", "Nm"]]
    savemat(tmp_path / "rig.mat", {"time": np.arange(n) * 1e-3, "tau_cmd": np.zeros(n), "q": np.zeros(n),
                                   "temperature": np.full(n, 25.0), "tau_motor_est": np.zeros(n), "units": units})
    log = read_log(tmp_path / "rig.mat")
    assert log.units == {"time": "s", "tau_cmd": "N·m", "q": "rad", "temperature": "°C", "tau_motor_est": "N·m"}
    assert log.meta == {}


# ---------------------------------------------------------------------------------------------- overwriting


@pytest.mark.parametrize("fmt", FORMATS)
def test_writing_refuses_to_overwrite_unless_asked(tmp_path, fmt):
    """An existing file is left as it was and FileExistsError raised; overwrite=True replaces it."""
    path = tmp_path / f"run.{fmt}"
    path.write_bytes(b"precious")
    with pytest.raises(FileExistsError, match="overwrite=True"):
        write_log(small_log(), path)
    assert path.read_bytes() == b"precious"
    write_log(small_log(seed=2), path, overwrite=True)
    assert_same(small_log(seed=2), read_log(path), meta=fmt != "csv")


def test_csv_writing_refuses_to_overwrite_a_sidecar_and_replaces_a_stale_one_when_asked(tmp_path):
    """A leftover run.units.json blocks writing run.csv; with overwrite=True a stale sidecar is removed."""
    side = sidecar_path(tmp_path / "run.csv")
    side.write_text('{"q_extra": "m"}')
    standard_only = RunLog({"time": np.arange(1.0, 6.0), "tau_cmd": np.zeros(5), "q": np.ones(5)},
                           {"time": "s", "tau_cmd": "N·m", "q": "rad"})
    with pytest.raises(FileExistsError, match="run.units.json"):
        write_log(standard_only, tmp_path / "run.csv")
    assert not (tmp_path / "run.csv").exists()
    write_log(standard_only, tmp_path / "run.csv", overwrite=True)
    assert not side.exists()


# ----------------------------------------------------------------------------------------------- validation


def test_missing_required_column_is_named(tmp_path):
    """A log without 'tau_cmd' is refused with a message naming 'tau_cmd'."""
    rows = [[row[0], row[2]] for row in minimal_rows()]
    write_rows(tmp_path / "run.csv", rows)
    with pytest.raises(LogError, match="missing required column 'tau_cmd'") as err:
        read_log(tmp_path / "run.csv")
    assert err.value.column == "tau_cmd"


def test_a_log_without_q_tau_sensor_or_force_loadcell_is_refused(tmp_path):
    """At least one output-side column ('q', 'tau_sensor', 'force_loadcell') is required."""
    write_rows(tmp_path / "run.csv", [row[:2] for row in minimal_rows()])
    with pytest.raises(LogError, match="at least one of the columns 'q', 'tau_sensor', 'force_loadcell'"):
        read_log(tmp_path / "run.csv")


def test_nan_and_inf_are_reported_with_their_count_and_first_rows(tmp_path):
    """Non-finite cells name the column, the count, and the first five rows (header = row 1)."""
    rows = minimal_rows(20)
    for sample, text in [(1, "nan"), (4, "inf"), (5, "-inf"), (6, "NaN"), (9, "nan"), (12, "nan")]:
        rows[1 + sample][2] = text
    write_rows(tmp_path / "run.csv", rows)
    with pytest.raises(LogError, match=r"column 'q': 6 value\(s\) NaN or infinite, at rows 3, 6, 7, 8, 11, \.\.\.$") \
            as err:
        read_log(tmp_path / "run.csv")
    assert (err.value.column, err.value.row) == ("q", 3)


def test_time_that_does_not_increase_names_the_first_offending_row(tmp_path):
    """A repeated time stamp at sample index 6 is reported at row 8, with the value it failed to exceed."""
    rows = minimal_rows()
    rows[1 + 6][0] = rows[1 + 5][0]
    write_rows(tmp_path / "run.csv", rows)
    with pytest.raises(LogError, match=r"column 'time', row 8: 0\.005 s does not exceed 0\.005 s of row 7; time "
                                       r"must increase strictly") as err:
        read_log(tmp_path / "run.csv")
    assert err.value.row == 8


def test_irregular_sampling_beyond_max_jitter_names_the_row_and_the_step(tmp_path):
    """A 1.5 ms step among 1 ms steps is refused at 5 % jitter (row, step and median named), accepted at 60 %."""
    rows = minimal_rows()
    for k in range(4, 10):
        rows[1 + k][0] = repr(1e-3 * k + 0.5e-3)
    write_rows(tmp_path / "run.csv", rows)
    with pytest.raises(LogError, match=r"column 'time', row 6: the step 0\.0015 s from row 5 deviates 50 % from "
                                       r"the median step 0\.001 s; max_jitter = 5 %") as err:
        read_log(tmp_path / "run.csv")
    assert err.value.row == 6
    assert len(read_log(tmp_path / "run.csv", max_jitter=0.6)) == 10
    assert len(read_log(tmp_path / "run.csv", max_jitter=math.inf)) == 10


def test_a_log_shorter_than_the_minimum_is_refused(tmp_path):
    """Fewer than MIN_SAMPLES samples is an error that states the minimum."""
    write_rows(tmp_path / "run.csv", minimal_rows(MIN_SAMPLES - 1))
    with pytest.raises(LogError, match=f"has {MIN_SAMPLES - 1} sample\\(s\\); at least {MIN_SAMPLES} are needed"):
        read_log(tmp_path / "run.csv")


def _bad_cell_file(tmp_path, fmt):
    """Column 'q' holds the text 'abc' at 0-based sample index 3 (row 5)."""
    rows = minimal_rows()
    rows[1 + 3][2] = "abc"
    if fmt == "csv":
        write_rows(tmp_path / "run.csv", rows)
    columns = {name: [row[j] for row in rows[1:]] for j, name in enumerate(rows[0])}
    numbers = {name: np.array(cells, dtype=float) for name, cells in columns.items() if name != "q"}
    if fmt == "parquet":
        pq.write_table(pa.table({**numbers, "q": pa.array(columns["q"], type=pa.string())}), tmp_path / "run.parquet")
    if fmt == "mat":
        q = np.empty((len(columns["q"]), 1), dtype=object)
        q[:, 0] = [float(c) if c != "abc" else c for c in columns["q"]]
        savemat(tmp_path / "run.mat", {**numbers, "q": q}, oned_as="column")
    return tmp_path / f"run.{fmt}"


@pytest.mark.parametrize("fmt", FORMATS)
def test_a_non_numeric_cell_names_its_column_and_row_in_every_format(tmp_path, fmt):
    """Text in 'q' at sample index 3 is reported as row 5 (header = row 1) whatever the format."""
    with pytest.raises(LogError, match="column 'q', row 5: 'abc' is not a number") as err:
        read_log(_bad_cell_file(tmp_path, fmt))
    assert (err.value.column, err.value.row) == ("q", 5)


def test_an_empty_cell_in_the_first_sample_is_row_two(tmp_path):
    """The first sample is row 2: the header is row 1, as a spreadsheet shows the CSV."""
    rows = minimal_rows()
    rows[1][1] = ""
    write_rows(tmp_path / "run.csv", rows)
    with pytest.raises(LogError, match="column 'tau_cmd', row 2: empty cell"):
        read_log(tmp_path / "run.csv")


def test_a_misspelt_column_suggests_the_standard_name(tmp_path):
    """An undeclared 'tau_cmnd' is refused with "did you mean 'tau_cmd'?"."""
    rows = minimal_rows()
    rows[0][1] = "tau_cmnd"
    write_rows(tmp_path / "run.csv", rows)
    with pytest.raises(LogError, match="unknown column 'tau_cmnd': did you mean 'tau_cmd'\\?") as err:
        read_log(tmp_path / "run.csv")
    assert err.value.column == "tau_cmnd"


def test_a_column_close_to_a_standard_name_is_kept_when_its_unit_is_declared(tmp_path):
    """'qd_motor' is close to 'q_motor' but declared in the sidecar, so it is kept with its unit."""
    rows = [row + [repr(0.5)] for row in minimal_rows()]
    rows[0][-1] = "qd_motor"
    write_rows(tmp_path / "run.csv", rows)
    (tmp_path / "run.units.json").write_text('{"qd_motor": "rad/s"}')
    assert read_log(tmp_path / "run.csv").units["qd_motor"] == "rad/s"


def test_an_unknown_column_far_from_every_standard_name_is_kept_as_unknown_with_a_warning(tmp_path):
    """'position_lab' (no unit declared, no close standard name) is kept, unit 'unknown', and a LogWarning says so."""
    rows = [row + ["7"] for row in minimal_rows()]
    rows[0][-1] = "position_lab"
    write_rows(tmp_path / "run.csv", rows)
    with pytest.warns(LogWarning, match="'position_lab' are not in the format and have no unit; kept with unit "
                                        "'unknown' \\(declare their units in the sidecar run.units.json\\)"):
        log = read_log(tmp_path / "run.csv")
    assert log.units["position_lab"] == "unknown"
    assert np.array_equal(log["position_lab"], np.full(10, 7.0))


def test_a_units_row_in_a_csv_is_refused_with_a_pointer_to_the_sidecar(tmp_path):
    """A second header row of units ('s', 'N·m', 'rad') is recognised and the sidecar named instead."""
    rows = minimal_rows()
    rows.insert(1, ["s", "N·m", "rad"])
    write_rows(tmp_path / "run.csv", rows)
    with pytest.raises(LogError, match="row 2 holds no number .*a units row\\?.*run.units.json"):
        read_log(tmp_path / "run.csv")


def test_a_row_with_a_missing_cell_is_named(tmp_path):
    """A row with fewer cells than the header is reported by its row number."""
    rows = minimal_rows()
    rows[1 + 4] = rows[1 + 4][:2]
    write_rows(tmp_path / "run.csv", rows)
    with pytest.raises(LogError, match="row 6 has 2 cells; the header row has 3"):
        read_log(tmp_path / "run.csv")


def test_a_declared_unit_that_disagrees_with_the_format_is_refused(tmp_path):
    """A Parquet file declaring 'q' in degrees is refused: the format fixes radians."""
    rows = minimal_rows()
    table = pa.table({name: np.array([r[j] for r in rows[1:]], dtype=float) for j, name in enumerate(rows[0])})
    table = table.replace_schema_metadata({b"torquebed.units": json.dumps({"q": "deg"})})
    pq.write_table(table, tmp_path / "run.parquet")
    with pytest.raises(LogError, match="column 'q' is in 'deg' according to the schema metadata 'torquebed.units'; "
                                       "the format fixes 'rad' for joint='hinge'"):
        read_log(tmp_path / "run.parquet")


def test_an_unknown_suffix_is_refused(tmp_path):
    """Only .csv, .parquet and .mat are run-log files."""
    (tmp_path / "run.txt").write_text("time,tau_cmd,q\n")
    with pytest.raises(LogError, match="unknown suffix '.txt'; use one of .csv, .parquet, .mat"):
        read_log(tmp_path / "run.txt")


def _nan_file(tmp_path, fmt):
    rows = minimal_rows()
    rows[1 + 2][2] = "nan"
    columns = {name: np.array([row[j] for row in rows[1:]], dtype=float) for j, name in enumerate(rows[0])}
    path = tmp_path / f"run.{fmt}"
    if fmt == "csv":
        write_rows(path, rows)
        (tmp_path / "run.units.json").write_text("{}")
    elif fmt == "parquet":
        pq.write_table(pa.table(columns), path)
    else:
        savemat(path, columns, oned_as="column")
    return path


@pytest.mark.parametrize("fmt", FORMATS)
def test_a_failed_read_leaves_the_file_bytes_unchanged(tmp_path, fmt):
    """Reading a log that is refused (a NaN) changes neither the file nor its sidecar."""
    path = _nan_file(tmp_path, fmt)
    before = {p.name: digest(p) for p in tmp_path.iterdir()}
    with pytest.raises(LogError, match="column 'q': 1 value\\(s\\) NaN or infinite, at rows 4$"):
        read_log(path)
    assert {p.name: digest(p) for p in tmp_path.iterdir()} == before


def test_writing_refuses_a_log_the_reader_would_refuse(tmp_path):
    """write_log applies the reader's rules: a NaN is reported and no file is left behind."""
    log = small_log()
    log.columns["qd"][5] = np.nan
    with pytest.raises(LogError, match="column 'qd': 1 value\\(s\\) NaN or infinite, at rows 7$"):
        write_log(log, tmp_path / "run.parquet")
    assert not any(tmp_path.iterdir())


def test_mat_writing_refuses_a_column_name_matlab_cannot_hold(tmp_path):
    """A column named '2nd_q' cannot be a MATLAB variable; the error says so and suggests CSV or Parquet."""
    log = small_log()
    log = RunLog({**log.columns, "2nd_q": log["q"]}, {**log.units, "2nd_q": "rad"})
    with pytest.raises(LogError, match="column '2nd_q' cannot be a MATLAB variable.*write CSV or Parquet"):
        write_log(log, tmp_path / "run.mat")
    assert not (tmp_path / "run.mat").exists()


# ----------------------------------------------------------------------------------------------- slide joint


def slide_log(n: int = 30) -> SlideRunLog:
    rng = np.random.default_rng(5)
    columns = {"time": 1e-3 * np.arange(n), "tau_cmd": rng.normal(0, 5, n), "q": rng.normal(0, 1e-3, n),
               "qd": rng.normal(0, 1e-2, n), "force_loadcell": rng.normal(0, 5, n)}
    units = {"time": "s", "tau_cmd": "N", "q": "m", "qd": "m/s", "force_loadcell": "N"}
    return SlideRunLog(columns, units, {"joint": "slide"})


def test_runlog_fixes_rotational_units_so_a_slide_log_needs_slide_runlog():
    """RunLog refuses 'tau_cmd' in N; SlideRunLog takes N, m, m/s and refuses N·m."""
    log = slide_log()
    with pytest.raises(ValueError, match="'tau_cmd' is in 'N'; the format fixes 'N·m'"):
        RunLog(log.columns, log.units)
    with pytest.raises(ValueError, match="a slide joint's log fixes 'N'"):
        SlideRunLog(log.columns, {**log.units, "tau_cmd": "N·m"})
    assert {k: SLIDE_UNITS[k] for k in ("tau_cmd", "q", "qd")} == {"tau_cmd": "N", "q": "m", "qd": "m/s"}


@pytest.mark.parametrize("fmt", FORMATS)
def test_slide_joint_log_round_trips_with_linear_units(tmp_path, fmt):
    """A slide log (N, m, m/s) read with joint='slide' is the same SlideRunLog."""
    log = slide_log()
    back = read_log(write_log(log, tmp_path / f"slide.{fmt}"), joint="slide")
    assert_same(log, back, meta=fmt != "csv")
    assert back.units["tau_cmd"] == "N" and back.units["q"] == "m" and back.units["qd"] == "m/s"


@pytest.mark.parametrize("fmt", FORMATS)
def test_a_slide_log_read_as_a_hinge_is_refused_with_a_hint(tmp_path, fmt):
    """Reading a slide log with the default joint='hinge' names the column and suggests joint='slide'."""
    path = write_log(slide_log(), tmp_path / f"slide.{fmt}")
    with pytest.raises(LogError, match="column 'tau_cmd' is in 'N' .*fixes 'N·m' for joint='hinge'; for a slide "
                                       "joint pass joint='slide'"):
        read_log(path)


def test_a_hinge_csv_without_sidecar_reads_as_slide_in_linear_units(tmp_path):
    """Without declared units, joint='slide' alone decides that 'tau_cmd' is in N and 'q' in m."""
    write_rows(tmp_path / "run.csv", minimal_rows())
    log = read_log(tmp_path / "run.csv", joint="slide")
    assert isinstance(log, SlideRunLog)
    assert (log.units["tau_cmd"], log.units["q"]) == ("N", "m")


# --------------------------------------------------------------------------------------------- MATLAB v7.3


def _mat73_header() -> bytes:
    text = b"MATLAB 7.3 MAT-file, Platform: GLNXA64, Created on: Mon Jan  1 00:00:00 2024 HDF5 schema 1.00 ."
    return (text.ljust(116) + bytes(8) + b"\x00\x02IM").ljust(512, b"\x00")


def test_v73_mat_without_h5py_says_to_install_it_or_resave_as_v7(tmp_path, monkeypatch):
    """A v7.3 (HDF5) .mat read without h5py raises a LogError naming h5py and save(..., '-v7')."""
    path = tmp_path / "rig.mat"
    path.write_bytes(_mat73_header() + b"\x89HDF\r\n\x1a\n" + bytes(64))
    before = digest(path)
    monkeypatch.setitem(sys.modules, "h5py", None)  # 'import h5py' now raises ImportError
    with pytest.raises(LogError, match=r"MATLAB v7\.3 \(HDF5\) file; reading it needs h5py \(pip install h5py\), "
                                       r"or re-save it as v7 in MATLAB: save\('rig\.mat', '-v7'\)"):
        read_log(path)
    assert digest(path) == before


@pytest.mark.parametrize("units_as", ["struct", "cell"])
def test_v73_mat_is_read_with_h5py(tmp_path, units_as):
    """With h5py, a v7.3 file laid out as MATLAB writes it (transposed doubles, units struct or cell) reads exactly."""
    h5py = pytest.importorskip("h5py")
    log = small_log(n=15)
    path = tmp_path / "rig.mat"

    def char(group, name, text):  # a 1 x L char is HDF5 (L, 1) of UTF-16 codes
        ds = group.create_dataset(name, data=np.array([[ord(c)] for c in text], dtype=np.uint16))
        ds.attrs["MATLAB_class"] = np.bytes_("char")
        return ds

    with h5py.File(path, "w", userblock_size=512) as f:
        for name, values in sorted(log.columns.items()):  # HDF5 lists names sorted; column order is in 'units'
            f.create_dataset(name, data=values[None, :]).attrs["MATLAB_class"] = np.bytes_("double")
        if units_as == "struct":
            units = f.create_group("units")
            units.attrs["MATLAB_class"] = np.bytes_("struct")
            units.attrs["MATLAB_fields"] = np.array([np.frombuffer(n.encode(), "S1") for n in log.units],
                                                    dtype=h5py.vlen_dtype(np.dtype("S1")))
            for name, unit in log.units.items():
                char(units, name, unit)
        else:  # an N x 2 cell {column, unit} is HDF5 (2, N) of references into '#refs#'
            refs = f.create_group("#refs#")
            cells = np.empty((2, len(log.units)), dtype=h5py.ref_dtype)
            for j, (name, unit) in enumerate(log.units.items()):
                cells[0, j] = char(refs, f"c{j}", name).ref
                cells[1, j] = char(refs, f"u{j}", unit).ref
            f.create_dataset("units", data=cells).attrs["MATLAB_class"] = np.bytes_("cell")
        char(f, "meta", json.dumps(log.meta))
    with path.open("r+b") as fh:
        fh.write(_mat73_header())
    assert_same(log, read_log(path))

def test_csv_with_trailing_blank_lines_reads_the_same_numbers(tmp_path):
    """Blank lines at the end send the reader down its cell-by-cell path, which gives the same doubles."""
    log = small_log(seed=4)
    path = write_log(log, tmp_path / "run.csv")
    with path.open("a") as fh:
        fh.write("\n\n")
    assert_same(log, read_log(path), meta=False)


# ------------------------------------------------------------------------------------- refusing bad input


def _columns(rows=None) -> dict[str, np.ndarray]:
    """The minimal rows as float columns."""
    rows = rows or minimal_rows()
    return {name: np.array([row[j] for row in rows[1:]], dtype=float) for j, name in enumerate(rows[0])}


def _write_columns(path, columns, **mat_variables):
    """Columns as a CSV, Parquet (pyarrow) or v5 .mat (savemat) file, by suffix; no units."""
    if path.suffix == ".csv":
        rows = zip(*columns.values(), strict=True)
        write_rows(path, [list(columns)] + [[repr(float(x)) for x in row] for row in rows])
    elif path.suffix == ".parquet":
        pq.write_table(pa.table(columns), path)
    else:
        savemat(path, {**columns, **mat_variables}, oned_as="column")
    return path


@pytest.mark.parametrize("fmt", FORMATS)
def test_every_error_names_the_file_once(tmp_path, fmt):
    """A LogError from read_log starts with the file's name; a message that names it already is not prefixed."""
    columns = _columns()
    del columns["tau_cmd"]
    path = _write_columns(tmp_path / f"run.{fmt}", columns)
    with pytest.raises(LogError, match=rf"^run\.{fmt}: missing required column 'tau_cmd'") as err:
        read_log(path)
    assert err.value.column == "tau_cmd"
    (tmp_path / f"empty.{fmt}").write_bytes(b"")
    with pytest.raises(LogError) as err:
        read_log(tmp_path / f"empty.{fmt}")
    assert str(err.value).count(f"empty.{fmt}") == 1, str(err.value)


def test_mat_columns_of_different_lengths_name_the_file_and_the_column(tmp_path):
    """A 9-sample 'q' beside a 10-sample 'time' is a LogError naming run.mat, 'q' and the first missing row."""
    path = _mat_log_file(tmp_path, q=np.zeros(9))
    with pytest.raises(LogError, match=r"^run\.mat: column 'q' has 9 samples; 'time' has 10") as err:
        read_log(path)
    assert (err.value.column, err.value.row) == ("q", 11)


def _mat_log_file(tmp_path, **variables):
    """A v5 .mat of the 10-sample minimal log, with ``variables`` replacing or adding variables."""
    return _write_columns(tmp_path / "run.mat", _columns(), **variables)


def _parquet_with(tmp_path, **columns):
    """A Parquet file of the minimal log with ``columns`` (pyarrow arrays) replacing or adding columns."""
    table = pa.table({**{name: pa.array(values) for name, values in _columns().items()}, **columns})
    pq.write_table(table, tmp_path / "run.parquet")
    return tmp_path / "run.parquet"


@pytest.mark.parametrize("units", ['{"q": 3}', '["rad"]', '{"q": null}'])
def test_parquet_units_metadata_must_map_columns_to_unit_strings(tmp_path, units):
    """'torquebed.units' that is not a JSON object of strings is a LogError naming the file and the key."""
    table = pa.table(_columns()).replace_schema_metadata({b"torquebed.units": units})
    pq.write_table(table, tmp_path / "run.parquet")
    with pytest.raises(LogError, match=r"^run\.parquet: schema metadata 'torquebed.units' must"):
        read_log(tmp_path / "run.parquet")


@pytest.mark.parametrize("text", [b"\xff\xfe{", b"[" * 100_000, b'{"seed": ' + b"1" * 5000 + b"}"])
def test_parquet_meta_that_is_not_json_is_refused(tmp_path, text):
    """Non-UTF-8, too deeply nested or oversized-integer 'torquebed.meta' is a LogError naming the file."""
    table = pa.table(_columns()).replace_schema_metadata({b"torquebed.meta": text})
    pq.write_table(table, tmp_path / "run.parquet")
    with pytest.raises(LogError, match=r"^run\.parquet: schema metadata 'torquebed.meta' is not valid JSON"):
        read_log(tmp_path / "run.parquet")


def test_a_truncated_parquet_file_is_refused_naming_it_once(tmp_path):
    """A Parquet file cut anywhere is a LogError that names the file once."""
    data = write_log(small_log(n=8), tmp_path / "whole.parquet").read_bytes()
    for cut in range(0, len(data), max(1, len(data) // 40)):
        (tmp_path / "cut.parquet").write_bytes(data[:cut])
        with pytest.raises(LogError, match=r"^cut\.parquet is not a readable Parquet file") as err:
            read_log(tmp_path / "cut.parquet")
        assert str(err.value).count("cut.parquet") == 1


def test_a_parquet_timestamp_time_column_is_refused_with_its_type(tmp_path):
    """Nanosecond timestamps in 'time' are a LogError naming the column and the type, not a crash."""
    stamps = pa.array(1_700_000_000_000_000_123 + 1_000_000 * np.arange(10), type=pa.timestamp("ns"))
    with pytest.raises(LogError, match=r"^run\.parquet: column 'time' holds timestamp\[ns\] values; the format "
                                       r"stores time in seconds") as err:
        read_log(_parquet_with(tmp_path, time=stamps))
    assert err.value.column == "time"


@pytest.mark.parametrize("values", [pa.array([[0.1, 0.2]] * 10), pa.array([{"x": 1.0}] * 10),
                                    pa.array([b"\x00\x01"] * 10), pa.array([decimal.Decimal("1.5")] * 10)],
                         ids=["list", "struct", "binary", "decimal"])
def test_parquet_columns_that_are_not_numbers_or_text_are_refused_with_their_type(tmp_path, values):
    """List, struct, binary and decimal columns are a LogError naming the column and its Parquet type."""
    kind = re.escape(str(values.type).split("<")[0])  # Parquet renames a list's item field
    with pytest.raises(LogError, match=rf"^run\.parquet: column 'q' holds {kind}") as err:
        read_log(_parquet_with(tmp_path, q=values))
    assert err.value.column == "q"


def test_a_dictionary_encoded_parquet_column_reads_as_its_values(tmp_path):
    """A dictionary-encoded column (pandas' categorical) of numbers reads like the plain column."""
    q = _columns()["q"]
    log = read_log(_parquet_with(tmp_path, q=pa.array(q).dictionary_encode()))
    assert np.array_equal(log["q"], q)


# ----------------------------------------------------------------------------------------- CSV encodings


def _csv_text() -> str:
    """The minimal log with a non-standard column 'T_gehäuse' in °C, as CSV text (declared in a sidecar)."""
    rows = [row + ["25.5"] for row in minimal_rows()]
    rows[0][-1] = "T_gehäuse"
    return "".join(",".join(row) + "\r\n" for row in rows)


@pytest.mark.parametrize("encoding", ["latin-1", "cp1252", "utf-8-sig", "utf-16", "utf-16-be"])
def test_a_csv_in_another_encoding_reads_the_same_log(tmp_path, encoding):
    """Latin-1/cp1252 (no byte-order mark), UTF-8 with one, and UTF-16 with one read like UTF-8."""
    (tmp_path / "utf8.csv").write_bytes(_csv_text().encode("utf-8"))
    bom = "\ufeff" if encoding == "utf-16-be" else ""  # the other codecs write their byte-order mark
    (tmp_path / "other.csv").write_bytes((bom + _csv_text()).encode(encoding))
    for stem in ("utf8", "other"):
        (tmp_path / f"{stem}.units.json").write_text('{"T_gehäuse": "°C"}', encoding="utf-8")
    assert_same(read_log(tmp_path / "utf8.csv"), read_log(tmp_path / "other.csv"))
    assert read_log(tmp_path / "other.csv").units["T_gehäuse"] == "°C"


def test_a_cp1252_sidecar_is_read(tmp_path):
    """A sidecar saved by a Windows editor (cp1252) gives the same units."""
    rows = minimal_rows()
    write_rows(tmp_path / "run.csv", [rows[0] + ["T_board"]] + [row + ["25"] for row in rows[1:]])
    (tmp_path / "run.units.json").write_bytes('{"T_board": "°C"}'.encode("cp1252"))
    assert read_log(tmp_path / "run.csv").units["T_board"] == "°C"


def test_a_tab_separated_utf16_excel_export_says_tabs_and_names_the_file(tmp_path):
    """Excel's 'Unicode text' export (UTF-16 LE with a byte-order mark, tabs) gets the separator message."""
    text = "".join("\t".join(row) + "\r\n" for row in minimal_rows())
    (tmp_path / "export.csv").write_bytes(text.encode("utf-16"))
    with pytest.raises(LogError, match=r"^export\.csv: the header row is one cell .*separated by tabs"):
        read_log(tmp_path / "export.csv")


def test_a_csv_no_accepted_encoding_decodes_names_the_encodings_tried(tmp_path):
    """Bytes that are neither UTF-8 nor cp1252 (0x81 is undefined in cp1252) are refused naming both and the row."""
    rows = minimal_rows()
    data = ("\n".join(",".join(row) for row in rows) + "\n").encode()
    data = data.replace(b"0.3", b"0.3\x81\xb0", 1)
    (tmp_path / "run.csv").write_bytes(data)
    with pytest.raises(LogError, match=r"^run\.csv is not text in UTF-8 \(byte 0x81 in row 5\) or cp1252 \(byte "
                                       r"0x81 in row 5\)") as err:
        read_log(tmp_path / "run.csv")
    assert err.value.row == 5


def test_a_utf16_file_with_an_odd_byte_count_is_refused_naming_the_encoding(tmp_path):
    """A byte-order mark fixes the encoding: a cut UTF-16 file is a LogError naming UTF-16, not a crash."""
    (tmp_path / "run.csv").write_bytes(_csv_text().encode("utf-16")[:-1])
    with pytest.raises(LogError, match=r"^run\.csv is not text in UTF-16 "):
        read_log(tmp_path / "run.csv")


def test_an_unclosed_quote_is_a_logerror_naming_the_row(tmp_path):
    """A stray '"' makes the rest of the file one cell; past the csv module's field limit that is a LogError."""
    rows = minimal_rows(30_000)
    rows[3][1] = '"0.3'
    (tmp_path / "run.csv").write_text("\n".join(",".join(row) for row in rows) + "\n")
    with pytest.raises(LogError, match=r"^run\.csv: row 4: "):
        read_log(tmp_path / "run.csv")


@pytest.mark.parametrize("text", [b"\x81\xff", b"[" * 100_000, b'{"q_extra": 3}', b'["m"]', b"{"])
def test_a_bad_sidecar_is_a_logerror_naming_the_sidecar(tmp_path, text):
    """A sidecar that is undecodable, not JSON, or not an object of unit strings names run.units.json."""
    write_rows(tmp_path / "run.csv", minimal_rows())
    (tmp_path / "run.units.json").write_bytes(text)
    with pytest.raises(LogError, match=r"^run\.units\.json") as err:
        read_log(tmp_path / "run.csv")
    assert err.value.path == tmp_path / "run.units.json"


# ---------------------------------------------------------------------------------------------- numbers


@pytest.mark.parametrize("cell", ["1_000", "１", "٣", "\xa01", "1\u3000", "\x0b1", "0x10", "1e5_0"])
@pytest.mark.parametrize("fmt", ["csv", "parquet"])
def test_numbers_are_ascii_decimals_not_whatever_float_accepts(tmp_path, fmt, cell):
    """'1_000', full-width or Arabic-Indic digits and non-ASCII spaces are refused, naming column and row."""
    rows = minimal_rows()
    rows[1 + 3][2] = cell
    if fmt == "csv":
        write_rows(tmp_path / "run.csv", rows)
    else:
        columns = _columns([row[:2] for row in rows])
        pq.write_table(pa.table({**columns, "q": pa.array([row[2] for row in rows[1:]])}), tmp_path / "run.parquet")
    with pytest.raises(LogError, match=rf"column 'q', row 5: {re.escape(repr(cell))} is not a number") as err:
        read_log(tmp_path / f"run.{fmt}")
    assert (err.value.column, err.value.row) == ("q", 5)


@pytest.mark.parametrize("blank_lines", ["", "\n\n"], ids=["fast path", "cell by cell"])
def test_spaces_and_tabs_around_numbers_and_any_decimal_spelling_are_accepted(tmp_path, blank_lines):
    """' 1', '\\t2 ', '+.5', '5.', '1E+2' and '-0' are numbers on both reading paths."""
    rows = minimal_rows(6)
    for k, cell in enumerate([" 1", "\t2 ", "+.5", "5.", "1E+2", "-0"]):
        rows[1 + k][2] = cell
    (tmp_path / "run.csv").write_text("\n".join(",".join(row) for row in rows) + "\n" + blank_lines)
    assert read_log(tmp_path / "run.csv")["q"].tolist() == [1.0, 2.0, 0.5, 5.0, 100.0, -0.0]


# ------------------------------------------------------------------------------------------- .mat structure


@pytest.fixture(scope="module")
def child():
    """read_log in a child process: a file that crashes the reader fails a test instead of ending pytest."""
    reader = ChildReader()
    yield reader
    reader.close()


def _plain_mat(tmp_path, name="run.mat", **extra) -> bytes:
    """An uncompressed v5 .mat of a 5-sample log (time, tau_cmd, q, units, meta) and ``extra`` variables.

    Its first variable, 'time', is at byte 128: tag (8), array flags (16), dimensions (16), name (8), then
    the tag of its data at byte 176 and the dimensions' values at bytes 160 and 164.
    """
    n = 5
    variables = {"time": 1e-3 * np.arange(n), "tau_cmd": np.zeros(n), "q": np.ones(n),
                 "units": {"time": "s", "tau_cmd": "N·m", "q": "rad"}, "meta": "{}", **extra}
    savemat(tmp_path / name, variables, oned_as="column", do_compression=False)
    return (tmp_path / name).read_bytes()


def _patched(tmp_path, data: bytes, at: int, value: int, name="run.mat"):
    """``data`` with the little-endian uint32 at byte ``at`` set to ``value``, written to ``name``."""
    path = tmp_path / name
    path.write_bytes(data[:at] + struct.pack("<I", value) + data[at + 4:])
    return path


def _crashing_mat(tmp_path, compressed: bool):
    """The 616-byte (uncompressed) .mat whose 'time' data is tagged with type 8, which MAT v5 leaves
    undefined; scipy 1.17's loadmat looks the type up in a table without a range check and crashes (SIGSEGV)."""
    data = _plain_mat(tmp_path)
    if not compressed:
        return _patched(tmp_path, data, 176, 8)
    inner = data[128:128 + 8 + struct.unpack_from("<I", data, 132)[0]]
    inner = inner[:48] + struct.pack("<I", 8) + inner[52:]
    packed = zlib.compress(inner)
    path = tmp_path / "run.mat"
    path.write_bytes(data[:128] + struct.pack("<II", 15, len(packed)) + packed + data[128 + len(inner):])
    return path


@pytest.mark.parametrize("compressed", [False, True], ids=["plain", "compressed"])
def test_the_mat_that_crashes_scipy_is_a_logerror(tmp_path, child, compressed):
    """A data element of undefined type 8 is refused before scipy parses the file, naming file and variable."""
    kind, message = child.read(_crashing_mat(tmp_path, compressed))
    assert (kind, message) == ("LogError", "run.mat: variable 'time''s real part has data type 8; expected one of "
                                           "[1, 2, 3, 4, 5, 6, 7, 9, 12, 13]")


def test_a_mat_cut_after_its_header_says_so(tmp_path):
    """A .mat cut at 128 bytes is reported as holding no variables, not as lacking the column 'time'."""
    data = write_log(small_log(n=8), tmp_path / "whole.mat").read_bytes()
    (tmp_path / "run.mat").write_bytes(data[:128])
    with pytest.raises(LogError, match=r"^run\.mat: the file holds no variables after its 128-byte header"):
        read_log(tmp_path / "run.mat")


def _variable_ends(data: bytes) -> set[int]:
    """Where each top-level variable of a little-endian v5 .mat ends (a cut there leaves a whole file)."""
    ends, pos = set(), 128
    while pos < len(data):
        pos += 8 + struct.unpack_from("<I", data, pos + 4)[0]
        ends.add(pos)
    return ends


def test_a_mat_cut_anywhere_is_a_logerror_naming_the_file(tmp_path, child):
    """Every prefix of a compressed and of an uncompressed .mat, except those ending at a variable's end, is
    refused with a LogError naming the file."""
    for data in (write_log(small_log(n=8), tmp_path / "whole.mat").read_bytes(), _plain_mat(tmp_path, "p.mat")):
        whole = _variable_ends(data)
        for cut in range(0, len(data), 3):
            (tmp_path / "cut.mat").write_bytes(data[:cut])
            kind, message = child.read(tmp_path / "cut.mat")
            expected = ("RunLog", "LogError") if cut in whole else ("LogError",)
            assert kind in expected and (kind == "RunLog" or message.startswith("cut.mat")), (cut, kind, message)


@pytest.mark.parametrize(("at", "value", "message"), [
    (164, 6, r"variable 'time''s real part holds 40 bytes of 8-byte values; its dimensions \[5, 6\] need 240"),
    (160, 0x80000000, r"a variable has negative dimensions"),
    (128, 0, r"the data element at byte 128 has type 0; a variable is miMATRIX"),
    (132, 0xFFFF_FFF0, r"the variable at byte 128 declares 4294967280 bytes"),
    (144, 0x11, r"a variable is a MATLAB object"),
    (144, 0x05, r"variable 'time' is a sparse array"),
], ids=["dims", "negative", "type", "size", "opaque", "sparse"])
def test_a_mat_whose_structure_is_inconsistent_is_refused_before_parsing(tmp_path, child, at, value, message):
    """Dimensions that disagree with the data, bad tags, sizes past the end, classes a log cannot hold."""
    kind, text = child.read(_patched(tmp_path, _plain_mat(tmp_path), at, value))
    assert kind == "LogError" and re.search(rf"^run\.mat: {message}", text), text


def test_a_struct_with_field_name_length_zero_is_refused(tmp_path, child):
    """scipy divides by the field name length; zero is refused before."""
    data = _plain_mat(tmp_path)
    at = data.index(struct.pack("<HHI", 5, 4, 8))  # 'units': small element, int32, 4 bytes, value 8
    kind, text = child.read(_patched(tmp_path, data, at + 4, 0))
    assert (kind, text) == ("LogError", "run.mat: variable 'units''s field name length is 0")


def test_a_cell_array_with_dimensions_but_no_cells_is_refused(tmp_path, child):
    """A 100000 x 100000 cell with one cell's bytes would make scipy allocate 10^10 objects: refused."""
    cell = np.empty((1, 1), dtype=object)
    cell[0, 0] = "x"
    data = _plain_mat(tmp_path, extra=cell)
    at = data.index(b"extra") - 8 - 8  # the dimensions' values, before the name's small element
    data = data[:at] + struct.pack("<ii", 100_000, 100_000) + data[at + 8:]
    (tmp_path / "run.mat").write_bytes(data)
    kind, text = child.read(tmp_path / "run.mat")
    assert kind == "LogError" and "variable 'extra' declares 10000000000 cells or fields" in text, text


def test_mat_arrays_nested_too_deep_are_refused(tmp_path, child):
    """Cells in cells 12 deep (the C stack of scipy's recursive reader is the limit otherwise) are refused."""
    nested = np.zeros(1)
    for _ in range(12):
        cell = np.empty((1, 1), dtype=object)
        cell[0, 0] = nested
        nested = cell
    kind, text = child.read(_mat_log_file(tmp_path, extra=nested))
    assert kind == "LogError" and "nests arrays deeper than 8 levels" in text, text


def test_a_mat_v4_log_is_read_and_a_cut_one_refused(tmp_path, child):
    """MATLAB v4 files are checked the same way: a whole one reads, every prefix is a LogError."""
    columns = _columns()
    savemat(tmp_path / "v4.mat", columns, oned_as="column", format="4")
    log = read_log(tmp_path / "v4.mat")
    assert all(np.array_equal(log[name], values) for name, values in columns.items())
    data = (tmp_path / "v4.mat").read_bytes()
    for cut in range(1, len(data), 11):
        (tmp_path / "cut.mat").write_bytes(data[:cut])
        kind, text = child.read(tmp_path / "cut.mat")
        assert kind == "LogError" and text.startswith("cut.mat"), (cut, text)


def _fake_h5py(monkeypatch):
    """Make h5py look installed to the parent process (the parser script is replaced in these tests)."""
    module = types.ModuleType("h5py")
    module.__spec__ = importlib.machinery.ModuleSpec("h5py", None)
    monkeypatch.setitem(sys.modules, "h5py", module)


def _v73_file(tmp_path):
    path = tmp_path / "rig.mat"
    path.write_bytes(_mat73_header() + b"\x89HDF\r\n\x1a\n" + bytes(64))
    return path


def test_a_crash_of_the_v73_parser_is_a_logerror_naming_the_signal(tmp_path, monkeypatch):
    """The v7.3 parser runs in a child process; one killed by SIGSEGV gives a LogError, not a dead process."""
    script = tmp_path / "crash.py"
    script.write_text("import os, signal\nos.kill(os.getpid(), signal.SIGSEGV)\n")
    monkeypatch.setattr(sim.logio, "_MAT73_SCRIPT", script)
    _fake_h5py(monkeypatch)
    with pytest.raises(LogError, match=r"^the \.mat parser crashed on rig\.mat \(signal 11, SIGSEGV\)$"):
        read_log(_v73_file(tmp_path))


def test_a_v73_parser_that_takes_too_long_is_stopped(tmp_path, monkeypatch):
    """A parser still running after MAT73_TIMEOUT_S is killed and the file refused."""
    script = tmp_path / "hang.py"
    script.write_text("import time\ntime.sleep(60)\n")
    monkeypatch.setattr(sim.logio, "_MAT73_SCRIPT", script)
    monkeypatch.setattr(sim.logio, "MAT73_TIMEOUT_S", 0.5)
    _fake_h5py(monkeypatch)
    with pytest.raises(LogError, match=r"^the \.mat parser did not finish on rig\.mat within MAT73_TIMEOUT_S"):
        read_log(_v73_file(tmp_path))


def test_the_v73_parser_answer_cannot_run_code(tmp_path, monkeypatch):
    """Only arrays and builtins are unpickled from the parser: a pickle calling os.system is refused."""
    script = tmp_path / "evil.py"
    marker = tmp_path / "ran"
    script.write_text("import os, pickle, sys\n"
                      "class Evil:\n"
                      f"    def __reduce__(self): return (os.system, ('touch {marker}',))\n"
                      "sys.stdout.buffer.write(pickle.dumps(('ok', Evil())))\n")
    monkeypatch.setattr(sim.logio, "_MAT73_SCRIPT", script)
    _fake_h5py(monkeypatch)
    with pytest.raises(LogError, match=r"^the \.mat parser failed on rig\.mat"):
        read_log(_v73_file(tmp_path))
    assert not marker.exists()


def test_an_hdf5_file_h5py_cannot_read_is_a_logerror(tmp_path):
    """A v7.3 header followed by a broken HDF5 file: h5py's error becomes a LogError naming the file."""
    pytest.importorskip("h5py")
    with pytest.raises(LogError, match=r"^rig\.mat is not a readable MATLAB v7\.3 \(HDF5\) file: OSError"):
        read_log(_v73_file(tmp_path))


def test_a_parquet_column_name_that_is_not_utf8_is_refused(tmp_path):
    """Parquet stores names as bytes; one that is not UTF-8 is a LogError naming the file."""
    data = bytearray(write_log(small_log(n=8), tmp_path / "run.parquet").read_bytes())
    for start in range(len(data)):  # every copy of the name: in the footer and in the Arrow schema
        if data[start:start + 7] == b"current":
            data[start] = 0xFF
    (tmp_path / "run.parquet").write_bytes(bytes(data))
    with pytest.raises(LogError, match=r"^run\.parquet: a column name is not UTF-8 text"):
        read_log(tmp_path / "run.parquet")


def _varint(value: int) -> bytes:
    """Thrift's compact protocol integer (little-endian base 128)."""
    out = bytearray()
    while True:
        out.append(value & 0x7F | (0x80 if value >> 7 else 0))
        value >>= 7
        if not value:
            return bytes(out)


def test_a_parquet_footer_declaring_2_to_the_40_rows_is_refused_before_reading(tmp_path, child):
    """Every 8 (an i64 field, zigzag 16) in the footer set to 2^40: the row counts are refused up front
    (pyarrow would allocate terabytes for them, and the kernel would kill the process on first touch)."""
    data = write_log(small_log(n=8), tmp_path / "whole.parquet").read_bytes()
    length = struct.unpack("<I", data[-8:-4])[0]
    footer = data[-8 - length:-8].replace(b"\x16\x10", b"\x16" + _varint(2 ** 40 << 1))
    (tmp_path / "run.parquet").write_bytes(data[:-8 - length] + footer + struct.pack("<I", len(footer)) + b"PAR1")
    kind, text = child.read(tmp_path / "run.parquet")
    columns = len(small_log(n=8).columns)
    assert (kind, re.sub(r"\(\d.*", "", text)) == (
        "LogError", f"run.parquet: the file declares 1099511627776 rows of {columns} column(s) ")


def test_a_mat_inflating_past_a_quarter_of_the_memory_is_refused(tmp_path, monkeypatch):
    """A compressed variable of 16 MB of zeros (a few kB in the file) on a machine of 8 MB: refused while
    inflating, before scipy reads it. The content read from a .mat is at most a quarter of the memory."""
    path = tmp_path / "run.mat"
    savemat(path, {**_columns(), "zeros": np.zeros(2_000_000)}, oned_as="column", do_compression=True)
    assert path.stat().st_size < 100_000
    monkeypatch.setattr(sim.logio, "_memory_bytes", lambda: 8_000_000)
    with pytest.raises(LogError, match=r"^run\.mat: inflating the variable at byte \d+ passes the limit of "
                                       r"2000000 bytes on a file's content"):
        read_log(path)


@pytest.mark.parametrize("reader", [read_log, read_variables])
def test_a_missing_file_or_a_directory_is_refused_in_one_line_naming_it(tmp_path, reader):
    with pytest.raises(LogError, match=r"missing\.csv does not exist$"):
        reader(tmp_path / "missing.csv")
    with pytest.raises(LogError, match=r" is a directory; give a log file \(\.csv, \.parquet, \.mat, \.json\)$"):
        reader(tmp_path)
