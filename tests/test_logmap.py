"""A drive's own record read with a [log] map (sim.logmap): every feature against a record worked out by hand.

The mapped files are written here with plain csv, json, scipy.io.savemat and pyarrow code, as a drive's own
software would write them, not with sim.logio.write_log.
"""

import csv
import dataclasses
import hashlib
import json
import math
import re
import time
import tomllib
import warnings

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest
from scipy.io import savemat

import sim.logmap
from sim.discrepancy.rig import load_rig, rig_from_dict, rig_to_toml
from sim.logio import MIN_SAMPLES, LogError, read_log
from sim.logmap import (
    MAX_BITS,
    MAX_UPSAMPLING,
    MIN_SPAN_SAMPLES,
    LogMap,
    LogMapError,
    MappedRecord,
    log_map_from_dict,
    read_mapped,
    with_options,
)
from sim.runlog import RunLog

N = 60  # samples of a record: more than MIN_SPAN_SAMPLES, so that one enabled span of all of it is kept
K = np.arange(N)


def write_csv(path, columns: dict) -> None:
    """A CSV file as a drive's software writes it: a header row, then the values with repr."""
    with path.open("w", newline="", encoding="utf-8") as fh:
        writer = csv.writer(fh, lineterminator="\n")
        writer.writerow(list(columns))
        writer.writerows(zip(*[[repr(float(v)) for v in values] for values in columns.values()], strict=True))


def write_json(path, value) -> None:
    path.write_text(json.dumps(value), encoding="utf-8")


def mapped(path, joint: str = "hinge", max_jitter: float = 0.05, **table) -> MappedRecord:
    """``path`` read with the [log] table ``table``."""
    return read_mapped(path, log_map_from_dict(table), joint=joint, max_jitter=max_jitter)


def only(record: MappedRecord) -> RunLog:
    assert len(record.logs) == 1
    return record.logs[0]


def digest(path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def base_columns(**more) -> dict:
    """time [s] at 1 kHz, tau_cmd [N·m] and q [rad] named as the run log names them, and ``more``."""
    return {"time": 1e-3 * K, "tau_cmd": 0.01 * K, "q": 0.02 * K, **more}


# ---------------------------------------------------------------------------------------------- expressions


def test_a_column_is_the_product_of_a_column_and_a_mat_scalar(tmp_path):
    """tau_cmd = vir * gtau: a .mat column times a .mat scalar (the motor's torque constant), noted with its value."""
    vir = np.linspace(-1.0, 1.0, N)
    savemat(tmp_path / "drive.mat", {"t": 1e-3 * K, "vir": vir, "gtau": 2.5, "pos": 0.1 * K}, oned_as="column")
    record = mapped(tmp_path / "drive.mat", columns={"time": "t", "tau_cmd": "vir * gtau", "q": "pos"})
    log = only(record)
    assert list(log.columns) == ["time", "tau_cmd", "q"]
    np.testing.assert_array_equal(log["tau_cmd"], vir * 2.5)
    assert log.units == {"time": "s", "tau_cmd": "N·m", "q": "rad"}
    assert "tau_cmd [N·m] = vir * gtau, gtau = 2.5" in record.notes


def test_a_number_scales_a_column(tmp_path):
    """tau_cmd = pwm * 0.00036: a PWM count scaled by a number."""
    pwm = np.arange(N) * 100.0
    write_csv(tmp_path / "drive.csv", {"time": 1e-3 * K, "pwm": pwm, "q": 0.1 * K})
    log = only(mapped(tmp_path / "drive.csv", columns={"tau_cmd": "pwm * 0.00036"}))
    np.testing.assert_array_equal(log["tau_cmd"], pwm * 0.00036)
    np.testing.assert_array_equal(log["time"], 1e-3 * K)  # taken by name: the file has 'time'


def test_a_minus_sign_flips_a_column(tmp_path):
    """q = -position: an encoder counting the other way."""
    write_csv(tmp_path / "drive.csv", {"time": 1e-3 * K, "tau_cmd": 0.01 * K, "position": 0.5 * K})
    log = only(mapped(tmp_path / "drive.csv", columns={"q": "-position"}))
    np.testing.assert_array_equal(log["q"], -0.5 * K)


def test_expressions_combine_variables_and_numbers_with_parentheses(tmp_path):
    """(a - b) / 2 + 1 and a unary plus evaluate as arithmetic does."""
    a, b = 0.3 * K, 0.1 * K**2
    write_csv(tmp_path / "drive.csv", {"time": 1e-3 * K, "a": a, "b": b})
    log = only(mapped(tmp_path / "drive.csv", columns={"tau_cmd": "(a - b) / 2 + 1", "q": "+a * -2"}))
    np.testing.assert_allclose(log["tau_cmd"], (a - b) / 2 + 1, rtol=0, atol=1e-12)
    np.testing.assert_allclose(log["q"], a * -2, rtol=0, atol=1e-12)


def test_backticked_names_with_spaces_and_brackets_are_variables(tmp_path):
    """`pos (deg)` and `tau cmd` name CSV columns that are not identifiers."""
    write_csv(tmp_path / "drive.csv", {"t [ms]": 5.0 * K, "tau cmd": 0.01 * K, "pos (deg)": 1.0 * K})
    log = only(mapped(tmp_path / "drive.csv", columns={"time": "`t [ms]`", "tau_cmd": "2 * `tau cmd`",
                                                       "q": "`pos (deg)`"}, units={"time": "ms", "q": "deg"}))
    np.testing.assert_allclose(log["time"], 5e-3 * K, rtol=1e-15)
    np.testing.assert_allclose(log["tau_cmd"], 0.02 * K, rtol=1e-15)
    np.testing.assert_allclose(log["q"], np.deg2rad(1.0 * K), rtol=1e-15)


def test_a_backticked_name_and_a_plain_name_like_its_placeholder_are_different_variables(tmp_path):
    """`a b` is replaced by an identifier while parsing; a variable of the expression spelt like it stays itself."""
    write_csv(tmp_path / "drive.csv", {"time": 1e-3 * K, "a b": 1.0 * K, "_v0_": 10.0 * K, "q": 0.1 * K})
    log = only(mapped(tmp_path / "drive.csv", columns={"tau_cmd": "`a b` + _v0_"}))
    np.testing.assert_array_equal(log["tau_cmd"], 11.0 * K)


def test_a_backticked_member_of_a_dotted_name_is_the_member_of_that_name(tmp_path):
    """header.`gear ratio`: the JSON header's member 'gear ratio'."""
    write_json(tmp_path / "drive.json", {"header": {"gear ratio": 10}, "samples": [
        {"t": 1e-3 * k, "cmd": 0.1 * k, "q": 0.2 * k} for k in range(N)]})
    log = only(mapped(tmp_path / "drive.json", columns={"time": "t", "tau_cmd": "cmd * header.`gear ratio`"}))
    np.testing.assert_allclose(log["tau_cmd"], 1.0 * K, rtol=1e-15)


def test_a_name_beyond_ascii_is_the_variable_as_written_not_its_nfkc_form(tmp_path):
    """pos_µm (micro sign) and ﬁ (a ligature): Python's parser would read them as pos_μm (Greek mu) and fi."""
    write_csv(tmp_path / "drive.csv", {"time": 1e-3 * K, "ﬁ": 0.1 * K, "pos_µm": 1.0 * K, "fi": 5.0 * K})
    log = only(mapped(tmp_path / "drive.csv", "slide", columns={"tau_cmd": "ﬁ", "q": "pos_µm"}, units={"q": "um"}))
    np.testing.assert_allclose(log["tau_cmd"], 0.1 * K, rtol=1e-15)
    np.testing.assert_allclose(log["q"], 1e-6 * K, rtol=1e-15)


@pytest.mark.parametrize("expression", ["2.5", "gtau", "gtau * 2 - 1"])
def test_an_expression_that_is_a_constant_is_refused(tmp_path, expression):
    """A number or a scalar is the same in every sample: refused, naming the column and the value."""
    savemat(tmp_path / "drive.mat", {"t": 1e-3 * K, "gtau": 2.5, "pos": 0.1 * K}, oned_as="column")
    with pytest.raises(LogError, match=rf"^drive\.mat: columns\.tau_cmd = '{re.escape(expression)}' is a constant "
                                       r"\([\d.]+\); a column needs a variable that changes"):
        mapped(tmp_path / "drive.mat", columns={"time": "t", "tau_cmd": expression, "q": "pos"})


@pytest.mark.parametrize("expression", ["a ** 2", "a % 2", "f(a)", "a[0]", "None", "True", "1j * a", "a if b else c",
                                        "`a", "a; b", "lambda: 1", "'text'", "(1).real", "a @ b", "", "0x1for", "5ms",
                                        "a" * 501])
def test_an_expression_beyond_arithmetic_of_names_and_numbers_is_refused_at_once(expression):
    """Only + - * /, parentheses, numbers and (dotted, backticked) names, at most 500 characters: anything else is
    a LogMapError naming the column, before any file is read, and without a warning of Python's parser."""
    with warnings.catch_warnings(record=True) as caught, pytest.raises(
            LogMapError, match=r"^columns\.q = .* is not an expression of variables and numbers"):
        warnings.simplefilter("always")
        log_map_from_dict({"columns": {"q": expression}})
    assert not caught, [str(w.message) for w in caught]


def test_a_missing_variable_lists_the_files_variables_with_a_did_you_mean(tmp_path):
    """A name the file lacks: the file, the name, the closest variable and all the variables."""
    write_csv(tmp_path / "drive.csv", {"time": 1e-3 * K, "tau_cmd": 0.01 * K, "position": 0.1 * K})
    with pytest.raises(LogError) as err:
        mapped(tmp_path / "drive.csv", columns={"q": "-postion"})
    assert str(err.value) == ("drive.csv: the file has no variable 'postion' (did you mean 'position'?); its "
                              "variables: time, tau_cmd, position")


def test_no_position_at_all_is_refused_naming_the_column_to_map(tmp_path):
    write_csv(tmp_path / "drive.csv", {"time": 1e-3 * K, "tau_cmd": 0.01 * K, "enc": 0.1 * K})
    with pytest.raises(LogError, match=r"^drive\.csv: no variable is mapped to 'q' \(the position, rad\) .*"
                                       r"columns\.q = \"\.\.\.\"; its variables: time, tau_cmd, enc"):
        mapped(tmp_path / "drive.csv")


# ---------------------------------------------------------------------------------------------------- units


@pytest.mark.parametrize(("joint", "column", "unit", "in_file", "si"), [
    ("hinge", "q", "deg", 90.0, math.pi / 2),
    ("hinge", "q", "turn", 0.25, math.pi / 2),
    ("hinge", "qd", "rpm", 60.0, 2 * math.pi),
    ("hinge", "qd", "deg/s", 180.0, math.pi),
    ("hinge", "tau_cmd", "mN·m", 1500.0, 1.5),
    ("hinge", "tau_cmd", "mNm", 1500.0, 1.5),
    ("hinge", "tau_cmd", "N·mm", 250.0, 0.25),
    ("hinge", "time", "ms", 5.0, 0.005),
    ("hinge", "time", "us", 250.0, 0.00025),
    ("slide", "q", "mm", 250.0, 0.25),
    ("slide", "qd", "mm/s", 40.0, 0.04),
    ("slide", "tau_cmd", "mN", 500.0, 0.5),
])
def test_a_unit_is_converted_to_the_columns_si_unit(tmp_path, joint, column, unit, in_file, si):
    """The file holds ``in_file * (1 + k)`` in ``unit``; the run log holds ``si * (1 + k)`` in its SI unit."""
    write_csv(tmp_path / "drive.csv", base_columns(x=in_file * (1 + K)))
    log = only(mapped(tmp_path / "drive.csv", joint, columns={column: "x"}, units={column: unit}))
    np.testing.assert_allclose(log[column], si * (1 + K), rtol=1e-14)
    assert log.units[column] == {"hinge": {"time": "s", "q": "rad", "qd": "rad/s", "tau_cmd": "N·m"},
                                 "slide": {"q": "m", "qd": "m/s", "tau_cmd": "N"}}[joint][column]


def test_a_temperature_in_fahrenheit_is_converted_to_celsius(tmp_path):
    """32 °F is 0 °C and 212 °F is 100 °C: an offset unit, not a scale."""
    write_csv(tmp_path / "drive.csv", base_columns(board=32.0 + 1.8 * K))
    log = only(mapped(tmp_path / "drive.csv", columns={"temperature": "board"}, units={"temperature": "degF"}))
    np.testing.assert_allclose(log["temperature"][[0, 1, 10]], [0.0, 1.0, 10.0], rtol=0, atol=1e-12)
    assert log.units["temperature"] == "°C"


def test_a_column_that_is_not_a_run_log_column_keeps_the_unit_given_such_as_percent(tmp_path):
    """duty = pwm / 10 [%]: kept as it is with its unit; without a unit it is refused, naming the key to give."""
    write_csv(tmp_path / "drive.csv", base_columns(pwm=10.0 * K))
    record = mapped(tmp_path / "drive.csv", columns={"duty": "pwm / 10"}, units={"duty": "%"})
    log = only(record)
    np.testing.assert_allclose(log["duty"], 1.0 * K, rtol=1e-15)
    assert log.units["duty"] == "%"
    assert "duty [%] = pwm / 10" in record.notes
    with pytest.raises(LogError, match=r"^drive\.csv: columns\.duty: 'duty' is not a run-log column \(time, tau_cmd, "
                                       r"q, .*\); give its unit, e\.g\. units\.duty = \"%\""):
        mapped(tmp_path / "drive.csv", columns={"duty": "pwm / 10"})


def test_a_unit_the_file_declares_is_converted_too(tmp_path):
    """A JSON 'units' member beside the records says t is in ms and pos in deg."""
    write_json(tmp_path / "drive.json", {"units": {"t": "ms", "pos": "deg"},
                                         "samples": [{"t": 5 * k, "cmd": k, "pos": 90} for k in range(N)]})
    record = mapped(tmp_path / "drive.json", columns={"time": "t", "tau_cmd": "cmd", "q": "pos"})
    log = only(record)
    np.testing.assert_allclose(log["time"], 5e-3 * K, rtol=1e-15)
    np.testing.assert_allclose(log["q"], math.pi / 2, rtol=1e-15)
    assert "time [s] = t [ms]" in record.notes and "q [rad] = pos [deg]" in record.notes


@pytest.mark.parametrize(("joint", "column", "unit", "accepted"), [
    ("hinge", "q", "%", "rad, deg, mrad, turn, arcmin"),
    ("slide", "q", "deg", "m, mm, um, cm, inch"),
    ("hinge", "tau_cmd", "N", "N·m, mN·m, kN·m, N·mm, ozf·in, lbf·ft"),
    ("slide", "tau_cmd", "N·m", "N, mN, kN, kgf, lbf"),
    ("hinge", "time", "m", "s, ms, us, ns, min"),
])
def test_a_unit_of_another_kind_is_refused_listing_the_accepted_units(tmp_path, joint, column, unit, accepted):
    write_csv(tmp_path / "drive.csv", base_columns(x=1.0 + K))
    units = {"hinge": {"q": "rad", "tau_cmd": "N·m", "time": "s"}, "slide": {"q": "m", "tau_cmd": "N"}}[joint]
    with pytest.raises(LogError) as err:
        mapped(tmp_path / "drive.csv", joint, columns={column: "x"}, units={column: unit})
    assert str(err.value) == (f"drive.csv: units.{column} = {unit!r} is not a unit of {column!r} [{units[column]}]: "
                              f"accepted are units of the same kind, e.g. {accepted}")


@pytest.mark.parametrize(("unit", "close"), [("degg", "deg"), ("rmp", "rpm"), ("Nmm", "N·mm"), ("mN-m", "mN·m")])
def test_an_unknown_unit_is_refused_with_a_did_you_mean(unit, close):
    with pytest.raises(LogMapError, match=rf"^units\.q = '{unit}' is not a unit pint knows; did you mean "
                                          rf"'{close}'\? \(e\.g\. "):
        log_map_from_dict({"units": {"q": unit}})


@pytest.mark.parametrize("text", ["9**9**9", "10**10**8 s", "((9**99)**99)**99", "10⁹⁹⁹⁹⁹⁹⁹⁹", "(m/s)**2",
                                  "m" * 101])
def test_a_unit_or_duration_with_a_huge_power_or_too_long_is_refused_at_once(text):
    """pint computes integer powers exactly: 9**9**9 would take hours. Refused before pint sees it."""
    start = time.perf_counter()
    for table, key in (({"units": {"q": text}}, "units.q"), ({"resample": text}, "resample")):
        with pytest.raises(LogMapError, match=rf"^{re.escape(key)} = .*: expected at most 100 characters, with "
                                              r"powers only of a name or a number"):
            log_map_from_dict(table)
    assert time.perf_counter() - start < 1.0


@pytest.mark.parametrize("unit", ["m/s**2", "m/s^2", "s⁻¹", "kg*m**2", "m**(2)", "1/s"])
def test_units_with_small_powers_are_accepted(unit):
    assert log_map_from_dict({"units": {"x": unit}}).units == {"x": unit}


# ------------------------------------------------------------------------------------------- two's complement


def test_a_16_bit_twos_complement_count_reads_as_signed(tmp_path):
    """65535 -> -1, 32768 -> -32768, 32767 and 885 stay; applied before the scale of the expression."""
    counts = np.resize([0.0, 885.0, 65535.0, 32768.0, 32767.0, 65000.0], N)
    write_csv(tmp_path / "drive.csv", base_columns(pwm=counts))
    record = mapped(tmp_path / "drive.csv", columns={"tau_cmd": "pwm * 0.001"}, twos_complement={"pwm": 16})
    signed = np.resize([0.0, 885.0, -1.0, -32768.0, 32767.0, -536.0], N)
    np.testing.assert_allclose(only(record)["tau_cmd"], signed * 0.001, rtol=1e-15)


def test_a_twos_complement_mat_scalar_and_integer_array_read_as_signed(tmp_path):
    """A uint8 array and a scalar, 8 bits: 255 -> -1, 128 -> -128."""
    savemat(tmp_path / "drive.mat", {"t": 1e-3 * K, "raw": np.resize(np.array([1, 255, 128, 127], np.uint8), N),
                                     "offset": 255, "pos": 0.1 * K}, oned_as="column")
    log = only(mapped(tmp_path / "drive.mat", columns={"time": "t", "tau_cmd": "raw + offset", "q": "pos"},
                      twos_complement={"raw": 8, "offset": 8}))
    np.testing.assert_array_equal(log["tau_cmd"], np.resize([0.0, -2.0, -129.0, 126.0], N))


def test_the_widest_twos_complement_is_exact_in_a_float64(tmp_path):
    """MAX_BITS = 53: 2**53 - 1 is -1 exactly; wider counts could not be told apart as floats and are refused."""
    assert MAX_BITS == 53
    savemat(tmp_path / "drive.mat", {"t": 1e-3 * K, "c": np.resize(np.array([2**53 - 1, 2**52, 5], np.int64), N),
                                     "pos": 0.1 * K}, oned_as="column")
    log = only(mapped(tmp_path / "drive.mat", columns={"time": "t", "tau_cmd": "c", "q": "pos"},
                      twos_complement={"c": 53}))
    np.testing.assert_array_equal(log["tau_cmd"][:3], [-1.0, -(2.0**52), 5.0])
    for bits in (1, 54, 64):
        with pytest.raises(LogMapError, match=rf"^twos_complement\.c = {bits}: valid range \[2, 53\] bits"):
            log_map_from_dict({"twos_complement": {"c": bits}})


@pytest.mark.parametrize("bad", [1.5, 65536.0, -1.0, math.nan])
def test_twos_complement_refuses_a_count_that_is_not_an_unsigned_integer_naming_variable_and_row(tmp_path, bad):
    """Sample 4 (row 5) holds ``bad``; the message names the file, the variable, the row and the key."""
    counts = np.full(N, 7.0)
    counts[3] = bad
    write_csv(tmp_path / "drive.csv", base_columns(pwm=counts))
    with pytest.raises(LogError) as err:
        mapped(tmp_path / "drive.csv", columns={"tau_cmd": "pwm"}, twos_complement={"pwm": 16})
    assert str(err.value) == (f"drive.csv: variable 'pwm', row 5: {bad:.6g} is not an unsigned 16-bit count (an "
                              f"integer from 0 to 65535), as twos_complement.pwm = 16 says")
    assert (err.value.column, err.value.row) == ("pwm", 5)


def test_twos_complement_of_a_variable_the_file_lacks_is_refused_with_a_did_you_mean(tmp_path):
    write_csv(tmp_path / "drive.csv", base_columns(pwm=1.0 * K))
    with pytest.raises(LogError, match=r"^drive\.csv: twos_complement\.pmw: the file has no variable 'pmw'; its "
                                       r"variables: time, tau_cmd, q, pwm \(did you mean 'pwm'\?\)"):
        mapped(tmp_path / "drive.csv", twos_complement={"pmw": 16})


# -------------------------------------------------------------------------------------------------- JSON


def records(n: int = N) -> list[dict]:
    """Records of a drive: t [ms], a command, a nested position, flags."""
    return [{"t": 5 * k, "cmd": 0.1 * k, "pos": {"x": 0.01 * k, "y": 1}, "on": True} for k in range(n)]


def test_json_records_as_a_list(tmp_path):
    """A list of objects; a nested member is named with a dot (pos.x)."""
    write_json(tmp_path / "drive.json", records())
    log = only(mapped(tmp_path / "drive.json", columns={"time": "t", "tau_cmd": "cmd", "q": "pos.x"},
                      units={"time": "ms"}))
    np.testing.assert_allclose(log["time"], 5e-3 * K, rtol=1e-15)
    np.testing.assert_allclose(log["tau_cmd"], 0.1 * K, rtol=1e-15)
    np.testing.assert_allclose(log["q"], 0.01 * K, rtol=1e-15)


def test_json_records_under_a_key_with_a_header_usable_in_expressions(tmp_path):
    """The records are found as the one list of objects; the header's members are variables (header.mass)."""
    write_json(tmp_path / "drive.json", {"header": {"mass": 2.0, "gear": {"ratio": 10}, "drive": "X1"},
                                         "samples": records()})
    record = mapped(tmp_path / "drive.json", columns={"time": "t", "tau_cmd": "cmd * header.mass",
                                                      "q": "pos.x / header.gear.ratio"}, units={"time": "ms"})
    log = only(record)
    np.testing.assert_allclose(log["tau_cmd"], 0.2 * K, rtol=1e-15)
    np.testing.assert_allclose(log["q"], 0.001 * K, rtol=1e-15)
    assert "tau_cmd [N·m] = cmd * header.mass, header.mass = 2" in record.notes


def test_json_with_several_lists_of_records_needs_records_to_name_one(tmp_path):
    """Two lists of objects: refused naming both; records = "samples" reads that one; a wrong name lists them."""
    write_json(tmp_path / "drive.json", {"header": {"mass": 2.0}, "samples": records(),
                                         "events": [{"t": 0, "what": "start"}]})
    table = {"columns": {"time": "t", "tau_cmd": "cmd", "q": "pos.x"}, "units": {"time": "ms"}}
    with pytest.raises(LogError, match=r"^drive\.json: the file has 2 lists of records \('samples', 'events'\); name "
                                       r"the one to read \(records = \"\.\.\.\" in the rig's \[log\] table\)"):
        mapped(tmp_path / "drive.json", **table)
    assert len(only(mapped(tmp_path / "drive.json", records="samples", **table))) == N
    with pytest.raises(LogError, match=r"^drive\.json: records = 'sample': the file has no list of records of that "
                                       r"name; its members: 'header' \(a dict\), 'samples' \(a list of records\), "
                                       r"'events' \(a list of records\)"):
        mapped(tmp_path / "drive.json", records="sample", **table)


def test_records_names_a_member_of_json_only(tmp_path):
    write_csv(tmp_path / "drive.csv", base_columns())
    with pytest.raises(LogError, match=r"^drive\.csv: records = 'samples' names a member of a JSON log; drive\.csv "
                                       r"is not JSON"):
        mapped(tmp_path / "drive.csv", records="samples")


def test_a_json_object_of_columns(tmp_path):
    """An object of equal-length lists of numbers; a number beside them is a scalar variable."""
    write_json(tmp_path / "drive.json", {"t": (1e-3 * K).tolist(), "i": (0.5 * K).tolist(), "q": (0.2 * K).tolist(),
                                         "kt": 0.08})
    log = only(mapped(tmp_path / "drive.json", columns={"time": "t", "tau_cmd": "i * kt"}))
    np.testing.assert_allclose(log["tau_cmd"], 0.04 * K, rtol=1e-15)
    np.testing.assert_array_equal(log["q"], 0.2 * K)


def test_a_json_record_lacking_a_field_is_refused_naming_variable_and_row(tmp_path):
    rows = records()
    del rows[7]["cmd"]
    write_json(tmp_path / "drive.json", rows)
    with pytest.raises(LogError, match=r"^drive\.json: variable 'cmd', row 9: empty$"):
        mapped(tmp_path / "drive.json", columns={"time": "t", "tau_cmd": "cmd", "q": "pos.x"}, units={"time": "ms"})


def test_a_header_number_named_like_a_run_log_column_is_not_taken_as_a_column(tmp_path):
    """A JSON header's 'temperature' (the room's) and a .mat scalar 'temperature' are one value, not a column."""
    write_json(tmp_path / "drive.json", {"temperature": 22.5, "time": "2024-05-01T12:00", "samples": [
        {"t": 0.001 * k, "tau_cmd": 0.1 * k, "q": 0.2 * k} for k in range(N)]})
    log = only(mapped(tmp_path / "drive.json", columns={"time": "t"}))
    assert list(log.columns) == ["time", "tau_cmd", "q"]
    savemat(tmp_path / "drive.mat", {**base_columns(), "temperature": 21.0}, oned_as="column")
    assert list(only(mapped(tmp_path / "drive.mat")).columns) == ["time", "tau_cmd", "q"]


@pytest.mark.parametrize(("value", "expected"), [
    (np.array(2.5), 2.5), (np.float32(2.5), 2.5), (np.int64(3), 3.0), (np.array(True), 1.0), (np.bool_(True), 1.0),
    (np.array("abc"), "variable 'gain' is text, not a number or a column of numbers"),
    (np.str_("abc"), "variable 'gain' is text, not a number or a column of numbers"),
    (np.array(None, dtype=object), "variable 'gain' is empty, not a number or a column of numbers"),
    (np.array(1 + 2j), "variable 'gain' is complex, not a number or a column of numbers"),
    (np.array([], dtype=object), "variable 'gain' is empty, not a number or a column of numbers"),
    (np.zeros((2, 3)), "variable 'gain' has shape (2, 3); a column is a vector"),
])
def test_a_scalar_of_any_kind_a_reader_gives_is_a_number_or_a_logerror(tmp_path, monkeypatch, value, expected):
    """What a reader can give for a scalar variable (a v7.3 .mat's scalar dataset is a 0-d array, h5py's numbers
    are NumPy scalars): a number used in the expression, or a LogError naming the file and the variable."""
    savemat(tmp_path / "drive.mat", base_columns(), oned_as="column")
    found = sim.logmap.read_variables(tmp_path / "drive.mat")
    monkeypatch.setattr(sim.logmap, "read_variables", lambda path, records=None: dataclasses.replace(
        found, values={**found.values, "gain": value}))
    if isinstance(expected, float):
        log = only(mapped(tmp_path / "drive.mat", columns={"tau_cmd": "tau_cmd * gain"}))
        np.testing.assert_array_equal(log["tau_cmd"], 0.01 * K * expected)
    else:
        with pytest.raises(LogError) as err:
            mapped(tmp_path / "drive.mat", columns={"tau_cmd": "tau_cmd * gain"})
        assert str(err.value) == f"drive.mat: {expected}"


def test_read_log_reads_a_json_run_log_as_a_list_or_under_a_key_with_units_and_meta(tmp_path):
    """read_log: a list of records; records beside 'units' and other members, which become the meta."""
    rows = [{"time": 1e-3 * k, "tau_cmd": 0.1 * k, "q": 0.2 * k, "current": 0.3 * k} for k in range(20)]
    write_json(tmp_path / "list.json", rows)
    with pytest.warns(UserWarning, match="'current' are not in the format and have no unit"):
        log = read_log(tmp_path / "list.json")
    assert list(log.columns) == ["time", "tau_cmd", "q", "current"] and log.meta == {}
    write_json(tmp_path / "keyed.json", {"units": {"current": "A"}, "fixture": "locked", "records": rows})
    log = read_log(tmp_path / "keyed.json")
    assert log.units["current"] == "A" and log.meta == {"fixture": "locked"}
    np.testing.assert_array_equal(log["q"], [0.2 * k for k in range(20)])
    write_json(tmp_path / "deg.json", {"units": {"q": "deg"}, "records": rows})
    with pytest.raises(LogError, match=r"^deg\.json: column 'q' is in 'deg' according to the member 'units' beside "
                                       r"the records; the format fixes 'rad'"):
        read_log(tmp_path / "deg.json")


def test_a_parquet_record_maps_like_the_others(tmp_path):
    """A Parquet file with int32 counts and a position in degrees."""
    pq.write_table(pa.table({"ts_us": pa.array((1000 * K).astype(np.int64)),
                             "cnt": pa.array(np.resize([0, 65535, 2], N).astype(np.int32)),
                             "deg": pa.array(1.0 * K)}), tmp_path / "drive.parquet")
    log = only(mapped(tmp_path / "drive.parquet", columns={"time": "ts_us", "tau_cmd": "cnt / 100", "q": "deg"},
                      units={"time": "us", "q": "deg"}, twos_complement={"cnt": 16}))
    np.testing.assert_allclose(log["time"], 1e-3 * K, rtol=1e-15)
    np.testing.assert_array_equal(log["tau_cmd"][:3], [0.0, -0.01, 0.02])
    np.testing.assert_allclose(log["q"], np.deg2rad(1.0 * K), rtol=1e-15)


# ------------------------------------------------------------------------------------------------ resampling


def jittery_time(n: int = N, step: float = 5e-3, seed: int = 3) -> np.ndarray:
    """Steps of ``step`` +- 30 %, from 0.1 s."""
    rng = np.random.default_rng(seed)
    return 0.1 + np.concatenate(([0.0], np.cumsum(step * (1 + rng.uniform(-0.3, 0.3, n - 1)))))


def test_resample_linear_puts_the_record_on_a_5_ms_grid_as_np_interp_does(tmp_path):
    t = jittery_time()
    cmd, pos = np.sin(20 * t), np.cos(15 * t)
    write_csv(tmp_path / "drive.csv", {"time": t, "tau_cmd": cmd, "q": pos})
    log = only(mapped(tmp_path / "drive.csv", resample="5 ms"))
    count = int(math.floor((t[-1] - t[0]) / 5e-3 * (1 + 1e-12))) + 1
    grid = t[0] + 5e-3 * np.arange(count)
    np.testing.assert_array_equal(log["time"], grid)
    np.testing.assert_array_equal(log["tau_cmd"], np.interp(grid, t, cmd))
    np.testing.assert_array_equal(log["q"], np.interp(grid, t, pos))


def test_resample_previous_holds_each_sample_until_the_next(tmp_path):
    """Samples at 0, 4, 11, 15, 20 ms on a 5 ms grid: 0 ms <- 0, 5 <- 4, 10 <- 4, 15 <- 15, 20 <- 20."""
    t = np.array([0.0, 4.0, 11.0, 15.0, 20.0]) * 1e-3
    write_csv(tmp_path / "drive.csv", {"time": t, "tau_cmd": [1.0, 2.0, 3.0, 4.0, 5.0], "q": [10.0, 20, 30, 40, 50]})
    log = only(mapped(tmp_path / "drive.csv", resample="5 ms", interpolation="previous"))
    np.testing.assert_allclose(log["time"], [0.0, 0.005, 0.01, 0.015, 0.02], rtol=0, atol=1e-15)
    np.testing.assert_array_equal(log["tau_cmd"], [1.0, 2.0, 2.0, 4.0, 5.0])
    np.testing.assert_array_equal(log["q"], [10.0, 20.0, 20.0, 40.0, 50.0])
    linear = only(mapped(tmp_path / "drive.csv", resample="5 ms"))
    np.testing.assert_allclose(linear["tau_cmd"], [1.0, 2 + 1 / 7, 2 + 6 / 7, 4.0, 5.0], rtol=1e-12)


def test_resample_reports_the_jitter_it_found_in_the_notes(tmp_path):
    """Steps of 4, 7, 4, 5 ms: median 4.5 ms, jitter up to |7 - 4.5| / 4.5 = 55.6 %."""
    t = np.array([0.0, 4.0, 11.0, 15.0, 20.0]) * 1e-3
    write_csv(tmp_path / "drive.csv", {"time": t, "tau_cmd": 1.0 + t, "q": 2.0 + t})
    record = mapped(tmp_path / "drive.csv", resample="5 ms")
    assert record.notes[-1] == ("resampled to a 5 ms grid by linear interpolation: 5 samples over 0.02 s became 5; "
                                "median step 4.5 ms, steps 4-7 ms (jitter up to 55.6 %), no gap above max_gap = 25 ms")


def test_a_gap_longer_than_max_gap_is_refused_naming_the_row(tmp_path):
    """A 60 ms gap before sample 31 (row 32): refused at the default of 5 steps (25 ms), accepted at max_gap 100 ms."""
    t = 5e-3 * K
    t[30:] += 0.055
    write_csv(tmp_path / "drive.csv", {"time": t, "tau_cmd": 1.0 + t, "q": 2.0 + t})
    with pytest.raises(LogError) as err:
        mapped(tmp_path / "drive.csv", resample="5 ms")
    assert str(err.value) == ("drive.csv: column 'time', row 32: a gap of 60 ms after 0.145 s, longer than max_gap = "
                              "25 ms (1 such gap(s)); cut the record there or raise max_gap")
    assert err.value.row == 32
    with pytest.raises(LogError, match=r"row 32: a gap of 60 ms .* longer than max_gap = 50 ms"):
        mapped(tmp_path / "drive.csv", resample="5 ms", max_gap="50 ms")
    assert len(only(mapped(tmp_path / "drive.csv", resample="5 ms", max_gap="100 ms"))) == N + 11


def test_a_jittery_record_without_resample_is_refused_with_a_hint_to_resample(tmp_path):
    write_csv(tmp_path / "drive.csv", {"time": jittery_time(), "tau_cmd": 0.1 * K, "q": 0.2 * K})
    with pytest.raises(LogError, match=r"^drive\.csv: column 'time', row \d+: the step .* max_jitter = 5 % .*; a "
                                       r"record sampled irregularly can be put on a uniform grid with --log "
                                       r"resample=STEP \(or resample in the rig's \[log\] table\)$"):
        mapped(tmp_path / "drive.csv")
    assert len(only(mapped(tmp_path / "drive.csv", max_jitter=math.inf))) == N


def test_a_resample_step_leaving_fewer_than_min_samples_is_refused(tmp_path):
    """60 samples over 59 ms on a 1 s grid would be one sample: refused, not a log of one row."""
    write_csv(tmp_path / "drive.csv", base_columns())
    with pytest.raises(LogError, match=rf"^drive\.csv: resample = 1000 ms would make 1 sample\(s\) of the record's 60 "
                                       rf"over 0\.059 s; a grid needs at least {MIN_SAMPLES} samples and at most "
                                       rf"{MAX_UPSAMPLING} times the record's: choose a step near its median step, "
                                       rf"1 ms"):
        mapped(tmp_path / "drive.csv", resample="1 s", max_gap="2 s")


def test_a_resample_step_far_finer_than_the_record_is_refused_before_allocating(tmp_path):
    """1e-300 s would be a grid of 6e297 samples, 5e-324 s one of more than a float counts; 1 us (59001 samples of
    60) is past MAX_UPSAMPLING too."""
    write_csv(tmp_path / "drive.csv", base_columns())
    for step in ("1e-300 s", "5e-324 s", "1 us"):
        with pytest.raises(LogError, match=rf"^drive\.csv: resample = .* ms would make .* sample\(s\) of the "
                                           rf"record's 60 .* at most {MAX_UPSAMPLING} times the record's"):
            mapped(tmp_path / "drive.csv", resample=step, max_gap="1 s")


def test_resampling_refuses_a_time_that_does_not_increase_naming_the_row(tmp_path):
    t = 5e-3 * K
    t[20] = t[19]
    write_csv(tmp_path / "drive.csv", {"time": t, "tau_cmd": 0.1 * K, "q": 0.2 * K})
    with pytest.raises(LogError, match=r"^drive\.csv: column 'time', row 22: 0\.095 s does not exceed 0\.095 s"):
        mapped(tmp_path / "drive.csv", resample="5 ms")


# ---------------------------------------------------------------------------------------------------- enable


def enable_record(path, on: np.ndarray, t: np.ndarray | None = None) -> None:
    n = len(on)
    t = 1e-3 * np.arange(n) if t is None else t
    write_csv(path, {"time": t, "tau_cmd": 0.1 * np.arange(n), "q": 0.2 * np.arange(n), "torque_enable": on})


def test_enable_cuts_the_record_to_the_span_where_it_is_nonzero(tmp_path):
    """Off for 10 samples, on for 70, off for 20: one log of samples 10-79 (rows 12-81)."""
    on = np.r_[np.zeros(10), np.ones(70), np.zeros(20)]
    enable_record(tmp_path / "drive.csv", on)
    record = mapped(tmp_path / "drive.csv", enable="torque_enable")
    log = only(record)
    np.testing.assert_array_equal(log["tau_cmd"], 0.1 * np.arange(10, 80))
    assert record.notes[-1] == ("enable = torque_enable: 1 span(s) kept, rows 12-81 (0.01-0.079 s); 30 of 100 "
                                "samples left out where it is 0")
    assert log.meta["mapping"]["span"] == 1 and log.meta["mapping"]["spans"] == 1


def test_enable_splits_the_record_into_two_logs(tmp_path):
    on = np.r_[np.ones(60), np.zeros(5), np.full(55, 2.0)]  # any nonzero value is on
    enable_record(tmp_path / "drive.csv", on)
    record = mapped(tmp_path / "drive.csv", enable="torque_enable")
    assert [len(log) for log in record.logs] == [60, 55]
    np.testing.assert_array_equal(record.logs[1]["time"], 1e-3 * np.arange(65, 120))
    assert [log.meta["mapping"]["span"] for log in record.logs] == [1, 2]
    assert "2 span(s) kept, rows 2-61 (0-0.059 s), rows 67-121 (0.065-0.119 s)" in record.notes[-1]


def test_the_analysis_names_a_sample_of_a_later_span_by_its_row_in_the_file(tmp_path):
    """Span 2 starts at row 67: its sample 10 is row 77 of the file; a resampled record is named by its time."""
    from sim.discrepancy.checks import located

    enable_record(tmp_path / "drive.csv", np.r_[np.ones(60), np.zeros(5), np.ones(55)])
    record = mapped(tmp_path / "drive.csv", enable="torque_enable")
    assert located(record.logs[1], 10) == ("row 77", 77) and located(record.logs[0], 10) == ("row 12", 12)
    resampled = mapped(tmp_path / "drive.csv", enable="torque_enable", resample="2 ms")
    assert located(resampled.logs[1], 5) == ("at t = 0.075 s (the record resampled to 2 ms)", None)
    write_csv(tmp_path / "plain.csv", {"time": 1e-3 * np.arange(5), "tau_cmd": np.zeros(5), "q": np.zeros(5)})
    assert located(read_log(tmp_path / "plain.csv"), 3) == ("row 5", 5)


def test_enabled_spans_shorter_than_min_span_samples_are_left_out_and_named(tmp_path):
    on = np.r_[np.ones(12), np.zeros(3), np.ones(60), np.zeros(3), np.ones(5)]
    enable_record(tmp_path / "drive.csv", on)
    record = mapped(tmp_path / "drive.csv", enable="torque_enable")
    assert len(only(record)) == 60
    assert record.notes[-1].endswith(f"2 enabled span(s) shorter than {MIN_SPAN_SAMPLES} "
                                     f"samples left out: rows 2-13 (0-0.011 s), rows 80-84 (0.078-0.082 s)")


def test_a_record_never_enabled_long_enough_is_refused(tmp_path):
    enable_record(tmp_path / "off.csv", np.zeros(100))
    with pytest.raises(LogError, match=r"^off\.csv: enable = 'torque_enable': the torque is never enabled long enough "
                                       r"to analyse: it is 0 in all 100 samples$"):
        mapped(tmp_path / "off.csv", enable="torque_enable")
    enable_record(tmp_path / "short.csv", np.r_[np.zeros(50), np.ones(20), np.zeros(30)])
    with pytest.raises(LogError, match=r"^short\.csv: .* it is nonzero only in rows 52-71 \(0\.05-0\.069 s\), each "
                                       r"shorter than 50 samples$"):
        mapped(tmp_path / "short.csv", enable="torque_enable")


def test_enable_may_be_an_expression(tmp_path):
    """enable = "mode - 3": on where mode is not 3."""
    on = np.r_[np.full(10, 3.0), np.full(60, 8.0), np.full(10, 3.0)]
    enable_record(tmp_path / "drive.csv", on)
    assert len(only(mapped(tmp_path / "drive.csv", enable="torque_enable - 3"))) == 60


def test_an_error_in_a_later_span_names_the_files_row(tmp_path):
    """A jittery step inside the second span (sample 100, row 102) is named by its row in the file."""
    t = 1e-3 * np.arange(130)
    t[100:] += 0.0004
    enable_record(tmp_path / "drive.csv", np.r_[np.ones(60), np.zeros(10), np.ones(60)], t)
    with pytest.raises(LogError, match=r"^drive\.csv: column 'time', row 102: the step 0\.0014 s from row 101 "
                                       r"deviates 40 % .* at rows 102\)") as err:
        mapped(tmp_path / "drive.csv", enable="torque_enable")
    assert err.value.row == 102


# ---------------------------------------------------------------------------------------- the files are only read


def test_the_input_files_are_unchanged_and_nothing_is_written_beside_them(tmp_path):
    """A read of each format, one refused too: the folder holds the same files with the same bytes after."""
    savemat(tmp_path / "a.mat", {"t": 1e-3 * K, "vir": 0.1 * K, "gtau": 2.0, "pos": 0.1 * K}, oned_as="column")
    write_csv(tmp_path / "b.csv", {"time": jittery_time(), "tau_cmd": 0.1 * K, "q": 0.2 * K})
    (tmp_path / "b.units.json").write_text('{"q": "deg"}', encoding="utf-8")
    write_json(tmp_path / "c.json", {"header": {"mass": 2.0}, "samples": records()})
    pq.write_table(pa.table(base_columns()), tmp_path / "d.parquet")
    before = {path.name: (digest(path), path.stat().st_mtime_ns) for path in tmp_path.iterdir()}
    mapped(tmp_path / "a.mat", columns={"time": "t", "tau_cmd": "vir * gtau", "q": "pos"})
    mapped(tmp_path / "b.csv", resample="5 ms")
    with pytest.raises(LogError):
        mapped(tmp_path / "b.csv")
    mapped(tmp_path / "c.json", columns={"time": "t", "tau_cmd": "cmd * header.mass", "q": "pos.x"},
           units={"time": "ms"})
    mapped(tmp_path / "d.parquet", enable="q")
    assert {path.name: (digest(path), path.stat().st_mtime_ns) for path in tmp_path.iterdir()} == before


# --------------------------------------------------------------------------------------- the table and options


TABLE = {"columns": {"time": "t", "tau_cmd": "vir * gtau", "q": "-`pos (deg)`"}, "units": {"q": "deg", "time": "ms"},
         "twos_complement": {"pwm": 16, "a.b": 8}, "records": "samples", "resample": "5 ms",
         "interpolation": "previous", "max_gap": "50 ms", "enable": "torque_enable"}


def test_log_map_from_dict_reads_every_key():
    assert log_map_from_dict(TABLE) == LogMap(
        columns={"time": "t", "tau_cmd": "vir * gtau", "q": "-`pos (deg)`"}, units={"q": "deg", "time": "ms"},
        twos_complement={"pwm": 16, "a.b": 8}, records="samples", resample_s=0.005, interpolation="previous",
        max_gap_s=0.05, enable="torque_enable")


@pytest.mark.parametrize(("table", "message"), [
    ({"colums": {}}, r"^\[log\] has no key 'colums' \(did you mean 'columns'\?\); valid keys: columns, units"),
    ({"columns": {"q": 1.5}}, r"^columns\.q = 1\.5: expected text"),
    ({"units": "deg"}, r"^units = 'deg': expected a table of names to strings"),
    ({"twos_complement": {"pwm": 16.0}}, r"^twos_complement = .*: expected a table of variable = bits"),
    ({"interpolation": "cubic", "resample": "5 ms"}, r"^interpolation = 'cubic': valid values are 'linear', "),
    ({"interpolation": "linear"}, r"^interpolation is given without resample"),
    ({"resample": "5 kg"}, r"^resample = '5 kg' is not a duration \(DimensionalityError\); e\.g\. \"5 ms\""),
    ({"resample": "-5 ms"}, r"^resample = '-5 ms': a duration must be positive and finite"),
    ({"max_gap": 10**400}, r"^max_gap = 1000.*: a duration must be positive and finite"),
    ({"resample": True}, r"^resample = True: expected a duration"),
    ({"enable": ""}, r"^enable = '': expected a name"),
    ({"records": 3}, r"^records = 3: expected a name"),
])
def test_a_bad_table_is_refused_naming_the_key(table, message):
    with pytest.raises(LogMapError, match=message):
        log_map_from_dict(table)


def test_to_dict_round_trips_through_log_map_from_dict():
    log_map = log_map_from_dict(TABLE)
    assert log_map_from_dict(log_map.to_dict()) == log_map
    assert log_map.to_dict()["resample"] == "0.005 s"
    assert log_map_from_dict(LogMap().to_dict()) == LogMap()


def test_with_options_overrides_a_table_value_and_adds_members():
    table = with_options(TABLE, ["columns.tau_cmd=vir * 3", "units.qd=rpm", "enable=en", "interpolation=linear"])
    log_map = log_map_from_dict(table)
    assert log_map.columns == {"time": "t", "tau_cmd": "vir * 3", "q": "-`pos (deg)`"}
    assert log_map.units == {"q": "deg", "time": "ms", "qd": "rpm"}
    assert (log_map.enable, log_map.interpolation) == ("en", "linear")
    assert TABLE["columns"]["tau_cmd"] == "vir * gtau"  # the table given is not changed


@pytest.mark.parametrize(("option", "key", "value"), [
    ("twos_complement.pwm=16", "twos_complement", {"pwm": 16}),
    ("resample=5 ms", "resample", "5 ms"),
    ('resample="5 ms"', "resample", "5 ms"),
    ("resample=0.002", "resample", 0.002),
    ("columns.q=-`pos (deg)`", "columns", {"q": "-`pos (deg)`"}),
    ("columns.q = 'a b' ", "columns", {"q": "a b"}),
    ("records=samples", "records", "samples"),
    ("max_gap=1\nx = 2", "max_gap", "1\nx = 2"),  # text, not a TOML document of two keys
    ("resample=" + "[" * 3000, "resample", "[" * 3000),  # nested too deep for TOML: text
    ("resample=" + "9" * 5000, "resample", "9" * 5000),  # too many digits for an int: text
])
def test_with_options_reads_toml_values_and_takes_anything_else_as_text(option, key, value):
    assert with_options({}, [option])[key] == value


def test_with_options_values_become_a_valid_map():
    log_map = log_map_from_dict(with_options({}, ["twos_complement.pwm=16", "resample=5 ms", "max_gap=0.1"]))
    assert (log_map.twos_complement, log_map.resample_s, log_map.max_gap_s) == ({"pwm": 16}, 0.005, 0.1)


@pytest.mark.parametrize(("options", "message"), [
    (["resample"], r"^'resample': expected KEY=VALUE"),
    (["=5"], r"^'=5': expected KEY=VALUE"),
    (["enable.x=1"], r"^'enable\.x=1': 'enable' has no members; tables: columns, units, twos_complement"),
    (["column.q=x"], r"^'column\.q=x': 'column' has no members \(did you mean 'columns'\?\)"),
    (["columns=1", "columns.q=x"], r"^'columns\.q=x': columns = '1' is not a table to set a member of"),
])
def test_with_options_refuses_what_is_not_key_equals_value(options, message):
    with pytest.raises(LogMapError, match=message):
        with_options({}, options)


@pytest.mark.parametrize(("text", "seconds"), [("5 ms", 0.005), ("0.5 s", 0.5), ("250 us", 0.00025),
                                               ("2 min", 120.0), ("1/200 s", 0.005), (0.01, 0.01), (1, 1.0)])
def test_a_duration_is_text_with_a_unit_or_a_number_of_seconds(text, seconds):
    assert log_map_from_dict({"resample": text}).resample_s == pytest.approx(seconds, rel=1e-15)


def test_a_rig_with_a_log_table_is_saved_and_loaded_with_the_same_map(tmp_path):
    """rig_to_toml writes the [log] table; load_rig and rig_from_dict read it back to the same LogMap."""
    rig = rig_from_dict({"model": "rigid-joint", "joint": "hinge", "inertia_kgm2": 0.01, "effort_gain": 1.0,
                         "log": TABLE})
    assert rig.log_map == log_map_from_dict(TABLE)
    text = rig_to_toml(rig)
    assert "\n[log]\n" in text
    assert tomllib.loads(text)["log"]["columns"]["q"] == "-`pos (deg)`"
    (tmp_path / "rig.toml").write_text(text, encoding="utf-8")
    assert load_rig(tmp_path / "rig.toml").log_map == rig.log_map
    assert rig_from_dict(tomllib.loads(text)).log_map == rig.log_map


def test_a_rig_log_table_read_with_options_maps_a_record(tmp_path):
    """The CLI's path: the rig's table, options laid over it, then the record read."""
    savemat(tmp_path / "drive.mat", {"t": 1e-3 * K, "vir": 0.1 * K, "gtau": 2.0, "pos": 1.0 * K}, oned_as="column")
    (tmp_path / "rig.toml").write_text('model = "rigid-joint"\njoint = "hinge"\ninertia_kgm2 = 0.01\n'
                                       'effort_gain = 1.0\n\n[log]\ncolumns = {time = "t", tau_cmd = "vir * gtau", '
                                       'q = "pos"}\nunits = {q = "deg"}\n', encoding="utf-8")
    rig = load_rig(tmp_path / "rig.toml")
    log_map = log_map_from_dict(with_options(rig.log_map.to_dict(), ["columns.tau_cmd=vir * gtau * 2"]))
    log = only(read_mapped(tmp_path / "drive.mat", log_map))
    np.testing.assert_allclose(log["tau_cmd"], 0.4 * K, rtol=1e-15)
    np.testing.assert_allclose(log["q"], np.deg2rad(K), rtol=1e-15)


def test_command_line_values_of_name_keys_stay_text_where_toml_would_read_another_type():
    """--log enable=true or records=2024 name variables, as typed; numbers only where the key takes one."""
    table = with_options({}, ["enable=true", "records=2024", "columns.q=inf", "twos_complement.pwm=16",
                              "resample=0.005"])
    assert table == {"enable": "true", "records": "2024", "columns": {"q": "inf"}, "twos_complement": {"pwm": 16},
                     "resample": 0.005}
    assert log_map_from_dict(table).resample_s == 0.005


def test_a_rig_whose_log_expressions_hold_newlines_and_quotes_is_saved_so_that_it_loads_again():
    rig = rig_from_dict({"model": "rigid-joint", "joint": "hinge", "inertia_kgm2": 0.01, "effort_gain": 1.0,
                         "log": {"columns": {"tau_cmd": "(`a \"b\"`\n+ c)", "time": "`t\\\\s`"}}})
    assert rig_from_dict(tomllib.loads(rig_to_toml(rig))).log_map == rig.log_map
