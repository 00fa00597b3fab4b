"""Mutation fuzzing of ``sim.logio.read_log`` and ``sim.logmap.read_mapped``: seed logs, byte mutations, and a
reader in a child process.

    python -m tests.logio_fuzzing [--seconds 90] [--seed 0]

Seeds are small valid logs written by ``write_log`` (CSV with its sidecar, Parquet, compressed .mat) and
variants of them (an uncompressed .mat, a MATLAB v4 .mat, uncompressed Parquet, UTF-16 and cp1252 CSV), JSON
run logs (a list of records; records under a key beside a header with 'units'), and a drive's own records in
every format (kind "mapped"), read with ``read_mapped`` and the fixed map :data:`MAPPED_TABLE` (expressions,
units, two's complement, resampling, enable). A case mutates one seed file (or a CSV's sidecar) with a few
operations (bit flips, interesting 32-bit values, truncation, insertion, deletion, duplication, splicing from
another seed, re-encoding a CSV, mutations inside a compressed .mat element, and for JSON a value replaced by
an odd one or removed), then reads it in a child process, so that a crash of native code is counted rather
than fatal. The script prints the number of cases and the outcomes by kind and exits 1 if any read ended in an
exception other than ``LogError``, a LogError not naming its file, a signal, or a changed input file. The most
frequent LogError messages of each kind follow the counts.
"""

from __future__ import annotations

import argparse
import codecs
import csv
import json
import math
import multiprocessing
import random
import re
import resource
import struct
import sys
import tempfile
import time
import traceback
import warnings
import zlib
from collections import Counter
from dataclasses import dataclass
from pathlib import Path

import numpy as np

FORMATS = ("csv", "parquet", "mat", "json")
WRITTEN = ("csv", "parquet", "mat")  # the formats write_log writes
KINDS = (*FORMATS, "mapped")  # "mapped": a drive's own records of every format, read with MAPPED_TABLE
OPS = ("flip", "int32", "truncate", "insert", "delete", "duplicate", "splice", "reencode", "inner")
JSON_OPS = (*OPS, "json", "json")  # a JSON value replaced or removed, twice as often as a byte operation
JSON_VALUES = (None, True, False, 0, -1, 65535, 65536, 1.5, -0.0, 1e308, 2**64, 10**400, math.nan, math.inf, "",
               "1.5", " 2 ", "x", [], {}, [1, 2], {"a": 1}, [[1]], [None], [{}])
INTERESTING_U32 = (0, 1, 2, 7, 8, 9, 14, 15, 16, 0x7F, 0x80, 0xFF, 0xFFFF, 0x10000, 0x7FFFFFFF, 0x80000000,
                   0xFFFFFFFF)
ENCODINGS = ("utf-16", "utf-16-le", "utf-16-be", "cp1252", "latin-1", "utf-8-sig", "utf-32")
READ_TIMEOUT_S = 60.0
MEMORY_LIMIT = 8 << 30  # bytes of address space for the reading child

Op = tuple[str, int, int, bytes]  # (kind, position, size or value, payload)


# ------------------------------------------------------------------------------------------------- seeds


def small_log(n: int = 12):
    """Standard columns, a non-standard one with a non-ASCII unit, meta; 1 kHz."""
    from sim.runlog import RunLog

    rng = np.random.default_rng(7)
    columns = {"time": 1e-3 * np.arange(n), "tau_cmd": rng.normal(0, 1, n), "q": rng.normal(0, 1, n),
               "temperature": 25 + rng.normal(0, 1, n), "tau_flexure": rng.normal(0, 1, n)}
    units = {"time": "s", "tau_cmd": "N·m", "q": "rad", "temperature": "°C", "tau_flexure": "N·m"}
    return RunLog(columns, units, {"fixture": "locked", "seed": 7})


def write_seeds(folder: Path) -> dict[str, list[Path]]:
    """Valid logs in every format and their variants, by format; under "mapped", a drive's own records."""
    import pyarrow.parquet as pq
    from scipy.io import savemat

    from sim.logio import write_log

    log = small_log()
    seeds: dict[str, list[Path]] = {fmt: [write_log(log, folder / f"seed.{fmt}")] for fmt in WRITTEN}
    text = (folder / "seed.csv").read_text(encoding="utf-8")
    for encoding in ("utf-16", "cp1252"):
        path = folder / f"seed_{encoding.replace('-', '')}.csv"
        path.write_bytes(text.encode(encoding))
        sidecar_copy(folder / "seed.units.json", path, encoding)
        seeds["csv"].append(path)
    pq.write_table(pq.read_table(folder / "seed.parquet"), folder / "seed_plain.parquet", compression="none")
    seeds["parquet"].append(folder / "seed_plain.parquet")
    variables = {**log.columns, "units": dict(log.units), "meta": '{"fixture": "locked"}'}
    savemat(folder / "seed_plain.mat", variables, oned_as="column", do_compression=False)
    savemat(folder / "seed_v4.mat", dict(log.columns), oned_as="column", format="4")
    seeds["mat"] += [folder / "seed_plain.mat", folder / "seed_v4.mat"]
    rows = [dict(zip(log.columns, row, strict=True)) for row in np.column_stack(list(log.columns.values())).tolist()]
    (folder / "records.json").write_text(json.dumps(rows), encoding="utf-8")
    (folder / "keyed.json").write_text(json.dumps({"units": dict(log.units), **log.meta, "records": rows},
                                                  ensure_ascii=False), encoding="utf-8")
    seeds["json"] = [folder / "records.json", folder / "keyed.json"]
    seeds["mapped"] = write_mapped_seeds(folder)
    return seeds


# A drive's own record and the map that reads it: time in ms with jitter, a product with a scalar (a .mat or JSON
# header scalar, or a constant column), a 16-bit two's complement count, a position in degrees counted the other
# way (a CSV column 'pos.deg', a .mat struct's member, a JSON record's nested member), and a torque-enable flag off
# for the first samples.
MAPPED_TABLE = {"columns": {"time": "t", "tau_cmd": "vir * gtau + pwm * 0.001", "q": "-`pos.deg`"},
                "units": {"time": "ms", "q": "deg"}, "twos_complement": {"pwm": 16}, "resample": "5 ms",
                "enable": "en"}


def drive_record(n: int = 64) -> dict[str, np.ndarray]:
    """The variables of a drive's record (``gtau`` a column of one value)."""
    rng = np.random.default_rng(11)
    return {"t": 5.0 * np.arange(n) + rng.uniform(-1.0, 1.0, n), "vir": rng.normal(0.0, 1.0, n),
            "gtau": np.full(n, 0.25), "pwm": rng.choice([0.0, 5.0, 885.0, 32767.0, 32768.0, 65535.0], n),
            "pos.deg": np.cumsum(rng.normal(0.0, 1.0, n)), "en": np.r_[np.zeros(4), np.ones(n - 4)]}


def write_mapped_seeds(folder: Path) -> list[Path]:
    """A drive's record as CSV, Parquet (pwm as uint16), .mat (gtau a scalar, pos a struct), a JSON list of records
    and JSON records beside a header (gtau and units), written with plain code as a drive's software would."""
    import pyarrow as pa
    import pyarrow.parquet as pq
    from scipy.io import savemat

    record = drive_record()
    paths = [folder / "drive.csv", folder / "drive.parquet", folder / "drive.mat", folder / "drive_list.json",
             folder / "drive_keyed.json"]
    with paths[0].open("w", newline="", encoding="utf-8") as fh:
        writer = csv.writer(fh, lineterminator="\n")
        writer.writerow(list(record))
        writer.writerows(zip(*[[repr(float(v)) for v in values] for values in record.values()], strict=True))
    pq.write_table(pa.table({**record, "pwm": pa.array(record["pwm"].astype(np.uint16))}), paths[1])
    savemat(paths[2], {"t": record["t"], "vir": record["vir"], "gtau": 0.25, "pwm": record["pwm"].astype(np.uint16),
                       "pos": {"deg": record["pos.deg"]}, "en": record["en"]}, oned_as="column")
    rows = [{"t": t, "vir": vir, "gtau": 0.25, "pwm": int(pwm), "pos": {"deg": deg}, "en": bool(en)}
            for t, vir, pwm, deg, en in zip(record["t"].tolist(), record["vir"].tolist(), record["pwm"].tolist(),
                                            record["pos.deg"].tolist(), record["en"].tolist(), strict=True)]
    paths[3].write_text(json.dumps(rows), encoding="utf-8")
    header = {"gtau": 0.25, "units": {"t": "ms"}, "drive": {"model": "X1", "firmware": [1, 2]}}
    paths[4].write_text(json.dumps({**header, "samples": [{k: v for k, v in row.items() if k != "gtau"}
                                                          for row in rows]}), encoding="utf-8")
    return paths


def sidecar_copy(sidecar: Path, csv_path: Path, encoding: str) -> None:
    """The seed sidecar, re-encoded, beside ``csv_path``."""
    text = sidecar.read_text(encoding="utf-8")
    csv_path.with_name(csv_path.stem + ".units.json").write_bytes(text.encode(encoding))


# --------------------------------------------------------------------------------------------- mutations


def mutate(data: bytes, ops: list[Op], other: bytes) -> bytes:
    """``data`` after each of ``ops``; ``other`` is the splicing source."""
    for op in ops:
        data = apply(data, op, other)
    return data


def apply(data: bytes, op: Op, other: bytes) -> bytes:
    """One mutation. Positions and sizes wrap around the data's length."""
    kind, position, size, payload = op
    n = len(data)
    at = position % (n + 1)
    if kind == "flip" and n:
        at %= n
        return data[:at] + bytes([data[at] ^ (1 << (size % 8))]) + data[at + 1:]
    if kind == "int32":
        value = INTERESTING_U32[size % len(INTERESTING_U32)]
        return data[:at] + struct.pack("<I" if position % 2 else ">I", value) + data[at + 4:]
    if kind == "truncate":
        return data[:at]
    if kind == "insert":
        return data[:at] + payload + data[at:]
    if kind == "delete":
        return data[:at] + data[at + 1 + size % 64:]
    if kind == "duplicate":
        return data[:at] + data[at:at + 1 + size % 64] + data[at:]
    if kind == "splice" and other:
        start = size % len(other)
        return data[:at] + other[start:start + 1 + len(payload) * 16] + data[at + len(payload) * 16:]
    if kind == "reencode":
        return reencode(data, ENCODINGS[size % len(ENCODINGS)])
    if kind == "inner":
        return mutate_compressed(data, position, size, payload)
    if kind == "json":
        return mutate_json(data, position, size)
    return data


def mutate_json(data: bytes, position: int, size: int) -> bytes:
    """JSON with one value (a member or an element, at any depth) replaced by one of :data:`JSON_VALUES` or
    removed; data that is not JSON is returned as it is."""
    try:
        top = json.loads(data)
    except (ValueError, RecursionError):
        return data
    slots, pending = [], [top]
    while pending and len(slots) < 10_000:
        value = pending.pop()
        keys = value.keys() if isinstance(value, dict) else range(len(value)) if isinstance(value, list) else ()
        for key in keys:
            slots.append((value, key))
            pending.append(value[key])
    if not slots:
        return data
    container, key = slots[position % len(slots)]
    choice = size % (len(JSON_VALUES) + 1)
    if choice == len(JSON_VALUES):
        del container[key]
    else:
        container[key] = JSON_VALUES[choice]
    return json.dumps(top).encode()


def reencode(data: bytes, encoding: str) -> bytes:
    """Text re-encoded (undecodable bytes kept as replacement characters, unencodable ones as '?')."""
    for source in ("utf-8-sig", "utf-16", "cp1252"):
        try:
            text = data.decode(source)
            break
        except UnicodeDecodeError:
            continue
    else:
        text = data.decode("latin-1")
    return codecs.encode(text, encoding, errors="replace")


def mutate_compressed(data: bytes, position: int, size: int, payload: bytes) -> bytes:
    """Flip a byte or put a 32-bit value inside one miCOMPRESSED element of a v5 .mat, recompressed."""
    elements = compressed_elements(data)
    if not elements:
        return data
    start, end = elements[position % len(elements)]
    try:
        inner = zlib.decompress(data[start + 8:end])
    except zlib.error:
        return data
    at = (position // 7) % max(len(inner), 1)
    if payload:
        inner = inner[:at] + bytes([inner[at] ^ payload[0] if at < len(inner) else payload[0]]) + inner[at + 1:]
    else:
        inner = inner[:at] + struct.pack("<I", INTERESTING_U32[size % len(INTERESTING_U32)]) + inner[at + 4:]
    packed = zlib.compress(inner)
    return data[:start] + struct.pack("<II", 15, len(packed)) + packed + data[end:]


def compressed_elements(data: bytes) -> list[tuple[int, int]]:
    """(start, end) of each top-level miCOMPRESSED element of a little-endian v5 .mat."""
    spans, pos = [], 128
    while pos + 8 <= len(data):
        mdtype, nbytes = struct.unpack_from("<II", data, pos)
        end = pos + 8 + nbytes
        if end > len(data):
            break
        if mdtype == 15:
            spans.append((pos, end))
        pos = end
    return spans


def random_ops(rng: random.Random, ops: tuple[str, ...] = OPS) -> list[Op]:
    """One to four mutations drawn from ``rng``."""
    return [(rng.choice(ops), rng.randrange(1 << 20), rng.randrange(1 << 16),
             rng.randbytes(rng.randrange(0, 9))) for _ in range(rng.randint(1, 4))]


def ops_of(kind: str) -> tuple[str, ...]:
    """The mutations for seeds of ``kind``: the JSON ones too where there are JSON seeds."""
    return JSON_OPS if kind in ("json", "mapped") else OPS


# ----------------------------------------------------------------------------------- reading in a child


def read_outcome(path: str, joint: str = "hinge", mapped: bool = False) -> tuple[str, str]:
    """``read_log(path)`` (or ``read_mapped(path)`` with :data:`MAPPED_TABLE`) as (kind, detail): ('RunLog', ''),
    ('MappedRecord', ''), ('LogError', message) or (exception name, traceback)."""
    from sim.logio import LogError, read_log
    from sim.logmap import MappedRecord, log_map_from_dict, read_mapped
    from sim.runlog import RunLog

    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            if mapped:
                outcome = read_mapped(path, log_map_from_dict(MAPPED_TABLE), joint=joint)
                ok = isinstance(outcome, MappedRecord) and all(isinstance(log, RunLog) for log in outcome.logs)
            else:
                outcome = read_log(path, joint=joint)
                ok = isinstance(outcome, RunLog)
    except LogError as err:
        return "LogError", str(err)
    except Exception as err:  # the property under test: nothing else may escape
        return type(err).__name__, traceback.format_exc()
    return ("MappedRecord" if mapped else "RunLog", "") if ok else ("not a log", repr(outcome)[:200])


def _serve(conn, memory_limit: int) -> None:
    resource.setrlimit(resource.RLIMIT_AS, (memory_limit, memory_limit))  # a MemoryError, not the OOM killer
    while True:
        try:
            request = conn.recv()
        except EOFError:
            return
        conn.send(read_outcome(*request))


class ChildReader:
    """``read_outcome`` in a long-lived child process; a crash gives ('signal', name) and a fresh child.

    The child's address space is limited to ``memory_limit`` bytes, so that a reader allocating without
    bound fails with MemoryError in the child rather than drawing the kernel's OOM killer on the machine.
    """

    def __init__(self, timeout_s: float = READ_TIMEOUT_S, memory_limit: int = MEMORY_LIMIT) -> None:
        self.timeout_s, self.memory_limit = timeout_s, memory_limit
        self._context = multiprocessing.get_context("spawn")
        self._start()

    def _start(self) -> None:
        self._conn, child_conn = self._context.Pipe()
        self._process = self._context.Process(target=_serve, args=(child_conn, self.memory_limit), daemon=True)
        self._process.start()
        child_conn.close()

    def read(self, path: Path, joint: str = "hinge", mapped: bool = False) -> tuple[str, str]:
        """The outcome of reading ``path`` in the child (with ``read_mapped`` and MAPPED_TABLE if ``mapped``)."""
        self._conn.send((str(path), joint, mapped))
        try:
            if self._conn.poll(self.timeout_s):
                return self._conn.recv()
            self._process.kill()
            outcome = ("timeout", f"no answer in {self.timeout_s} s")
        except (EOFError, ConnectionError):
            self._process.join()
            code = self._process.exitcode
            outcome = ("signal", signal_name(-code) if code is not None and code < 0 else f"exit {code}")
        self._process.join()
        self._start()
        return outcome

    def close(self) -> None:
        """End the child."""
        self._conn.close()
        self._process.join(timeout=10)
        if self._process.is_alive():
            self._process.kill()


def signal_name(number: int) -> str:
    import signal

    try:
        return signal.Signals(number).name
    except ValueError:
        return f"signal {number}"


# ---------------------------------------------------------------------------------------------- a case


@dataclass
class Case:
    """One mutated file: which seed, whether its sidecar is the target, the mutations, and whether it is read
    with ``read_mapped`` (and MAPPED_TABLE) rather than ``read_log``."""

    seed: Path
    sidecar: bool
    ops: list[Op]
    mapped: bool = False


def sidecar_of(path: Path) -> Path:
    return path.with_name(path.stem + ".units.json")


def run_case(case: Case, splice_from: bytes, folder: Path, reader: ChildReader) -> tuple[str, str]:
    """Write the mutated case to ``folder``, read it in the child; the outcome, or a broken property."""
    target = folder / f"case{case.seed.suffix}"
    for stale in (target, sidecar_of(target)):
        stale.unlink(missing_ok=True)
    target.write_bytes(case.seed.read_bytes())
    if sidecar_of(case.seed).exists():
        sidecar_of(target).write_bytes(sidecar_of(case.seed).read_bytes())
    mutated = sidecar_of(target) if case.sidecar and sidecar_of(target).exists() else target
    mutated.write_bytes(mutate(mutated.read_bytes(), case.ops, splice_from))
    files = [p for p in (target, sidecar_of(target)) if p.exists()]
    before = {p: (p.read_bytes(), p.stat().st_mtime_ns) for p in files}
    kind, detail = reader.read(target, mapped=case.mapped)
    if any((p.read_bytes(), p.stat().st_mtime_ns) != state for p, state in before.items()):
        return "modified", f"{[p.name for p in files]} changed by reading"
    if kind == "LogError" and not any(p.name in detail for p in files):
        return "unnamed", f"LogError without the file name: {detail}"
    return kind, detail


def kind_of(detail: str) -> str:
    """A short key to group outcomes: for a traceback the innermost frame, else the message without its
    numbers and quoted text."""
    lines = detail.strip().splitlines() or [""]
    frames = [line.strip() for line in lines if line.strip().startswith("File ")]
    if frames:
        where = re.sub(r'File ".*/(site-packages/)?', "", frames[-1])
        return where
    return re.sub(r"'[^']*'|\d+", "#", lines[-1])[:160]


def is_fine(kind: str) -> bool:
    """Whether an outcome keeps the property: a RunLog (of read_log), a MappedRecord (of read_mapped) or a
    LogError naming its file."""
    return kind in ("RunLog", "MappedRecord", "LogError")


# ------------------------------------------------------------------------------------------------ script


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=90.0)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)
    rng = random.Random(args.seed)
    outcomes: Counter = Counter()
    messages: Counter = Counter()
    examples: dict[str, str] = {}
    reader = ChildReader()
    with tempfile.TemporaryDirectory() as seeds_dir, tempfile.TemporaryDirectory() as cases_dir:
        seeds = write_seeds(Path(seeds_dir))
        every = [p for paths in seeds.values() for p in paths]
        deadline = time.monotonic() + args.seconds
        while time.monotonic() < deadline:
            fmt = KINDS[outcomes.total() % len(KINDS)]
            seed = rng.choice(seeds[fmt])
            case = Case(seed, fmt == "csv" and rng.random() < 0.2, random_ops(rng, ops_of(fmt)), fmt == "mapped")
            kind, detail = run_case(case, rng.choice(every).read_bytes(), Path(cases_dir), reader)
            key = kind if is_fine(kind) else f"{kind}: {kind_of(detail)}"
            outcomes[(fmt, key)] += 1
            if kind == "LogError":
                messages[(fmt, kind_of(detail.split(": ", 1)[-1]))] += 1
            if not is_fine(kind):
                examples.setdefault(key, f"{case}\n{detail}")
    reader.close()
    print(f"{outcomes.total()} cases in {args.seconds:g} s (seed {args.seed})")
    for (fmt, key), count in sorted(outcomes.items()):
        print(f"  {fmt:8s} {count:6d}  {key}")
    print("most frequent LogError messages (numbers and quoted text blanked):")
    for fmt in KINDS:
        for (_, message), count in sorted(((k, c) for k, c in messages.items() if k[0] == fmt),
                                          key=lambda item: -item[1])[:6]:
            print(f"  {fmt:8s} {count:6d}  {message}")
    for key, example in examples.items():
        print(f"\n--- {key}\n{example}")
    return 1 if examples else 0


if __name__ == "__main__":
    sys.exit(main())
