"""Property-based fuzzing of read_log and read_mapped: a mutated log is a RunLog (a MappedRecord) or a LogError
naming its file, never another exception or a crash, and reading never changes the file. Reads run in a child
process (tests/logio_fuzzing.py), so a crash of native code fails the test instead of ending pytest. Text given
to a [log] map (expressions, units, durations, --log options) is a LogMapError or a valid map."""

import csv
import io
import warnings
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from sim.logio import LogError, read_log
from sim.logmap import LogMap, LogMapError, MappedRecord, log_map_from_dict, read_mapped, with_options
from tests.logio_fuzzing import MAPPED_TABLE, Case, ChildReader, is_fine, ops_of, run_case, write_seeds

# about 25 s in all on a 2-core machine for csv, parquet and mat; about 12 s for json and mapped
EXAMPLES = {"csv": 600, "parquet": 600, "mat": 1200, "json": 600, "mapped": 1200}
SLOW_EXAMPLES = 6000


def ops_lists(kind: str):
    return st.lists(st.tuples(st.sampled_from(ops_of(kind)), st.integers(0, 1 << 20), st.integers(0, 1 << 16),
                              st.binary(max_size=8)), min_size=1, max_size=4)


@pytest.fixture(scope="module")
def seeds(tmp_path_factory) -> dict[str, list[Path]]:
    return write_seeds(tmp_path_factory.mktemp("seeds"))


@pytest.fixture(scope="module")
def cases_dir(tmp_path_factory) -> Path:
    return tmp_path_factory.mktemp("cases")


@pytest.fixture(scope="module")
def reader():
    child = ChildReader()
    yield child
    child.close()


def check_case(fmt, seeds, cases_dir, reader, data) -> None:
    """Draw a seed of ``fmt``, a target (file or sidecar) and mutations; the outcome keeps the property."""
    seed = data.draw(st.sampled_from(seeds[fmt]), label="seed")
    sidecar = fmt == "csv" and data.draw(st.booleans(), label="mutate the sidecar")
    ops = data.draw(ops_lists(fmt), label="mutations")
    splice_from = data.draw(st.sampled_from([p for paths in seeds.values() for p in paths]), label="splice")
    kind, detail = run_case(Case(seed, sidecar, ops, fmt == "mapped"), splice_from.read_bytes(), cases_dir, reader)
    assert is_fine(kind), f"{kind}\n{detail}"


def fuzz_test(fmt: str, examples: int):
    @settings(max_examples=examples, deadline=None, derandomize=True, database=None)
    @given(data=st.data())
    def test(seeds, cases_dir, reader, data):
        check_case(fmt, seeds, cases_dir, reader, data)

    if fmt == "mapped":
        test.__doc__ = (f"{examples} mutated records of a drive in every format (deterministic), read with a fixed "
                        f"map (expressions, units, two's complement, resample, enable): each reads as a "
                        f"MappedRecord or a LogError naming its file; no other exception, no signal, no input "
                        f"changed.")
    else:
        test.__doc__ = (f"{examples} mutated {fmt} logs (deterministic): each reads as a RunLog or a LogError naming "
                        f"its file; no other exception, no signal, no input changed.")
    return test


test_mutated_csv_logs_read_as_a_runlog_or_a_logerror = fuzz_test("csv", EXAMPLES["csv"])
test_mutated_parquet_logs_read_as_a_runlog_or_a_logerror = fuzz_test("parquet", EXAMPLES["parquet"])
test_mutated_mat_logs_read_as_a_runlog_or_a_logerror = fuzz_test("mat", EXAMPLES["mat"])
test_many_mutated_csv_logs_slow = pytest.mark.slow(fuzz_test("csv", SLOW_EXAMPLES))
test_many_mutated_parquet_logs_slow = pytest.mark.slow(fuzz_test("parquet", SLOW_EXAMPLES))
test_many_mutated_mat_logs_slow = pytest.mark.slow(fuzz_test("mat", SLOW_EXAMPLES))
test_mutated_json_logs_read_as_a_runlog_or_a_logerror = fuzz_test("json", EXAMPLES["json"])
test_mutated_records_read_mapped_as_a_mapped_record_or_a_logerror = fuzz_test("mapped", EXAMPLES["mapped"])
test_many_mutated_json_logs_slow = pytest.mark.slow(fuzz_test("json", SLOW_EXAMPLES))
test_many_mutated_records_read_mapped_slow = pytest.mark.slow(fuzz_test("mapped", SLOW_EXAMPLES))


# Text a user types for a map: arbitrary text, pieces of it (names of the seeds' variables, operators, numbers,
# units, TOML), and text close to valid for the place it is given in.
PIECES = st.lists(st.sampled_from(
    ["vir", "gtau", "pwm", "en", "t", "`pos.deg`", "pos.deg", "header.", "_v0_", "ﬁ", "µ", " ", "*", "/", "+", "-",
     "(", ")", "**", "^", "²", ".", "e", "0", "1", "5", "9", "16", "ms", "s", "deg", "mN·m", "Nm", "%", "rpm", "°C",
     "`", "=", '"', "'", "{", "}", "[", "]", ",", "\n", "#", "inf", "nan", "true"]), max_size=10).map("".join)
EXPRESSIONS = st.lists(st.sampled_from(["vir", "gtau", "pwm", "en", "t", "`pos.deg`", "pos.deg", " * ", " + ",
                                        " - ", " / ", "(", ")", "2", "0.5", "1e3", "0", "-"]),
                       min_size=1, max_size=7).map("".join)
UNITS = st.lists(st.sampled_from(["ms", "s", "us", "min", "deg", "rad", "turn", "rpm", "mm", "m", "N", "mN", "Nm",
                                  "mN·m", "%", "°C", "degF", "5", "0.5", " ", "*", "/", "**2", "^-1", "²"]),
                 min_size=1, max_size=4).map("".join)
DURATIONS = st.builds("{} {}".format, st.one_of(st.floats(), st.integers(-10, 10**30)),
                      st.sampled_from(["ms", "s", "us", "min", "", "kg", "ms**2"]))
TEXT_FOR = {"expression": st.one_of(EXPRESSIONS, PIECES, st.text(max_size=40)),
            "unit": st.one_of(UNITS, PIECES, st.text(max_size=40)),
            "duration": st.one_of(DURATIONS, UNITS, PIECES, st.text(max_size=40)),
            "other": st.one_of(PIECES, EXPRESSIONS, st.text(max_size=40))}
PLACES = {"columns.q": "expression", "enable": "expression", "units.q": "unit", "resample": "duration",
          "max_gap": "duration", "option": "other"}  # a table's value, or a whole --log option
OPTION_KEYS = {"columns.q": "expression", "columns.tau_cmd": "expression", "columns.duty": "expression",
               "enable": "expression", "units.q": "unit", "units.time": "unit", "units.duty": "unit",
               "resample": "duration", "max_gap": "duration", "twos_complement.pwm": "other",
               "twos_complement.vir": "other", "interpolation": "other", "records": "other", "columns": "other",
               "units": "other", "twos_complement": "other", "colums.q": "other"}  # --log KEY=text


def map_of(where: str, text: str) -> LogMap:
    """MAPPED_TABLE with ``text`` in one place: as a table value, as a whole option or as an option's value."""
    if where in ("columns.q", "units.q"):
        table, name = where.split(".")
        return log_map_from_dict({**MAPPED_TABLE, table: {**MAPPED_TABLE[table], name: text}})
    if where in ("resample", "max_gap", "enable"):
        return log_map_from_dict({**MAPPED_TABLE, where: text})
    if where == "option":
        return log_map_from_dict(with_options(MAPPED_TABLE, [text]))
    return log_map_from_dict(with_options(MAPPED_TABLE, [f"{where.removeprefix('--log ')}={text}"]))


@settings(max_examples=600, deadline=None, derandomize=True, database=None)
@given(data=st.data())
def test_text_given_to_a_map_is_a_logmaperror_or_a_valid_map_that_reads_or_refuses_a_record(seeds, data):
    """Arbitrary text as a column expression, a unit, a duration, a whole --log option or an option's value: a
    LogMapError, or a map that saves and reads back to itself and reads a drive's record as a MappedRecord or a
    LogError naming the file; never another exception."""
    places = {**PLACES, **{f"--log {key}": kind for key, kind in OPTION_KEYS.items()}}
    where = data.draw(st.sampled_from(sorted(places)), label="where")
    text = data.draw(TEXT_FOR[places[where]], label="text")
    try:
        log_map = map_of(where, text)
    except LogMapError:
        return
    assert log_map_from_dict(log_map.to_dict()) == log_map
    path = data.draw(st.sampled_from(seeds["mapped"]), label="record")
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            record = read_mapped(path, log_map)
    except LogError as err:
        assert str(err).startswith(f"{path.name}: ") and err.path == path, str(err)
        return
    assert isinstance(record, MappedRecord) and record.logs


CELL_TEXT = st.lists(st.sampled_from(["0", "1", "9", "+", "-", ".", "e", "E", "_", " ", "\t", "inf", "nan",
                                      "Infinity", "１", "٣", "\xa0", "\u3000", "x", "0x", ",", '"']),
                     max_size=6).map("".join)


@settings(max_examples=300, deadline=None, derandomize=True, database=None)
@given(cell=CELL_TEXT)
def test_the_fast_path_accepts_exactly_the_numbers_the_cell_by_cell_path_accepts(tmp_path_factory, cell):
    """A cell read by pyarrow (the fast path) and by the cell-by-cell path (forced by trailing blank lines)
    gives the same doubles or the same LogError."""
    folder = tmp_path_factory.mktemp("cell", numbered=True)
    rows = [["time", "tau_cmd", "q"]] + [[repr(1e-3 * k), "0.5", cell if k == 2 else "0.25"] for k in range(6)]
    out = io.StringIO()
    csv.writer(out, lineterminator="\n").writerows(rows)  # quotes a cell holding ',' or '"'
    text = out.getvalue()
    outcomes = []
    for name, tail in (("fast.csv", ""), ("cells.csv", "\n\n")):
        (folder / name).write_text(text + tail, encoding="utf-8")
        try:
            outcomes.append(read_log(folder / name)["q"].view(np.uint64).tolist())
        except LogError as err:
            outcomes.append(str(err).split(": ", 1)[1])
    assert outcomes[0] == outcomes[1], (cell, outcomes)
