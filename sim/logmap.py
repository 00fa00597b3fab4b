"""A drive's own record read as a run log: which variable is which column, units, scales, sampling, spans.

A :class:`LogMap` is the ``[log]`` table of a rig file (``docs/own_logs.md``) or the same given as command-line
options (``--log KEY=VALUE``)::

    [log]
    records = "samples"                # JSON: the member holding the records (found alone if only one)
    resample = "5 ms"                  # put an irregularly sampled record on a uniform grid
    interpolation = "linear"           # or "previous": each sample held until the next
    max_gap = "50 ms"                  # refuse a record with a longer gap (default: 5 grid steps)
    enable = "torque_enable"           # keep the samples where this is nonzero; each span is a record
    columns = {time = "t", tau_cmd = "vir * gtau", q = "-qm"}
    units = {time = "ms", q = "mm"}    # the unit of each column's expression, converted to the column's
    twos_complement = {pwm = 16}       # integer variables stored as unsigned counts: their bits

A column's expression combines the file's variables (a column, a .mat scalar, a JSON header member ``a.b``;
a name that is not an identifier goes in backticks) and numbers with ``+ - * /`` and parentheses. A run-log
column the map does not name is taken from the variable of that name, when the file has one. Units are
converted by pint (its unit names: ``deg``, ``mm``, ``ms``, ``mN·m``, ``%``, ``rpm`` ...).

:func:`read_mapped` reads a file with a map and returns its records as run logs, with a line for everything it
did (the jitter it found, the spans it cut), so that nothing is done silently. The file is only read.
"""

from __future__ import annotations

import ast
import difflib
import math
import re
import tomllib
import warnings
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from functools import cache
from pathlib import Path
from typing import Any

import numpy as np

from sim.logio import (
    MIN_SAMPLES,
    OUTPUT_COLUMNS,
    UNIT_ALIASES,
    LogError,
    SlideRunLog,
    cell_to_float,
    check_samples,
    joint_units,
    read_variables,
    row_of,
)
from sim.params import did_you_mean
from sim.runlog import RunLog

INTERPOLATIONS = ("linear", "previous")
DEFAULT_GAP_STEPS = 5  # a gap longer than this many grid steps is refused unless max_gap says otherwise
MIN_SPAN_SAMPLES = 50  # an enabled span shorter than this is left out (and named)
KEYS = ("columns", "units", "twos_complement", "records", "resample", "interpolation", "max_gap", "enable")
MAX_BITS = 53  # a count is read as a float64, which holds every integer up to 2**53 exactly
MAX_UPSAMPLING = 100  # a resampling grid of more than this many times the record's samples is refused
MAX_UNIT_TEXT = 100  # characters of a unit or a duration

# what a wrong unit's message offers, by the dimension of the column
COMMON_UNITS: dict[str, tuple[str, ...]] = {
    "s": ("s", "ms", "us", "ns", "min"),
    "rad": ("rad", "deg", "mrad", "turn", "arcmin"),
    "rad/s": ("rad/s", "deg/s", "rpm", "turn/s"),
    "m": ("m", "mm", "um", "cm", "inch"),
    "m/s": ("m/s", "mm/s", "cm/s"),
    "N·m": ("N·m", "mN·m", "kN·m", "N·mm", "ozf·in", "lbf·ft"),
    "N": ("N", "mN", "kN", "kgf", "lbf"),
    "°C": ("°C", "K", "degF"),
    "V": ("V", "mV"),
}


class LogMapError(ValueError):
    """A ``[log]`` table or ``--log`` option that is not valid; the message names the key."""


@dataclass(frozen=True)
class LogMap:
    """How a record file becomes a run log. See the module docstring for the keys.

    Attributes
    ----------
    columns : dict of str to str
        Run-log column -> expression of the file's variables.
    units : dict of str to str
        Run-log column -> unit of its expression's value (pint's names).
    twos_complement : dict of str to int
        Variable -> bits of the unsigned count it is stored as.
    records : str or None
        The JSON member that holds the records.
    resample_s : float or None
        Grid step [s] of a uniform resampling; None keeps the file's sampling (checked for jitter).
    interpolation : {'linear', 'previous'}
    max_gap_s : float or None
        Longest accepted step of the record before resampling [s]; None is ``DEFAULT_GAP_STEPS`` grid steps.
    enable : str or None
        Expression that is nonzero where the drive's torque is on.
    """

    columns: dict[str, str] = field(default_factory=dict)
    units: dict[str, str] = field(default_factory=dict)
    twos_complement: dict[str, int] = field(default_factory=dict)
    records: str | None = None
    resample_s: float | None = None
    interpolation: str = "linear"
    max_gap_s: float | None = None
    enable: str | None = None

    def to_dict(self) -> dict[str, Any]:
        """The ``[log]`` table that :func:`log_map_from_dict` reads back to this map."""
        out: dict[str, Any] = {}
        for key in ("records", "enable"):
            if getattr(self, key) is not None:
                out[key] = getattr(self, key)
        if self.resample_s is not None:
            out["resample"] = f"{self.resample_s!r} s"
            out["interpolation"] = self.interpolation
        if self.max_gap_s is not None:
            out["max_gap"] = f"{self.max_gap_s!r} s"
        for key in ("columns", "units", "twos_complement"):
            if getattr(self, key):
                out[key] = dict(getattr(self, key))
        return out


@dataclass(frozen=True)
class MappedRecord:
    """A record file read with a :class:`LogMap`.

    Attributes
    ----------
    logs : tuple of RunLog
        One run log per enabled span (one for a record without ``enable``), in time order.
    notes : tuple of str
        What was done to the record, one line each (mapping, units, spans cut, resampling and the jitter found).
    """

    logs: tuple[RunLog, ...]
    notes: tuple[str, ...]


# ------------------------------------------------------------------------------------------------ the table


def log_map_from_dict(data: Any) -> LogMap:
    """Validate a ``[log]`` table (a dict as TOML gives it); a LogMapError names the key at fault."""
    if not isinstance(data, dict):
        raise LogMapError("[log] must be a table")
    for key in data:
        if key not in KEYS:
            raise LogMapError(f"[log] has no key {key!r}{did_you_mean(key, KEYS)}; valid keys: {', '.join(KEYS)}")
    columns = _string_table(data, "columns")
    for name, expression in columns.items():
        _parse(expression, f"columns.{name}")
    units = _string_table(data, "units")
    for name, unit in units.items():
        if unit.strip():
            _pint_unit(unit, f"units.{name}")
    bits = data.get("twos_complement", {})
    if not isinstance(bits, dict) or not all(isinstance(b, int) and not isinstance(b, bool) for b in bits.values()):
        raise LogMapError(f"twos_complement = {bits!r}: expected a table of variable = bits, e.g. {{pwm = 16}}")
    for name, b in bits.items():
        if not 2 <= b <= MAX_BITS:
            raise LogMapError(f"twos_complement.{name} = {b}: valid range [2, {MAX_BITS}] bits (counts are read as "
                              f"float64, exact up to 2**{MAX_BITS})")
    records = _optional_string(data, "records")
    enable = _optional_string(data, "enable")
    if enable is not None:
        _parse(enable, "enable")
    interpolation = data.get("interpolation", "linear")
    if interpolation not in INTERPOLATIONS:
        raise LogMapError(f"interpolation = {interpolation!r}: valid values are {', '.join(map(repr, INTERPOLATIONS))}")
    resample = _duration(data, "resample")
    max_gap = _duration(data, "max_gap")
    if "interpolation" in data and resample is None:
        raise LogMapError("interpolation is given without resample: say the grid step, e.g. resample = \"5 ms\"")
    return LogMap(columns, units, dict(bits), records, resample, interpolation, max_gap, enable)


def with_options(data: dict[str, Any], options: Sequence[str]) -> dict[str, Any]:
    """``data`` (a ``[log]`` table) with command-line options ``KEY=VALUE`` laid over it.

    KEY is a key of the table or ``columns.NAME``, ``units.NAME``, ``twos_complement.NAME``. VALUE is text
    (``vir * gtau``, ``5 ms``, or quoted as TOML: ``"vir * gtau"``); a number where the key takes one
    (``twos_complement.pwm=16``, ``resample=0.005`` seconds).
    """
    out = {key: dict(value) if isinstance(value, dict) else value for key, value in data.items()}
    for option in options:
        key, sep, text = option.partition("=")
        key = key.strip()
        if not sep or not key:
            raise LogMapError(f"{option!r}: expected KEY=VALUE, e.g. --log columns.tau_cmd='vir * gtau'")
        try:
            parsed = tomllib.loads(f"v = {text}")
        except (ValueError, RecursionError):  # TOMLDecodeError; too many digits; nested too deep
            parsed = {}
        value = parsed["v"] if list(parsed) == ["v"] else text.strip()  # 'a\nb = 1' is text, not two keys
        table, dot, name = key.partition(".")
        numeric = table == "twos_complement" or key in ("resample", "max_gap")
        if not isinstance(value, str) and not (numeric and isinstance(value, (int, float))):
            value = text.strip()  # enable=true, records=2024: names, as typed
        if dot:
            tables = ("columns", "units", "twos_complement")
            if table not in tables or not name:
                raise LogMapError(f"{option!r}: {table!r} has no members{did_you_mean(table.lower(), tables)}; "
                                  f"tables: {', '.join(tables)}")
            if not isinstance(out.setdefault(table, {}), dict):
                raise LogMapError(f"{option!r}: {table} = {out[table]!r} is not a table to set a member of")
            out[table][name] = value
        else:
            out[key] = value
    return out


def _string_table(data: dict[str, Any], key: str) -> dict[str, str]:
    table = data.get(key, {})
    if not isinstance(table, dict):
        raise LogMapError(f"{key} = {table!r}: expected a table of names to strings")
    for name, value in table.items():
        if not isinstance(value, str):
            raise LogMapError(f"{key}.{name} = {value!r}: expected text, e.g. {key}.{name} = \"...\"")
    return dict(table)


def _optional_string(data: dict[str, Any], key: str) -> str | None:
    value = data.get(key)
    if value is not None and not (isinstance(value, str) and value.strip()):
        raise LogMapError(f"{key} = {value!r}: expected a name (text)")
    return value


def _duration(data: dict[str, Any], key: str) -> float | None:
    """A duration given as text with a unit ("5 ms") or a number of seconds, in seconds."""
    value = data.get(key)
    if value is None:
        return None
    if isinstance(value, (int, float)) and not isinstance(value, bool):
        seconds = float(value) if abs(value) < 1e308 else math.inf  # an int too large for a float
    elif isinstance(value, str):
        text = _pint_text(value, key)
        try:
            quantity = _registry().Quantity(text)
            seconds = float(quantity.to("s").magnitude)
        except Exception as err:  # pint raises its own errors and ValueError, AttributeError on odd text
            raise LogMapError(f"{key} = {value!r} is not a duration ({type(err).__name__}); e.g. \"5 ms\"") from None
    else:
        raise LogMapError(f"{key} = {value!r}: expected a duration, e.g. \"5 ms\"")
    if not (math.isfinite(seconds) and seconds > 0):
        raise LogMapError(f"{key} = {value!r}: a duration must be positive and finite")
    return seconds


# ------------------------------------------------------------------------------------------------- expressions

# a backticked name, or a word with a character beyond ASCII (which Python's parser would change to its NFKC
# form: 'µ' to 'μ', 'ﬁ' to 'fi'): both are kept as written
_BACKTICKED = re.compile(r"`([^`]*)`|(\w*[^\W\x00-\x7f]\w*)")
_NODES = (ast.Expression, ast.BinOp, ast.UnaryOp, ast.Constant, ast.Name, ast.Attribute, ast.Load, ast.Add,
          ast.Sub, ast.Mult, ast.Div, ast.USub, ast.UAdd)


@dataclass(frozen=True)
class _Expression:
    text: str
    tree: ast.Expression
    quoted: dict[str, str]  # placeholder identifier -> the backticked name

    def names(self) -> list[str]:
        """The variables the expression reads, in order of appearance."""
        out: list[str] = []

        def visit(node: ast.AST) -> None:
            if isinstance(node, (ast.Name, ast.Attribute)):
                out.append(_name_of(node, self.quoted))
            else:
                for child in ast.iter_child_nodes(node):
                    visit(child)

        visit(self.tree)
        return list(dict.fromkeys(out))


MAX_EXPRESSION = 500  # characters


def _parse(text: str, where: str) -> _Expression:
    """Parse ``text`` as an expression of names and numbers with + - * / and parentheses."""
    quoted: dict[str, str] = {}

    def placeholder(match: re.Match) -> str:
        key = f"_v{len(quoted)}_"
        while key in text:  # a name of the expression itself
            key += "_"
        quoted[key] = match.group(1) if match.group(1) is not None else match.group(2)
        return key

    tree = None
    if len(text) <= MAX_EXPRESSION:
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", SyntaxWarning)  # '0x1for' warns, then is refused below
                tree = ast.parse(_BACKTICKED.sub(placeholder, text).strip(), mode="eval")
        except (SyntaxError, ValueError, RecursionError, MemoryError):
            tree = None
    if tree is None or not all(_allowed(node) for node in ast.walk(tree)):
        raise LogMapError(f"{where} = {text[:80]!r} is not an expression of variables and numbers with + - * / and "
                          f"parentheses, at most {MAX_EXPRESSION} characters (a name that is not an identifier "
                          f"goes in backticks: `pos (deg)`)")
    return _Expression(text, tree, quoted)


def _allowed(node: ast.AST) -> bool:
    if isinstance(node, ast.Constant):
        return _is_plain_number(node.value)
    if isinstance(node, ast.Attribute):  # a dotted name: a.b.c
        return isinstance(node.value, (ast.Name, ast.Attribute))
    return isinstance(node, _NODES)


def _is_plain_number(value: Any) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool)


def _name_of(node: ast.AST, quoted: dict[str, str]) -> str:
    if isinstance(node, ast.Name):
        return quoted.get(node.id, node.id)
    if isinstance(node, ast.Attribute):
        return f"{_name_of(node.value, quoted)}.{quoted.get(node.attr, node.attr)}"
    raise LogMapError(f"{ast.dump(node)} is not a name")


def _evaluate(expression: _Expression, lookup: Callable[[str], Any]) -> Any:
    def value(node: ast.AST) -> Any:
        if isinstance(node, ast.Expression):
            return value(node.body)
        if isinstance(node, ast.Constant):
            return float(node.value)
        if isinstance(node, (ast.Name, ast.Attribute)):
            return lookup(_name_of(node, expression.quoted))
        if isinstance(node, ast.UnaryOp):
            return -value(node.operand) if isinstance(node.op, ast.USub) else value(node.operand)
        left, right = value(node.left), value(node.right)  # ast.BinOp
        if np.ndim(left) and np.ndim(right) and np.shape(left) != np.shape(right):
            raise LogMapError(f"{expression.text[:80]!r} combines variables of {len(left)} and {len(right)} samples")
        op = type(node.op)
        return {ast.Add: np.add, ast.Sub: np.subtract, ast.Mult: np.multiply, ast.Div: np.divide}[op](left, right)

    with np.errstate(all="ignore"):  # an overflow or a division by zero is refused as a non-finite value
        try:
            return value(expression.tree)
        except (OverflowError, RecursionError):  # a number too large for a float; an expression nested too deep
            raise LogMapError(f"{expression.text[:80]!r} cannot be evaluated (too large or nested too deep)") from None


# ------------------------------------------------------------------------------------------------------ units


@cache
def _registry() -> Any:
    import pint

    return pint.UnitRegistry()


_TORQUE_TYPED = re.compile(r"^\s*([a-zµμ]?)N\s*[ .*·⋅]?\s*m\s*$")  # Nm, mNm, N.m, kN m: a torque, not nN·m etc.


def _normalised(unit: str) -> str:
    """A unit as pint reads it: the run-log format's ASCII spellings and typed torques made explicit."""
    unit = UNIT_ALIASES.get(unit.strip(), unit.strip())
    match = _TORQUE_TYPED.match(unit)
    if match:
        unit = f"{match.group(1)}N*m"
    return unit.replace("·", "*").replace("⋅", "*").replace("µ", "u").replace("μ", "u")


_SMALL_EXPONENT = re.compile(r"\s*\(?\s*[-+]?\s*(\d{1,2}(\.\d*)?|\.\d+)\s*\)?(?![\d.eE(]|\s*\*\*)")


def _pint_text(text: str, where: str) -> str:
    """``text`` (a unit or a duration) normalised for pint; a LogMapError if it is long or raises something to
    a power other than a short number: pint computes integer powers exactly, and 9**9**9 takes hours."""
    import pint

    if len(text) <= MAX_UNIT_TEXT:
        normalised = _normalised(text)
        processed = pint.util.string_preprocessor(normalised)  # '^', '²' and 'squared' become '**'
        if not any(_big_power(processed, power.start()) for power in re.finditer(r"\*\*", processed)):
            return normalised
    raise LogMapError(f"{where} = {text[:80]!r}: expected at most {MAX_UNIT_TEXT} characters, with powers only of a "
                      f"name or a number and to a number of one or two digits (m/s**2, s^-1)")


def _big_power(text: str, at: int) -> bool:
    """Whether the power operator at ``at`` raises a parenthesised group, or raises to more than a short number."""
    return text[:at].rstrip().endswith(")") or not _SMALL_EXPONENT.match(text, at + 2)


def _pint_unit(unit: str, where: str) -> Any:
    registry = _registry()
    text = _pint_text(unit, where)
    try:
        return registry.Unit(text)
    except Exception:  # pint's UndefinedUnitError, DefinitionSyntaxError, ValueError, AssertionError ...
        known = sorted({u for units in COMMON_UNITS.values() for u in units} | {"%", "count"})
        close = difflib.get_close_matches(unit.strip(), known, n=1, cutoff=0.6)
        hint = f"; did you mean {close[0]!r}?" if close else ""
        raise LogMapError(f"{where} = {unit!r} is not a unit pint knows{hint} (e.g. {', '.join(known[:12])}, ...)"
                          ) from None


def _root(unit: Any) -> Any:
    return _registry().get_root_units(unit)[1]


def _converted(values: np.ndarray, unit: str, target: str, column: str) -> np.ndarray:
    """``values`` in ``unit`` converted to ``target``; a LogMapError naming the column if they do not agree."""
    source, goal = _pint_unit(unit, f"units.{column}"), _pint_unit(target, column)
    if _root(source) != _root(goal):
        examples = ", ".join(COMMON_UNITS.get(target, (target,)))
        raise LogMapError(f"units.{column} = {unit!r} is not a unit of {column!r} [{target}]: accepted are units of "
                          f"the same kind, e.g. {examples}")
    return np.asarray(_registry().Quantity(values, source).to(goal).magnitude, dtype=np.float64)


# ---------------------------------------------------------------------------------------------------- reading


def read_mapped(path: str | Path, log_map: LogMap, *, joint: str = "hinge", max_jitter: float = 0.05) -> MappedRecord:
    """Read the record file ``path`` as run logs with ``log_map``.

    Parameters
    ----------
    path : str or Path
        A CSV, Parquet, .mat or JSON file; only read.
    log_map : LogMap
    joint : {'hinge', 'slide'}
        Sets the units the run-log columns are converted to.
    max_jitter : float
        As for :func:`sim.logio.read_log`, where the map does not resample [1].

    Returns
    -------
    MappedRecord
        The run logs (one per enabled span) and a line for each thing done to the record.

    Raises
    ------
    LogError
        The file cannot be read or the map does not fit it; the message starts with the file's name and names
        the variable, the column and the row where it can.
    """
    path = Path(path)
    try:
        return _mapped(path, log_map, joint, max_jitter)
    except LogMapError as err:
        raise LogError(f"{path.name}: {err}", path=path) from None
    except LogError as err:
        raise err.located(path) from None


def _mapped(path: Path, log_map: LogMap, joint: str, max_jitter: float) -> MappedRecord:
    found = read_variables(path, records=log_map.records)
    units = joint_units(joint)
    variables = _Lookup(found.values, log_map.twos_complement)
    expressions = {name: _parse(text, f"columns.{name}") for name, text in log_map.columns.items()}
    for name in units:  # a variable of a column's name, unless it is one number or text (a header's member)
        if name not in expressions and isinstance(found.values.get(name), (list, tuple, np.ndarray)):
            expressions[name] = _parse(f"`{name}`", name)
    if "time" not in expressions:
        raise LogMapError(f"no variable is mapped to 'time' [s] and the file has none of that name; "
                          f"{variables.listing()}")
    notes = []
    columns: dict[str, np.ndarray] = {}
    column_units: dict[str, str] = {}
    for name, expression in expressions.items():
        values = np.asarray(_evaluate(expression, variables.get), dtype=np.float64)
        if values.ndim == 0:
            raise LogMapError(f"columns.{name} = {expression.text!r} is a constant ({float(values):.6g}); a column "
                              f"needs a variable that changes from sample to sample")
        unit = log_map.units.get(name) or _declared_unit(expression, found.declared)
        if name in units:
            if unit and unit.strip():
                values = _converted(values, unit, units[name], name)
            column_units[name] = units[name]
        elif unit:
            column_units[name] = unit.strip()
        else:
            raise LogMapError(f"columns.{name}: {name!r} is not a run-log column ({', '.join(units)}); give its "
                              f"unit, e.g. units.{name} = \"%\"")
        columns[name] = values
        if name in log_map.columns or unit:
            shown = expression.text if name in log_map.columns else name
            notes.append(f"{name} [{column_units[name]}] = {shown}"
                         + (f" [{unit}]" if unit and unit != column_units[name] else "")
                         + variables.scalars_text(expression))
    unused = [name for name in log_map.units if name not in columns]
    if unused:
        raise LogMapError(f"units.{unused[0]} is given, but no column {unused[0]!r} is mapped or in the file")
    n = len(columns["time"])
    for name, values in columns.items():
        if len(values) != n:
            raise LogMapError(f"column {name!r} has {len(values)} samples; 'time' has {n}")
    for name, what in (("tau_cmd", "the commanded effort"), ("q", "the position")):
        if name not in columns and (name == "tau_cmd" or not any(c in columns for c in OUTPUT_COLUMNS)):
            raise LogMapError(f"no variable is mapped to {name!r} ({what}, {units[name]}) and the file has none of "
                              f"that name: columns.{name} = \"...\"; {variables.listing()}")
    spans = [(0, n)]
    if log_map.enable is not None:
        enabled = np.asarray(_evaluate(_parse(log_map.enable, "enable"), variables.get), dtype=np.float64)
        if enabled.shape != (n,):
            raise LogMapError(f"enable = {log_map.enable!r} is not a variable with one value per sample")
        spans, note = _enabled_spans(enabled, columns["time"], log_map.enable)
        notes.append(note)
    logs, span_notes = [], []
    for k, (start, stop) in enumerate(spans):
        part = {name: values[start:stop] for name, values in columns.items()}
        own = []
        if log_map.resample_s is not None:
            part, note = _resampled(part, log_map, start)
            own.append(note if len(spans) == 1 else f"span {k + 1}: {note}")
        else:
            check_samples(part, max_jitter=max_jitter, first=start)
        span_notes += own
        meta = {**found.meta, "mapping": {"file": path.name, "notes": notes + own, "span": k + 1,
                                          "spans": len(spans), "first_sample": start,
                                          "resampled_s": log_map.resample_s}}
        logs.append((SlideRunLog if joint == "slide" else RunLog)(part, dict(column_units), meta))
    return MappedRecord(tuple(logs), tuple(notes + span_notes))


def _declared_unit(expression: _Expression, declared: dict[str, str]) -> str | None:
    """The unit the file declares for an expression that is one variable."""
    names = expression.names()
    if len(names) == 1 and isinstance(expression.tree.body, (ast.Name, ast.Attribute)):
        return declared.get(names[0])
    return None


class _Lookup:
    """The file's variables as numbers, converted on first use; errors name the variable and the row."""

    def __init__(self, values: dict[str, Any], bits: dict[str, int]) -> None:
        self.values, self.bits, self.cache = values, bits, {}
        missing = [name for name in bits if name not in values]
        if missing:
            raise LogMapError(f"twos_complement.{missing[0]}: the file has no variable {missing[0]!r}; "
                              f"{self.listing(missing[0])}")

    def listing(self, near: str | None = None) -> str:
        names = list(self.values)
        hint = did_you_mean(near, names) if near else ""
        shown = ", ".join(names[:40]) + (f", ... ({len(names)} in all)" if len(names) > 40 else "")
        return f"its variables: {shown}{hint}"

    def get(self, name: str) -> Any:
        if name not in self.cache:
            if name not in self.values:
                raise LogMapError(f"the file has no variable {name!r}{did_you_mean(name, list(self.values))}; "
                                  f"{self.listing()}")
            value = _numbers(name, self.values[name])
            if name in self.bits:
                value = _signed(name, value, self.bits[name])
            self.cache[name] = value
        return self.cache[name]

    def scalars_text(self, expression: _Expression) -> str:
        scalars = [(name, self.cache[name]) for name in expression.names()
                   if name in self.cache and np.ndim(self.cache[name]) == 0]
        return "".join(f", {name} = {float(value):.6g}" for name, value in scalars)


def _numbers(name: str, value: Any) -> Any:
    """A variable as a float or a 1-D float64 array; a LogError naming the variable and row otherwise."""
    if isinstance(value, (np.ndarray, np.generic)) and np.ndim(value) == 0:
        value = value.item()  # a v7.3 .mat's scalar dataset, a NumPy scalar: the Python number (or text, None)
    if isinstance(value, np.ndarray) and value.dtype.kind in "iuf" and value.size >= 1:
        if value.size == 1:
            return float(value.reshape(-1)[0])
        if value.ndim > 1 and sum(d > 1 for d in value.shape) > 1:
            raise LogMapError(f"variable {name!r} has shape {value.shape}; a column is a vector")
        return value.reshape(-1).astype(np.float64)
    if isinstance(value, (bool, np.bool_)):
        return float(value)
    if _is_plain_number(value):
        try:
            return float(value)
        except OverflowError:
            raise LogMapError(f"variable {name!r} = {value} is too large for a float") from None
    if isinstance(value, (list, tuple, np.ndarray)) and len(value) > 0:
        cells = list(np.ravel(np.asarray(value, dtype=object))) if isinstance(value, np.ndarray) else list(value)
        out = np.empty(len(cells))
        for i, cell in enumerate(cells):
            try:
                out[i] = float(cell) if isinstance(cell, (bool, np.bool_)) else cell_to_float(cell)
            except (TypeError, ValueError, OverflowError):
                what = "empty" if cell is None or (isinstance(cell, str) and not cell.strip()) else (
                    f"{str(cell)[:40]!r}, not a number")
                raise LogError(f"variable {name!r}, row {row_of(i)}: {what}", column=name, row=row_of(i)) from None
        return out
    kind = ("text" if isinstance(value, str) else "empty" if value is None or np.size(value) == 0
            else type(value).__name__)
    raise LogMapError(f"variable {name!r} is {kind}, not a number or a column of numbers")


def _signed(name: str, values: Any, bits: int) -> Any:
    """Unsigned ``bits``-bit counts read as two's complement."""
    array = np.atleast_1d(np.asarray(values, dtype=np.float64))
    top = 2.0 ** bits
    bad = np.flatnonzero(~((array >= 0) & (array < top) & (array == np.round(array))))
    if len(bad):
        i = int(bad[0])
        raise LogError(f"variable {name!r}, row {row_of(i)}: {array[i]:.6g} is not an unsigned {bits}-bit count "
                       f"(an integer from 0 to {int(top) - 1}), as twos_complement.{name} = {bits} says",
                       column=name, row=row_of(i))
    signed = np.where(array >= top / 2, array - top, array)
    return float(signed[0]) if np.ndim(values) == 0 else signed


def _enabled_spans(enabled: np.ndarray, time: np.ndarray, expression: str) -> tuple[list[tuple[int, int]], str]:
    """Index ranges [start, stop) where ``enabled`` is nonzero, long enough to analyse, and a note of the cut."""
    on = np.isfinite(enabled) & (enabled != 0)
    edges = np.flatnonzero(np.diff(np.concatenate(([0], on.astype(np.int8), [0]))))
    runs = list(zip(edges[::2].tolist(), edges[1::2].tolist(), strict=True))
    kept = [(a, b) for a, b in runs if b - a >= MIN_SPAN_SAMPLES]
    short = [(a, b) for a, b in runs if b - a < MIN_SPAN_SAMPLES]

    def rows(a: int, b: int) -> str:
        return f"rows {row_of(a)}-{row_of(b - 1)} ({time[a]:.6g}-{time[b - 1]:.6g} s)"

    if not kept:
        what = (f": it is nonzero only in {', '.join(rows(a, b) for a, b in runs[:5])}, each shorter than "
                f"{MIN_SPAN_SAMPLES} samples" if runs else f": it is 0 in all {len(on)} samples")
        raise LogMapError(f"enable = {expression!r}: the torque is never enabled long enough to analyse{what}")
    off = len(on) - int(on.sum())
    note = (f"enable = {expression}: {len(kept)} span(s) kept, {', '.join(rows(a, b) for a, b in kept)}; "
            f"{off} of {len(on)} samples left out where it is 0")
    if short:
        note += (f"; {len(short)} enabled span(s) shorter than {MIN_SPAN_SAMPLES} samples left out: "
                 f"{', '.join(rows(a, b) for a, b in short[:5])}{', ...' if len(short) > 5 else ''}")
    return kept, note


def _resampled(columns: dict[str, np.ndarray], log_map: LogMap, first: int) -> tuple[dict[str, np.ndarray], str]:
    """The columns on a uniform grid of ``log_map.resample_s``, and a note of the jitter found."""
    step = float(log_map.resample_s)  # type: ignore[arg-type]
    time = columns["time"]
    if len(time) < MIN_SAMPLES:
        raise LogError(f"the record has {len(time)} sample(s); at least {MIN_SAMPLES} are needed")
    bad = {name: np.flatnonzero(~np.isfinite(values)) for name, values in columns.items()}
    for name, rows in bad.items():
        if len(rows):
            i = int(rows[0]) + first
            raise LogError(f"column {name!r}: {len(rows)} value(s) NaN or infinite, the first at row {row_of(i)}",
                           column=name, row=row_of(i))
    dt = np.diff(time)
    back = np.flatnonzero(dt <= 0)
    if len(back):
        i = int(back[0]) + 1
        raise LogError(f"column 'time', row {row_of(i + first)}: {time[i]:.9g} s does not exceed {time[i - 1]:.9g} s; "
                       f"time must increase strictly ({len(back)} such row(s))", column="time", row=row_of(i + first))
    median = float(np.median(dt))
    jitter = float(np.max(np.abs(dt - median)) / median)
    steps = float(time[-1] - time[0]) / step * (1 + 1e-12)  # a Python float: inf rather than a warning
    if not MIN_SAMPLES - 1 <= steps <= MAX_UPSAMPLING * len(time):
        raise LogError(f"resample = {1e3 * step:.6g} ms would make {np.floor(steps) + 1:.6g} sample(s) of the "
                       f"record's {len(time)} over {time[-1] - time[0]:.6g} s; a grid needs at least {MIN_SAMPLES} "
                       f"samples and at most {MAX_UPSAMPLING} times the record's: choose a step near its median "
                       f"step, {1e3 * median:.6g} ms")
    max_gap = log_map.max_gap_s if log_map.max_gap_s is not None else DEFAULT_GAP_STEPS * step
    gaps = np.flatnonzero(dt > max_gap)
    if len(gaps):
        i = int(gaps[0]) + 1
        raise LogError(f"column 'time', row {row_of(i + first)}: a gap of {1e3 * dt[i - 1]:.6g} ms after "
                       f"{time[i - 1]:.6g} s, longer than max_gap = {1e3 * max_gap:.6g} ms ({len(gaps)} such gap(s)); "
                       f"cut the record there or raise max_gap", column="time", row=row_of(i + first))
    count = int(math.floor(steps)) + 1
    grid = time[0] + step * np.arange(count)
    if log_map.interpolation == "linear":
        out = {name: np.interp(grid, time, values) for name, values in columns.items() if name != "time"}
    else:
        index = np.searchsorted(time, grid, side="right") - 1
        out = {name: values[index] for name, values in columns.items() if name != "time"}
    note = (f"resampled to a {1e3 * step:.6g} ms grid by {log_map.interpolation} interpolation: {len(time)} samples "
            f"over {time[-1] - time[0]:.6g} s became {count}; median step {1e3 * median:.6g} ms, steps "
            f"{1e3 * dt.min():.6g}-{1e3 * dt.max():.6g} ms (jitter up to {100 * jitter:.3g} %), no gap above "
            f"max_gap = {1e3 * max_gap:.6g} ms")
    return {"time": grid, **out}, note


def mapped_names(name: str, count: int) -> list[str]:
    """Names of a record's ``count`` logs in a report: ``name``, with the span where there are several."""
    return [name] if count == 1 else [f"{name} [span {k + 1} of {count}]" for k in range(count)]
