"""Read and write run logs as CSV, Parquet and MATLAB .mat, with one set of validation rules.

A run log is the same whether simulated (``sim.run.run_open_loop``) or measured on a rig: columns named and
in the units of :data:`sim.runlog.STANDARD_UNITS` (rotational joint) or :data:`SLIDE_UNITS` (slide joint),
plus any further columns with their own units. ``docs/run_log_format.md`` is the user-facing description of
the format; this module is its implementation.

=================  ==========================================================================================
``.csv``           a header row of column names, then one row per sample; floats written with ``repr`` (the
                   shortest text that parses back to the same double). Units of columns that are not standard
                   (or differ from the rotational standard) go to a sidecar ``<stem>.units.json``.
``.parquet``       one float64 column per signal; units and meta as JSON in the schema metadata
                   (keys ``torquebed.units`` and ``torquebed.meta``).
``.mat``           one variable per column (an N x 1 double), a ``units`` struct (field = column, value = unit)
                   and a ``meta`` char array holding JSON. v4 and v5/v7 files are checked element by element
                   (:mod:`sim.matcheck`) and ``scipy.io.loadmat`` reads what was checked; v7.3 (HDF5) files need
                   ``h5py`` and are read in a child process (``sim/_mat73.py``), so that a crash of libhdf5
                   is a :class:`LogError`.
=================  ==========================================================================================

A CSV file or sidecar may be UTF-8, UTF-16 with a byte-order mark, or cp1252; text cells are numbers only if
they match :data:`NUMBER`.

Rows in error messages are numbered as a spreadsheet shows the CSV file: the header is row 1, so the first
sample is row 2 and sample ``k`` (1-based, MATLAB's ``q(k)``) is row ``k + 1``. The same numbering is used
for every format, so a log gives the same message whether it is stored as CSV, Parquet or .mat.
"""

from __future__ import annotations

import codecs
import csv
import difflib
import importlib.util
import io
import json
import math
import os
import pickle
import re
import signal
import subprocess
import sys
import warnings
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import IO, Any

import numpy as np

from sim.matcheck import MatStructureError, checked_mat
from sim.runlog import STANDARD_UNITS, RunLog

JOINTS = ("hinge", "slide")

# A slide (prismatic) joint's effort, position and velocity are linear; every other column keeps its unit.
SLIDE_UNITS: dict[str, str] = {**STANDARD_UNITS, "tau_cmd": "N", "q": "m", "qd": "m/s", "q_ref": "m"}

REQUIRED_COLUMNS = ("time", "tau_cmd")
OUTPUT_COLUMNS = ("q", "tau_sensor", "force_loadcell")  # a log needs at least one measure of the output side

# The sampling check compares every step with the median step; that needs at least two steps.
MIN_SAMPLES = 3

HEADER_ROWS = 1  # rows in messages count the CSV header as row 1, so sample index i (0-based) is row i + 2
FIRST_FEW = 5  # how many offending rows an error lists
TYPO_CUTOFF = 0.8  # difflib similarity above which an undeclared column is taken for a misspelt standard name
UNKNOWN_UNIT = "unknown"  # unit given to an undeclared, non-standard column that is kept

# ASCII spellings accepted for the format's non-ASCII units (MATLAB and spreadsheet users often cannot type
# '·' or '°'); a log read with one of them carries the canonical unit.
UNIT_ALIASES: dict[str, str] = {
    **{alias: "N·m" for alias in ("N*m", "N.m", "Nm", "N m", "N⋅m")},
    **{alias: "°C" for alias in ("degC", "deg C", "℃")},
}

# A number in text: an ASCII decimal (sign, digits, optional fraction and exponent) or, in any case,
# 'nan', 'inf', 'infinity'; spaces and tabs around it are ignored. No '_', no non-ASCII digits or spaces.
NUMBER = re.compile(r"[ \t]*[+-]?(?:(?:[0-9]+\.?[0-9]*|\.[0-9]+)(?:[eE][+-]?[0-9]+)?|(?i:inf|infinity|nan))[ \t]*")

PARQUET_UNITS_KEY = b"torquebed.units"
PARQUET_META_KEY = b"torquebed.meta"
MAT_RESERVED = ("units", "meta")
_MATLAB_NAME = re.compile(r"[A-Za-z][A-Za-z0-9_]{0,62}")  # MATLAB's isvarname, namelengthmax = 63
_HDF5_SIGNATURE = b"\x89HDF\r\n\x1a\n"
_HDF5_USERBLOCK = 512  # a v7.3 .mat is HDF5 behind MATLAB's 512-byte header
_MAT73_SCRIPT = Path(__file__).with_name("_mat73.py")
MAT73_TIMEOUT_S = 300.0  # a v7.3 file's parser (a child process) taking longer is stopped and the file refused


class LogError(ValueError):
    """A run log breaks the format.

    ``path`` is the file at fault (the log or its sidecar); ``column`` and ``row`` (spreadsheet row,
    header = 1) name where in it, if known. A message from :func:`read_log` starts with the file's name.
    """

    def __init__(self, message: str, *, column: str | None = None, row: int | None = None,
                 path: Path | None = None) -> None:
        super().__init__(message)
        self.column, self.row, self.path = column, row, path

    def located(self, path: Path) -> LogError:
        """This error, its message starting with ``path``'s name unless it names a file already."""
        if self.path is None:
            self.path = path
            self.args = (f"{path.name}: {self.args[0]}",)
        return self


class LogWarning(UserWarning):
    """A run log was read, but something in it was guessed (e.g. a column without a unit)."""


@dataclass(frozen=True)
class SlideRunLog(RunLog):
    """A :class:`~sim.runlog.RunLog` of a slide joint: ``tau_cmd`` [N], ``q`` [m], ``qd`` [m/s].

    ``RunLog`` fixes the rotational units for the standard names; this subclass checks :data:`SLIDE_UNITS`
    instead and otherwise applies ``RunLog``'s checks (equal-length 1-D columns, a unit for each, ``time``).
    """

    def __post_init__(self) -> None:
        for name, unit in self.units.items():
            if name in self.columns and name in SLIDE_UNITS and unit != SLIDE_UNITS[name]:
                raise ValueError(f"column {name!r} is in {unit!r}; a slide joint's log fixes {SLIDE_UNITS[name]!r}")
        as_rotational = {name: STANDARD_UNITS.get(name, unit) for name, unit in self.units.items()}
        RunLog(self.columns, as_rotational)  # the base class's checks, on the units a hinge log would carry


def joint_units(joint: str) -> dict[str, str]:
    """The standard columns' units for a ``'hinge'`` (rotational) or ``'slide'`` (linear) joint."""
    if joint == "hinge":
        return dict(STANDARD_UNITS)
    if joint == "slide":
        return dict(SLIDE_UNITS)
    raise ValueError(f"joint = {joint!r}; expected one of {JOINTS}")


def sidecar_path(csv_path: str | Path) -> Path:
    """The units sidecar of a CSV log: ``run.csv`` -> ``run.units.json``."""
    csv_path = Path(csv_path)
    return csv_path.with_name(csv_path.stem + ".units.json")


def row_of(index: int) -> int:
    """Spreadsheet row of the sample with 0-based ``index`` (the header is row 1)."""
    return index + 1 + HEADER_ROWS


# ---------------------------------------------------------------------------------------------------- writing


def write_log(log: RunLog, path: str | Path, *, overwrite: bool = False) -> Path:
    """Write ``log`` in the format given by the suffix of ``path`` (``.csv``, ``.parquet``, ``.mat``).

    Every column is stored as float64. The log is checked first with the rules :func:`read_log` applies
    (except sampling regularity), so a file this writes can be read back.

    Parameters
    ----------
    log : RunLog
        The run (a :class:`SlideRunLog` for a slide joint).
    path : str or Path
        Target file. For CSV the sidecar ``<stem>.units.json`` is written beside it when some column's unit
        is not the rotational standard one (and a stale sidecar is removed when ``overwrite``).
    overwrite : bool
        Replace existing files; otherwise an existing target (or sidecar) raises ``FileExistsError``.

    Returns
    -------
    Path
        ``path``.
    """
    path = Path(path)
    writer = _WRITERS.get(_suffix(path))
    if writer is None:
        raise LogError(f"cannot write {path.name!r}: unknown suffix {path.suffix!r}; use one of "
                       f"{', '.join(_WRITERS)}")
    columns = {name: _float_column_for_writing(name, values) for name, values in log.columns.items()}
    _check_columns(list(columns), set(log.units), "the log's units")
    check_samples(columns, max_jitter=math.inf)
    writer(columns, dict(log.units), _meta_json(log.meta), path, overwrite)
    return path


def _write_csv(columns: dict[str, np.ndarray], units: dict[str, str], meta_json: str, path: Path,
               overwrite: bool) -> None:
    side = sidecar_path(path)
    declared = {name: unit for name, unit in units.items() if STANDARD_UNITS.get(name) != unit}
    if not overwrite:
        for target in (path, side):  # a sidecar left from another log would give this one wrong units
            if target.exists():
                raise FileExistsError(f"{target} exists; pass overwrite=True to replace it")
    rows = np.column_stack(list(columns.values())).tolist()  # Python floats: repr is the shortest exact text
    with _created(path, overwrite, "w", newline="", encoding="utf-8") as fh:
        csv.writer(fh, lineterminator="\n").writerow(list(columns))
        fh.writelines(",".join(map(repr, row)) + "\n" for row in rows)
    if declared:
        with _created(side, overwrite, "w", encoding="utf-8") as fh:
            json.dump(declared, fh, ensure_ascii=False, indent=1)
            fh.write("\n")
    elif side.exists():
        side.unlink()  # overwrite=True: a sidecar from an earlier log would give this one wrong units


def _write_parquet(columns: dict[str, np.ndarray], units: dict[str, str], meta_json: str, path: Path,
                   overwrite: bool) -> None:
    import pyarrow as pa
    import pyarrow.parquet as pq

    table = pa.table({name: pa.array(values, type=pa.float64()) for name, values in columns.items()})
    table = table.replace_schema_metadata({PARQUET_UNITS_KEY: json.dumps(units, ensure_ascii=False),
                                           PARQUET_META_KEY: meta_json})
    with _created(path, overwrite, "wb") as fh:
        pq.write_table(table, fh)


def _write_mat(columns: dict[str, np.ndarray], units: dict[str, str], meta_json: str, path: Path,
               overwrite: bool) -> None:
    from scipy.io import savemat

    for name in columns:
        if not _MATLAB_NAME.fullmatch(name) or name in MAT_RESERVED:
            raise LogError(f"column {name!r} cannot be a MATLAB variable (a letter, then letters, digits or '_', "
                           f"at most 63 characters; not {' or '.join(map(repr, MAT_RESERVED))}); write CSV or "
                           f"Parquet instead", column=name)
    with _created(path, overwrite, "wb") as fh:
        savemat(fh, {**columns, "units": units, "meta": meta_json}, oned_as="column", do_compression=True)


_WRITERS: dict[str, Callable[..., None]] = {".csv": _write_csv, ".parquet": _write_parquet, ".mat": _write_mat}


@contextmanager
def _created(path: Path, overwrite: bool, mode: str, **kwargs: Any) -> Iterator[IO]:
    """Open ``path`` for writing, exclusively unless ``overwrite``; remove it again if writing fails."""
    try:
        fh = path.open(mode.replace("w", "w" if overwrite else "x"), **kwargs)
    except FileExistsError:
        raise FileExistsError(f"{path} exists; pass overwrite=True to replace it") from None
    try:
        with fh:
            yield fh
    except BaseException:
        path.unlink(missing_ok=True)
        raise


def _float_column_for_writing(name: str, values: np.ndarray) -> np.ndarray:
    values = np.asarray(values)
    if values.dtype.kind not in "iuf":
        raise LogError(f"column {name!r} holds {values.dtype} values; the format stores real numbers",
                       column=name)
    return values.astype(np.float64)


def _meta_json(meta: dict[str, Any]) -> str:
    try:
        return json.dumps(meta, ensure_ascii=False, allow_nan=False)
    except (TypeError, ValueError) as err:
        raise LogError(f"meta must be JSON-serialisable (no NaN): {err}") from None


# ---------------------------------------------------------------------------------------------------- reading


@dataclass
class _Raw:
    """What a reader found in a file, before validation.

    ``columns`` values are float64 arrays or, where the file holds text or mixed cells, sequences of cells.
    ``declared`` is the unit the file itself gives each column (sidecar, schema metadata, ``units`` struct).
    """

    columns: dict[str, Any]
    declared: dict[str, str]
    meta: dict[str, Any]
    where: str  # how a user declares units for this format, for messages


def read_log(path: str | Path, *, joint: str = "hinge", max_jitter: float = 0.05) -> RunLog:
    """Read and validate a run log; the format is given by the suffix (``.csv``, ``.parquet``, ``.mat``).

    The file is only read, never changed. See ``docs/run_log_format.md`` for the rules and messages.

    Parameters
    ----------
    path : str or Path
        The log file (for CSV, a sidecar ``<stem>.units.json`` beside it is read when present).
    joint : {'hinge', 'slide'}
        'hinge': ``tau_cmd`` [N·m], ``q`` [rad], ``qd`` [rad/s]; 'slide': [N], [m], [m/s].
    max_jitter : float
        Largest accepted relative deviation ``|dt_k - median(dt)| / median(dt)`` of a sampling step from the
        median step [1]; ``math.inf`` accepts any sampling.

    Returns
    -------
    RunLog
        A :class:`SlideRunLog` for ``joint='slide'``. Every column is float64. Columns keep the file's order.

    Raises
    ------
    LogError
        The file breaks the format; the message names the column and the row (the header is row 1).
    """
    path = Path(path)
    units = joint_units(joint)
    if not max_jitter >= 0:
        raise ValueError(f"max_jitter = {max_jitter}; expected a relative step deviation >= 0")
    reader = _reader(path)
    try:
        raw = reader(path)
        _check_columns(list(raw.columns), set(raw.declared), raw.where)
        log_units = _units(list(raw.columns), raw.declared, units, joint, raw.where)
        columns = {name: _to_float(name, values) for name, values in raw.columns.items()}
        check_samples(columns, max_jitter=max_jitter)
    except LogError as err:
        err.located(path)
        raise
    return (SlideRunLog if joint == "slide" else RunLog)(columns, log_units, raw.meta)


def _read_csv(path: Path) -> _Raw:
    side = sidecar_path(path)
    declared = _read_sidecar(side) if side.exists() else {}
    encoding = _text_encoding(path)
    head = _csv_rows(path, encoding)
    header = [name.strip() for name in next(head, [])]
    first = next(head, None)
    head.close()
    if not header:
        raise LogError(f"{path.name} is empty; the first row must name the columns", row=1, path=path)
    if any("\0" in name for name in header):
        raise LogError("the header row holds NUL characters: is the file UTF-16 without a byte-order mark? "
                       "Save it as UTF-8", row=1)
    if len(header) == 1 and (";" in header[0] or "\t" in header[0]):
        sep = "';'" if ";" in header[0] else "tabs"
        raise LogError(f"the header row is one cell {header[0]!r}: the file seems separated by {sep}; "
                       f"the format separates by ','", row=1)
    for j, name in enumerate(header):
        if not name:
            raise LogError(f"row 1, cell {j + 1}: empty column name", row=1)
        if name in header[:j]:
            raise LogError(f"column {name!r} appears twice in the header row (cells {header.index(name) + 1} "
                           f"and {j + 1})", column=name, row=1)
    if first and not any(_is_number(cell) for cell in first):
        shown = ", ".join(repr(c) for c in first[:4]) + (", ..." if len(first) > 4 else "")
        raise LogError(f"row {row_of(0)} holds no number ({shown}): a units row? The CSV format has only "
                       f"the header row; declare units of non-standard columns in {side.name}",
                       row=row_of(0))
    where = f"the sidecar {side.name}"
    numbers = _csv_numbers(path, header, encoding)
    if numbers is not None:
        return _Raw(numbers, declared, {}, where)
    body = list(_csv_rows(path, encoding))[1:]  # something is wrong: find it cell by cell
    while body and not body[-1]:
        body.pop()
    for i, row in enumerate(body):
        if len(row) != len(header):
            raise LogError(f"row {row_of(i)} has {len(row)} cells; the header row has {len(header)}",
                           row=row_of(i))
    cells = list(zip(*body, strict=True)) if body else [() for _ in header]
    return _Raw(dict(zip(header, cells, strict=True)), declared, {}, where)


def _read_sidecar(side: Path) -> dict[str, str]:
    """The units a CSV's sidecar declares; a LogError naming the sidecar if it is not a JSON map of strings."""
    try:
        text = side.read_text(encoding=_text_encoding(side))
        return _unit_map(_json_from(text, side.name), side.name)
    except LogError as err:
        raise err.located(side) from None


def _text_encoding(path: Path) -> str:
    """The codec that decodes all of ``path``: the one its byte-order mark names, else UTF-8, else cp1252.

    cp1252 (Windows' Western European) reads Latin-1 text the same, bar control characters.
    """
    with path.open("rb") as fh:
        start = fh.read(len(codecs.BOM_UTF8))
    marked = [(codec, name) for bom, codec, name in _BYTE_ORDER_MARKS if start.startswith(bom)]
    tried = []
    for codec, name in marked[:1] or [("utf-8", "UTF-8"), ("cp1252", "cp1252")]:
        failure = _decode_failure(path, codec)
        if failure is None:
            return codec
        tried.append((name, *failure))
    raise LogError(f"{path.name} is not text in " + " or ".join(f"{name} ({where})" for name, where, _ in tried)
                   + "; save it as UTF-8", row=tried[0][2], path=path)


_BYTE_ORDER_MARKS = ((codecs.BOM_UTF8, "utf-8-sig", "UTF-8"), (codecs.BOM_UTF16_LE, "utf-16", "UTF-16 LE"),
                     (codecs.BOM_UTF16_BE, "utf-16", "UTF-16 BE"))
_CHUNK_BYTES = 1 << 20


def _decode_failure(path: Path, codec: str) -> tuple[str, int | None] | None:
    """None if ``codec`` decodes all of ``path``; else where it fails and the row (single-byte codecs)."""
    decoder = codecs.getincrementaldecoder(codec)()
    ascii_compatible = not codec.startswith("utf-16")
    offset = 0
    with path.open("rb") as fh:
        while True:
            chunk = fh.read(_CHUNK_BYTES)
            if chunk and ascii_compatible and chunk.isascii() and not decoder.getstate()[0]:  # the usual log
                offset += len(chunk)
                continue
            pending = len(decoder.getstate()[0])  # bytes of the previous chunk the decoder still holds
            try:
                decoder.decode(chunk, final=not chunk)
            except UnicodeDecodeError as err:
                at = offset - pending + err.start
                if codec.startswith("utf-16"):
                    return f"{err.reason} at byte {at}", None
                fh.seek(0)
                row = fh.read(at).count(b"\n") + 1
                return f"byte 0x{err.object[err.start]:02X} in row {row}", row
            if not chunk:
                return None
            offset += len(chunk)


def _csv_rows(path: Path, encoding: str) -> Iterator[list[str]]:
    """The CSV file's rows as cells; a LogError naming the row a record that cannot be parsed starts in."""
    with path.open(newline="", encoding=encoding) as fh:
        reader = csv.reader(fh)
        while True:
            start = reader.line_num + 1
            try:
                yield next(reader)
            except StopIteration:
                return
            except csv.Error as err:  # e.g. an unclosed '"' making the rest of the file one cell
                raise LogError(f"row {start}: not readable as CSV ({err})", row=start) from None


def _csv_numbers(path: Path, header: list[str], encoding: str) -> dict[str, np.ndarray] | None:
    """All columns as float64 if every cell is a number (pyarrow: fast, correctly rounded), else None.

    Anything unusual (text, empty cells, 'nan', ragged or blank rows) returns None, and the cell-by-cell
    path reads the file again to name the column and row. pyarrow accepts no number that :data:`NUMBER`
    refuses. It reads UTF-8 directly and other encodings through Python's codec.
    """
    import pyarrow as pa
    import pyarrow.csv as pa_csv

    try:
        table = pa_csv.read_csv(
            path, read_options=pa_csv.ReadOptions(column_names=header, skip_rows=1,
                                                  encoding="utf8" if encoding.startswith("utf-8") else encoding),
            parse_options=pa_csv.ParseOptions(ignore_empty_lines=False),
            convert_options=pa_csv.ConvertOptions(column_types=dict.fromkeys(header, pa.float64())))
    except (pa.ArrowInvalid, UnicodeDecodeError):
        return None
    if any(column.null_count for column in table.columns):
        return None
    return {name: np.array(table.column(name).to_numpy(), dtype=np.float64) for name in header}


def _read_parquet(path: Path) -> _Raw:
    import pyarrow as pa
    import pyarrow.parquet as pq

    try:
        parquet = pq.ParquetFile(path)
        _check_parquet_rows(parquet.metadata)
        table = parquet.read()
    except (pa.ArrowException, OSError) as err:  # truncated or corrupt: ArrowInvalid, OSError, ...
        detail = re.sub(r" input source '[^']*'", "", str(err))
        raise LogError(f"{path.name} is not a readable Parquet file: {detail}", path=path) from None
    except UnicodeDecodeError as err:  # pyarrow decodes column names as it reads
        raise LogError(f"a column name is not UTF-8 text ({err})") from None
    names = table.column_names
    for j, name in enumerate(names):
        if name in names[:j]:
            raise LogError(f"column {name!r} appears twice", column=name)
    metadata = table.schema.metadata or {}
    units_key = "schema metadata 'torquebed.units'"
    declared = _unit_map(_json_from(metadata.get(PARQUET_UNITS_KEY), units_key), units_key)
    meta = _json_from(metadata.get(PARQUET_META_KEY), "schema metadata 'torquebed.meta'")
    columns = {name: _parquet_column(name, table.column(name)) for name in names}
    return _Raw(columns, declared, meta, "the schema metadata 'torquebed.units'")


def _check_parquet_rows(metadata: Any) -> None:
    """Refuse row counts that could not be read into memory: pyarrow allocates for them before reading.

    A corrupt footer can declare 2^40 rows in a file of a few hundred bytes; the reader would need the
    declared rows times the columns times 8 bytes twice over (pyarrow's buffers and the float64 columns).
    """
    groups = [metadata.row_group(i).num_rows for i in range(metadata.num_row_groups)]
    rows, columns = sum(groups), max(metadata.num_columns, 1)
    needed = 16 * rows * columns
    if min(groups, default=0) < 0 or needed > _memory_bytes():
        raise LogError(f"the file declares {rows} rows of {columns} column(s) ({needed / 1e9:.3g} GB to read), "
                       f"more than this machine's memory ({_memory_bytes() / 1e9:.3g} GB): a corrupt footer, "
                       f"or a log to split")


def _memory_bytes() -> int:
    """Physical memory of this machine."""
    return os.sysconf("SC_PHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")


def _parquet_column(name: str, column: Any) -> Any:
    """A Parquet column as float64, or as cells (text, booleans, nulls) for ``_to_float`` to check one by one."""
    import pyarrow as pa

    kind = column.type
    try:
        if pa.types.is_dictionary(kind):  # e.g. pandas' categorical: read the values
            column = column.cast(kind.value_type)
            kind = column.type
        if (pa.types.is_floating(kind) or pa.types.is_integer(kind)) and column.null_count == 0:
            return np.array(column.to_numpy(), dtype=np.float64)
        if any(test(kind) for test in (pa.types.is_floating, pa.types.is_integer, pa.types.is_string,
                                       pa.types.is_large_string, pa.types.is_boolean, pa.types.is_null)):
            return column.to_pylist()
    except (pa.ArrowException, ValueError) as err:  # e.g. text that is not UTF-8
        raise LogError(f"column {name!r} cannot be read: {err}", column=name) from None
    hint = (" (convert to seconds, e.g. since the first sample)" if pa.types.is_temporal(kind) else "")
    raise LogError(f"column {name!r} holds {kind} values; the format stores time in seconds and every signal as "
                   f"numbers (float64; integers and numbers as text are converted){hint}", column=name)


def _read_mat(path: Path) -> _Raw:
    variables, declared, meta = _mat_variables(path)
    return _Raw({name: _mat_vector(name, value) for name, value in variables.items()}, declared, meta,
                "the 'units' struct")


def _mat_variables(path: Path) -> tuple[dict[str, Any], dict[str, str], dict[str, Any]]:
    """A .mat file's variables as loadmat(simplify_cells=True) gives them (but 'units' and 'meta'), the units its
    'units' variable declares, and its 'meta'."""
    with path.open("rb") as fh:
        head = fh.read(_HDF5_USERBLOCK + len(_HDF5_SIGNATURE))
        if _HDF5_SIGNATURE in (head[:len(_HDF5_SIGNATURE)], head[_HDF5_USERBLOCK:]):
            variables = _read_mat73(path)
        else:
            try:
                content = checked_mat(fh, os.fstat(fh.fileno()).st_size, max_bytes=_memory_bytes() // 4)
            except MatStructureError as err:
                raise LogError(str(err)) from None
            variables = _loadmat(content)
    units = variables.pop("units", None)
    meta_text = variables.pop("meta", None)
    declared = _mat_units(units)
    if meta_text is not None and not isinstance(meta_text, str):
        raise LogError("variable 'meta' must be a char array of JSON text", column="meta")
    return variables, declared, _json_from(meta_text, "variable 'meta'")


def _loadmat(content: bytes) -> dict[str, Any]:
    """The variables of a v4 or v5/v7 file as :func:`~sim.matcheck.checked_mat` passed it, read by scipy."""
    from scipy.io import loadmat

    try:
        variables = loadmat(io.BytesIO(content), simplify_cells=True)
    except Exception as err:  # what check_mat leaves to scipy fails in Python (e.g. characters that do not decode)
        raise LogError(f"scipy cannot read it: {type(err).__name__}: {err}") from None
    return {k: v for k, v in variables.items() if not k.startswith("__")}


def _read_mat73(path: Path) -> dict[str, Any]:
    """Variables of a v7.3 (HDF5) .mat as loadmat(simplify_cells=True) gives them, read in a child process."""
    if importlib.util.find_spec("h5py") is None:
        raise LogError(f"{path.name} is a MATLAB v7.3 (HDF5) file; reading it needs h5py (pip install h5py), "
                       f"or re-save it as v7 in MATLAB: save('{path.name}', '-v7')", path=path)
    status, variables = _run_parser(_MAT73_SCRIPT, path)
    if status != "ok":
        raise LogError(f"{path.name} is not a readable MATLAB v7.3 (HDF5) file: {variables}", path=path)
    # HDF5 lists names sorted; the column order survives in 'units'
    try:
        order = [name for name in _mat_units(variables.get("units")) if name in variables]
    except LogError:
        order = []  # _read_mat names what is wrong with 'units'
    return {name: variables[name] for name in order + [name for name in variables if name not in order]}


def _run_parser(script: Path, path: Path) -> Any:
    """What ``python -P script path`` pickles to stdout; a LogError if it crashes, fails or takes too long."""
    try:
        done = subprocess.run([sys.executable, "-P", str(script), str(path)], capture_output=True,
                              stdin=subprocess.DEVNULL, timeout=MAT73_TIMEOUT_S)
    except subprocess.TimeoutExpired:
        raise LogError(f"the .mat parser did not finish on {path.name} within MAT73_TIMEOUT_S = "
                       f"{MAT73_TIMEOUT_S:g} s", path=path) from None
    if done.returncode < 0:
        raise LogError(f"the .mat parser crashed on {path.name} ({_signal_name(-done.returncode)})", path=path)
    try:
        return _ArrayUnpickler(io.BytesIO(done.stdout)).load()
    except Exception:  # no or broken output: the parser failed before writing its answer
        last = (done.stderr.decode(errors="replace").strip().splitlines() or ["no output"])[-1]
        raise LogError(f"the .mat parser failed on {path.name} (exit code {done.returncode}): {last}",
                       path=path) from None


def _signal_name(number: int) -> str:
    try:
        return f"signal {number}, {signal.Signals(number).name}"
    except ValueError:
        return f"signal {number}"


class _ArrayUnpickler(pickle.Unpickler):
    """Unpickles builtins and NumPy arrays only: a parser process that a crafted file took over cannot make
    this process run code."""

    ALLOWED = {(module, name) for core in ("numpy._core", "numpy.core")
               for module, name in ((f"{core}.multiarray", "_reconstruct"), (f"{core}.multiarray", "scalar"),
                                    (f"{core}.numeric", "_frombuffer"))} | {("numpy", "ndarray"), ("numpy", "dtype")}

    def find_class(self, module: str, name: str) -> Any:
        if (module, name) not in self.ALLOWED:
            raise pickle.UnpicklingError(f"{module}.{name} is not allowed")
        return super().find_class(module, name)


def _mat_units(units: Any) -> dict[str, str]:
    """The ``units`` variable: a struct (field = column) or an N x 2 cell {column, unit}."""
    if units is None:
        return {}
    if isinstance(units, dict):
        pairs = list(units.items())
    else:
        cells = np.asarray(units, dtype=object)
        if cells.ndim != 2 or cells.shape[1] != 2:
            raise LogError(f"variable 'units' has shape {cells.shape}; expected a struct (field = column name) "
                           f"or an N x 2 cell array {{column, unit}}", column="units")
        pairs = [(k, v) for k, v in cells]
    if not all(isinstance(k, str) and isinstance(v, str) for k, v in pairs):
        raise LogError("variable 'units' must map column names to unit char arrays", column="units")
    return dict(pairs)


def _mat_vector(name: str, value: Any) -> Any:
    if isinstance(value, str):
        raise LogError(f"variable {name!r} is text ({value[:20]!r}); every variable but "
                       f"{' and '.join(map(repr, MAT_RESERVED))} must be a numeric column", column=name)
    if isinstance(value, dict):
        raise LogError(f"variable {name!r} is a struct; every variable but "
                       f"{' and '.join(map(repr, MAT_RESERVED))} must be a numeric column", column=name)
    array = np.asarray(value)
    if array.ndim == 0:  # loadmat(simplify_cells=True) gives a 1 x 1 column as a scalar
        array = array.reshape(1)
    if array.ndim == 2 and 1 in array.shape:
        array = array.ravel()
    if array.ndim != 1:
        raise LogError(f"variable {name!r} has shape {array.shape}; every variable but "
                       f"{' and '.join(map(repr, MAT_RESERVED))} must be an N x 1 column", column=name)
    if array.dtype.kind in "iuf":
        return array.astype(np.float64)
    return list(array)  # logical, cell or char cells: _to_float names the first bad one


def _read_json(path: Path) -> _Raw:
    found = json_records(path)
    header = dict(found.header)
    units_key = "member 'units'"
    declared = _unit_map(_json_object(header.pop("units", {}), units_key), units_key)
    return _Raw(found.fields, declared, header, "the member 'units' beside the records")


_READERS: dict[str, Callable[[Path], _Raw]] = {".csv": _read_csv, ".parquet": _read_parquet, ".mat": _read_mat,
                                               ".json": _read_json}


# ------------------------------------------------------------------------------------------------ JSON records


@dataclass(frozen=True)
class JsonRecords:
    """The records of a JSON log.

    Attributes
    ----------
    fields : dict of str to list
        Field name to its value in every record (None where a record lacks it); fields of nested objects are
        named with dots (``{"pos": {"x": 1}}`` gives ``pos.x``). For a file of columns (an object of equal-length
        lists of numbers), the columns.
    header : dict
        The file's other members, as they are (a list of records has none).
    key : str or None
        The member that holds the records; None when the file is the list itself.
    """

    fields: dict[str, list[Any]]
    header: dict[str, Any]
    key: str | None


def json_records(path: Path, key: str | None = None) -> JsonRecords:
    """The records of the JSON file ``path``: a list of objects, an object with such a list as one member
    (``key`` names it where there are several), or an object of columns (equal-length lists of numbers)."""
    try:
        text = path.read_text(encoding=_text_encoding(path))
    except LogError as err:
        raise err.located(path) from None
    try:
        top = json.loads(text)
    except (ValueError, RecursionError) as err:
        raise LogError(f"{path.name} is not valid JSON ({type(err).__name__}: {err})", path=path) from None
    if isinstance(top, list):
        if key is not None:
            raise LogError(f"records = {key!r}, but the file is a list of records, not an object with members")
        return JsonRecords(_record_fields(top, "the file"), {}, None)
    if not isinstance(top, dict):
        raise LogError(f"the file holds a JSON {type(top).__name__}; a log is a list of records (objects), or an "
                       f"object with such a list as a member")
    lists = [name for name, value in top.items() if _is_record_list(value)]
    if key is not None:
        if not _is_record_list(top.get(key)):
            raise LogError(f"records = {key!r}: the file has no list of records of that name; "
                           + _members_text(top, lists))
        lists = [key]
    if len(lists) == 1:
        name = lists[0]
        return JsonRecords(_record_fields(top[name], f"member {name!r}"),
                           {k: v for k, v in top.items() if k != name}, name)
    if len(lists) > 1:
        raise LogError(f"the file has {len(lists)} lists of records ({', '.join(map(repr, lists))}); name the one "
                       f"to read (records = \"...\" in the rig's [log] table)")
    columns = {name: value for name, value in top.items() if isinstance(value, list) and value
               and not any(isinstance(v, (dict, list)) for v in value)}
    if not columns:
        raise LogError("the file has no list of records (objects) and no columns (lists of numbers); "
                       + _members_text(top, []))
    return JsonRecords(columns, {k: v for k, v in top.items() if k not in columns}, None)


def _is_record_list(value: Any) -> bool:
    return isinstance(value, list) and bool(value) and all(isinstance(v, dict) for v in value)


def _members_text(top: dict[str, Any], lists: list[str]) -> str:
    kinds = {name: ("a list of records" if name in lists else f"a {type(value).__name__}")
             for name, value in list(top.items())[:20]}
    return "its members: " + (", ".join(f"{k!r} ({v})" for k, v in kinds.items()) or "none")


def _record_fields(records: list[Any], where: str) -> dict[str, list[Any]]:
    """Field -> values of a list of records (objects; nested objects flattened with dots)."""
    rows = []
    for i, record in enumerate(records):
        if not isinstance(record, dict):
            raise LogError(f"{where}: record {i + 1} (row {row_of(i)}) is a JSON {type(record).__name__}; every "
                           f"record must be an object", row=row_of(i))
        rows.append(flatten(record))
    names = list(dict.fromkeys(name for row in rows for name in row))
    return {name: [row.get(name) for row in rows] for name in names}


def flatten(value: dict[str, Any], prefix: str = "") -> dict[str, Any]:
    """Nested objects (dicts) as one level, their members named ``outer.inner``."""
    out: dict[str, Any] = {}
    for name, member in value.items():
        if isinstance(member, dict):
            out.update(flatten(member, f"{prefix}{name}."))
        else:
            out[f"{prefix}{name}"] = member
    return out


def _json_object(value: Any, where: str) -> dict[str, Any]:
    if not isinstance(value, dict):
        raise LogError(f"{where} must be a JSON object")
    return value


# ----------------------------------------------------------------------------------- a record's own variables


@dataclass(frozen=True)
class Variables:
    """A record's variables as its file holds them, before they are mapped onto a run log.

    Attributes
    ----------
    values : dict of str to object
        Variable name to its value: a float64 array, a number, or cells as the file has them (text, mixed,
        None). A struct's or a JSON object's members are named with dots (``header.mass``).
    declared : dict of str to str
        The unit the file itself gives a variable (CSV sidecar, Parquet metadata, .mat 'units', JSON 'units').
    meta : dict
        The file's meta (Parquet and .mat 'meta').
    """

    values: dict[str, Any]
    declared: dict[str, str]
    meta: dict[str, Any]


def read_variables(path: str | Path, *, records: str | None = None) -> Variables:
    """The variables of a record file of any readable format, unvalidated: the columns of a CSV or Parquet file,
    the variables of a .mat (scalars too), the fields of a JSON log's records and the members beside them.

    ``records`` names the member of a JSON object that holds the records, where it has several. The file is only
    read. Raises :class:`LogError` (naming the file) where the file cannot be read.
    """
    path = Path(path)
    suffix = _suffix(path)
    _reader(path)
    try:
        if suffix == ".mat":
            values, declared, meta = _mat_variables(path)
            return Variables(flatten(values), declared, meta)
        if suffix == ".json":
            found = json_records(path, records)
            header = dict(found.header)
            declared = _unit_map(_json_object(header.pop("units", {}), "member 'units'"), "member 'units'")
            return Variables({**flatten(header), **found.fields}, declared, {})
        if records is not None:
            raise LogError(f"records = {records!r} names a member of a JSON log; {path.name} is not JSON")
        raw = _READERS[suffix](path)
        return Variables(raw.columns, raw.declared, raw.meta)
    except LogError as err:
        raise err.located(path) from None


def _json_from(text: bytes | str | None, where: str) -> dict[str, Any]:
    """The JSON object in ``text`` ({} for None); ``where`` names it in messages."""
    if text is None:
        return {}
    try:
        value = json.loads(text)
    except (ValueError, RecursionError) as err:  # JSONDecodeError, UnicodeDecodeError, too many digits, nesting
        raise LogError(f"{where} is not valid JSON ({type(err).__name__}: {err})") from None
    if not isinstance(value, dict):
        raise LogError(f"{where} must be a JSON object")
    return value


def _unit_map(value: dict[str, Any], where: str) -> dict[str, str]:
    """``value`` if it maps column names to unit strings, else a LogError naming ``where``."""
    if not all(isinstance(k, str) and isinstance(v, str) for k, v in value.items()):
        raise LogError(f'{where} must map column names to unit strings, e.g. {{"tau_flexure": "N·m"}}')
    return value


# ------------------------------------------------------------------------------------------------- validation


def _check_columns(names: Sequence[str], declared: set[str], where: str) -> None:
    """Misspelt standard names, missing required columns, no output-side column."""
    lowered = {name.lower(): name for name in STANDARD_UNITS}
    for name in names:
        if name in STANDARD_UNITS or name in declared:
            continue
        close = difflib.get_close_matches(name.lower(), list(lowered), n=1, cutoff=TYPO_CUTOFF)
        if close:
            raise LogError(f"unknown column {name!r}: did you mean {lowered[close[0]]!r}? (to keep a column of "
                           f"this name, declare its unit in {where})", column=name, row=1)
    for name in REQUIRED_COLUMNS:
        if name not in names:
            close = difflib.get_close_matches(name, list(names), n=1, cutoff=0.6)
            hint = f"; is {close[0]!r} meant to be it?" if close else ""
            raise LogError(f"missing required column {name!r} [{STANDARD_UNITS[name]}]{hint}", column=name)
    if not any(name in names for name in OUTPUT_COLUMNS):
        raise LogError(f"the log needs at least one of the columns {', '.join(map(repr, OUTPUT_COLUMNS))}; it has "
                       f"{', '.join(map(repr, names))}")


def _units(names: Sequence[str], declared: dict[str, str], standard: dict[str, str], joint: str,
           where: str) -> dict[str, str]:
    """Unit of every column: the joint's for standard names (a declared one must agree), else declared."""
    units: dict[str, str] = {}
    unknown = []
    for name in names:
        unit = declared.get(name)
        if unit is not None:
            unit = UNIT_ALIASES.get(unit.strip(), unit.strip())
        if name in standard:
            if unit is not None and unit != standard[name]:
                other = "slide" if joint == "hinge" else "hinge"
                hint = (f"; for a {other} joint pass joint={other!r}"
                        if unit == joint_units(other)[name] else "")
                raise LogError(f"column {name!r} is in {unit!r} according to {where}; the format fixes "
                               f"{standard[name]!r} for joint={joint!r}{hint}", column=name)
            units[name] = standard[name]
        elif unit is not None:
            units[name] = unit
        else:
            units[name] = UNKNOWN_UNIT
            unknown.append(name)
    if unknown:
        warnings.warn(f"column(s) {', '.join(map(repr, unknown))} are not in the format and have no unit; kept "
                      f"with unit {UNKNOWN_UNIT!r} (declare their units in {where})", LogWarning, stacklevel=3)
    return units


def _is_number(cell: Any) -> bool:
    try:
        cell_to_float(cell)
    except (TypeError, ValueError):
        return False
    return True


def cell_to_float(cell: Any) -> float:
    """A cell of a file as a float: text matching :data:`NUMBER`, or a real number; TypeError or ValueError else."""
    if isinstance(cell, str):
        if not NUMBER.fullmatch(cell):
            raise ValueError(cell)
        return float(cell)  # 'nan' and 'inf' are refused later, as non-finite
    if isinstance(cell, (bool, np.bool_)) or cell is None:
        raise TypeError(type(cell).__name__)
    array = np.asarray(cell)
    if array.size != 1 or array.dtype.kind not in "iuf":
        raise TypeError(array.dtype.name)
    return float(array.reshape(()))


def _to_float(name: str, values: Any) -> np.ndarray:
    """The column as float64, or a LogError naming the first cell that is not a number."""
    if isinstance(values, np.ndarray) and values.dtype.kind in "iuf":
        return values.astype(np.float64)
    if all(isinstance(cell, str) and NUMBER.fullmatch(cell) for cell in values):
        return np.array(values, dtype=np.float64)  # NumPy parses text with correct rounding, like float()
    out = np.empty(len(values))
    for i, cell in enumerate(values):
        try:
            out[i] = cell_to_float(cell)
        except (TypeError, ValueError):
            what = "empty cell" if cell is None or (isinstance(cell, str) and not cell.strip()) else (
                f"{cell!r} is not a number")
            raise LogError(f"column {name!r}, row {row_of(i)}: {what}", column=name, row=row_of(i)) from None
    return out


def _rows(indices: np.ndarray) -> str:
    shown = ", ".join(str(row_of(int(i))) for i in indices[:FIRST_FEW])
    return shown + (", ..." if len(indices) > FIRST_FEW else "")


def check_samples(columns: dict[str, np.ndarray], *, max_jitter: float, first: int = 0) -> None:
    """Equal lengths, length, finiteness, strictly increasing ``time``, regular sampling.

    ``first`` is the index in the file of the columns' first sample (a part of a record), for the rows named.
    """
    n = len(columns["time"])
    for name, values in columns.items():
        if len(values) != n:
            raise LogError(f"column {name!r} has {len(values)} samples; 'time' has {n}", column=name,
                           row=row_of(first + min(len(values), n)))
    if n < MIN_SAMPLES:
        raise LogError(f"the log has {n} sample(s); at least {MIN_SAMPLES} are needed (the sampling "
                       f"check compares steps with the median step)")
    for name, values in columns.items():
        bad = np.flatnonzero(~np.isfinite(values)) + first
        if len(bad):
            raise LogError(f"column {name!r}: {len(bad)} value(s) NaN or infinite, at rows {_rows(bad)}",
                           column=name, row=row_of(int(bad[0])))
    time = columns["time"]
    dt = np.diff(time)
    back = np.flatnonzero(dt <= 0) + 1
    if len(back):
        i = int(back[0])
        now, before = float(time[i]), float(time[i - 1])
        raise LogError(f"column 'time', row {row_of(first + i)}: {now:.9g} s does not exceed {before:.9g} s of row "
                       f"{row_of(first + i - 1)}; time must increase strictly ({len(back)} such row(s): "
                       f"{_rows(back + first)})", column="time", row=row_of(first + i))
    if math.isinf(max_jitter):
        return
    median = float(np.median(dt))
    deviation = np.abs(dt - median) / median
    irregular = np.flatnonzero(deviation > max_jitter) + 1
    if len(irregular):
        i = int(irregular[0])
        raise LogError(f"column 'time', row {row_of(first + i)}: the step {dt[i - 1]:.6g} s from row "
                       f"{row_of(first + i - 1)} deviates {100 * deviation[i - 1]:.3g} % from the median step "
                       f"{median:.6g} s; max_jitter = {100 * max_jitter:.3g} % ({len(irregular)} such step(s), at "
                       f"rows {_rows(irregular + first)}); a record sampled irregularly can be put on a uniform "
                       f"grid with --log resample=STEP (or resample in the rig's [log] table)",
                       column="time", row=row_of(first + i))


def _reader(path: Path) -> Callable[[Path], _Raw]:
    """The reader of ``path``'s format; a LogError if it is not a file or its suffix names no format."""
    if path.is_dir():
        raise LogError(f"{path} is a directory; give a log file ({', '.join(_READERS)})", path=path)
    if not path.exists():
        raise LogError(f"{path} does not exist", path=path)
    reader = _READERS.get(_suffix(path))
    if reader is None:
        raise LogError(f"cannot read {path.name!r}: unknown suffix {path.suffix!r}; use one of "
                       f"{', '.join(_READERS)}", path=path)
    return reader


def _suffix(path: Path) -> str:
    return path.suffix.lower()
