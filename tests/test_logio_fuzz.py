"""Property-based fuzzing of read_log: a mutated log is a RunLog or a LogError naming its file, never another
exception or a crash, and reading never changes the file. Reads run in a child process (tests/logio_fuzzing.py),
so a crash of native code fails the test instead of ending pytest."""

import csv
import io
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from sim.logio import LogError, read_log
from tests.logio_fuzzing import OPS, Case, ChildReader, is_fine, run_case, write_seeds

EXAMPLES = {"csv": 600, "parquet": 600, "mat": 1200}  # about 25 s in all on a 2-core machine
SLOW_EXAMPLES = 6000

OPS_LISTS = st.lists(st.tuples(st.sampled_from(OPS), st.integers(0, 1 << 20), st.integers(0, 1 << 16),
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
    ops = data.draw(OPS_LISTS, label="mutations")
    splice_from = data.draw(st.sampled_from([p for paths in seeds.values() for p in paths]), label="splice")
    kind, detail = run_case(Case(seed, sidecar, ops), splice_from.read_bytes(), cases_dir, reader)
    assert is_fine(kind), f"{kind}\n{detail}"


def fuzz_test(fmt: str, examples: int):
    @settings(max_examples=examples, deadline=None, derandomize=True, database=None)
    @given(data=st.data())
    def test(seeds, cases_dir, reader, data):
        check_case(fmt, seeds, cases_dir, reader, data)

    test.__doc__ = (f"{examples} mutated {fmt} logs (deterministic): each reads as a RunLog or a LogError naming "
                    f"its file; no other exception, no signal, no input changed.")
    return test


test_mutated_csv_logs_read_as_a_runlog_or_a_logerror = fuzz_test("csv", EXAMPLES["csv"])
test_mutated_parquet_logs_read_as_a_runlog_or_a_logerror = fuzz_test("parquet", EXAMPLES["parquet"])
test_mutated_mat_logs_read_as_a_runlog_or_a_logerror = fuzz_test("mat", EXAMPLES["mat"])
test_many_mutated_csv_logs_slow = pytest.mark.slow(fuzz_test("csv", SLOW_EXAMPLES))
test_many_mutated_parquet_logs_slow = pytest.mark.slow(fuzz_test("parquet", SLOW_EXAMPLES))
test_many_mutated_mat_logs_slow = pytest.mark.slow(fuzz_test("mat", SLOW_EXAMPLES))


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
