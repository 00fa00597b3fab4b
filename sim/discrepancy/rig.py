"""Rig descriptions: what produced a run log, which of its parameters may be re-fitted, which effects it has.

A rig is a TOML file with ``model = "testbed"`` or ``model = "rigid-joint"``; see ``docs/discrepancy.md``.

Testbed (the GIM8108 rig of ``sim.params``)::

    model = "testbed"
    fixture = "locked"                 # or "free"
    lever_length_m = 0.1               # optional; the same as [lever] length_m
    free = ["friction.coulomb_torque_nm", "motor.command_delay_s"]
    [friction]                         # any group of sim.params, same schema as --params files
    breakaway_torque_nm = 0.15
    [[effects]]                        # effects beyond the plant (written by --save-rig)
    name = "cogging"
    cogging_amplitude = 0.02           # N·m
    cogging_period = 0.0374            # rad
    cogging_phase = 0.3                # rad

Rigid joint (a user's own drive)::

    model = "rigid-joint"
    joint = "slide"                    # or "hinge"
    mass_kg = 2.0                      # inertia_kgm2 for a hinge
    effort_gain = 1.0                  # delivered effort per unit of tau_cmd [1]
    delay_s = 0.0                      # optional command dead time [s]
    peak_effort = 100.0                # optional saturation [N | N·m]
    constant_effort = 0.0              # optional: a constant force [N] or torque [N·m] the joint needs
    gravity_amplitude = 0.0            # optional, hinge: m·g·r [N·m]
    gravity_angle_rad = 0.0            # optional, hinge: angle of zero gravity torque
    free = ["mass_kg", "friction.coulomb"]
    [friction]
    coulomb = 1.5                      # [N | N·m]
    viscous = 4.0                      # [N·s/m | N·m·s/rad]
    breakaway = 1.5                    # optional static level (defaults to coulomb)
    stribeck_velocity = 0.01           # optional [m/s | rad/s]

Every error names the field and its valid range (:class:`RigError`); the file is only read.
"""

from __future__ import annotations

import dataclasses
import difflib
import json
import math
import re
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from models.gim8108_testbed.build import check_time_constants
from models.gim8108_testbed.derived import FIXTURES, derive
from sim.discrepancy.effects import EFFECTS, rig_kind
from sim.discrepancy.effects.transport_delay import MAX_DELAY_S
from sim.logmap import LogMap, LogMapError, log_map_from_dict
from sim.params import ParameterError, TestbedParams, did_you_mean, from_dict
from sim.runlog import TIME_CONVENTIONS, RunLog

MODELS = ("testbed", "rigid-joint")
JOINTS = ("hinge", "slide")

# Rigid-joint fields: name -> (theta key, unit for hinge, unit for slide, low, high)
_RIGID_FIELDS: dict[str, tuple[str, str, str, float, float]] = {
    "inertia_kgm2": ("inertia", "kg·m²", "", 0.0, 1e6),
    "mass_kg": ("inertia", "", "kg", 0.0, 1e6),
    "effort_gain": ("effort_gain", "1", "1", 0.0, 1e6),
    "delay_s": ("delay", "s", "s", 0.0, MAX_DELAY_S),
    "peak_effort": ("peak_effort", "N·m", "N", 0.0, 1e6),
    "constant_effort": ("constant_effort", "N·m", "N", -1e4, 1e4),
    "gravity_amplitude": ("gravity_amplitude", "N·m", "", -1e4, 1e4),
    "gravity_angle_rad": ("gravity_angle", "rad", "", -math.pi, math.pi),
}
_RIGID_DEFAULTS = {"delay": 0.0, "constant_effort": 0.0, "gravity_amplitude": 0.0, "gravity_angle": 0.0}
# rigid-joint fields that apply to one kind of joint only, and what to say when the other states them
_HINGE_ONLY = {"inertia_kgm2": "a slide's inertia is mass_kg",
               "gravity_amplitude": "gravity along a slide's incline is a constant force: constant_effort",
               "gravity_angle_rad": "gravity along a slide's incline is a constant force: constant_effort"}
_RIGID_FRICTION: dict[str, tuple[str, str, str, float, float]] = {
    "coulomb": ("coulomb", "N·m", "N", 0.0, 1e4),
    "viscous": ("viscous", "N·m·s/rad", "N·s/m", 0.0, 1e6),
    "breakaway": ("breakaway", "N·m", "N", 0.0, 1e4),
    "stribeck_velocity": ("stribeck_velocity", "rad/s", "m/s", 0.0, 1e3),
}


def _free_names(kind: str) -> dict[str, str]:
    """Rig-file field -> theta key of every parameter a rig of ``kind`` states and the analysis may re-fit."""
    return {p.fields[kind]: p.key for effect in EFFECTS.values() for p in effect.params if kind in p.fields}


# Parameters the analysis may re-fit (rig `free` list) -> theta key of the surrogate, by kind of rig.
TESTBED_FREE: dict[str, str] = _free_names("testbed")
RIGID_FREE: dict[str, str] = {**_free_names("hinge"), **_free_names("slide")}


class RigError(ValueError):
    """A rig description that is not valid or does not match the log; the message names the field."""


@dataclass(frozen=True)
class AddedEffect:
    """An effect beyond the baseline model, with its parameter values (theta keys, SI units)."""

    name: str
    parameters: dict[str, float]

    def to_dict(self) -> dict[str, Any]:
        return {"name": self.name, **self.parameters}


@dataclass(frozen=True)
class Rig:
    """A rig description.

    Attributes
    ----------
    model : {'testbed', 'rigid-joint'}
    joint : {'hinge', 'slide'}
        'hinge' for the testbed.
    params : TestbedParams or None
        The testbed's parameter set (None for a rigid joint).
    fixture : {'locked', 'free'} or None
        The testbed's fixture (None for a rigid joint).
    rigid : dict of str to float
        A rigid joint's values by theta key (SI; N or N·m by joint), empty for the testbed.
    free : tuple of str
        Names (as written in the TOML) of the baseline parameters to re-fit.
    effects : tuple of AddedEffect
        Effects beyond the baseline.
    overrides : dict
        The testbed's parameter overrides as read ({group: {field: value}}), kept for saving.
    source : str
        Where the rig came from (file name), for messages.
    time_convention : {'hold_end', 'command'} or None
        How the rig's logs stamp their rows (``docs/run_log_format.md``); None: not stated.
    log_map : LogMap or None
        How the rig's own record files become run logs (the ``[log]`` table, ``docs/own_logs.md``); None: they
        are run logs already.
    """

    model: str
    joint: str
    params: TestbedParams | None = None
    fixture: str | None = None
    rigid: dict[str, float] = field(default_factory=dict)
    free: tuple[str, ...] = ()
    effects: tuple[AddedEffect, ...] = ()
    overrides: dict[str, dict[str, Any]] = field(default_factory=dict)
    source: str = "<rig>"
    time_convention: str | None = None
    log_map: LogMap | None = None

    @property
    def free_keys(self) -> tuple[str, ...]:
        """Theta keys of the free parameters."""
        table = TESTBED_FREE if self.model == "testbed" else RIGID_FREE
        return tuple(table[name] for name in self.free)

    def with_effects(self, effects: tuple[AddedEffect, ...], theta_native: dict[str, float]) -> Rig:
        """A copy with ``effects`` added and native values (baseline parameters) replaced by theta values."""
        rig = self
        if theta_native:
            if self.model == "testbed":
                rig = _testbed_with_theta(self, theta_native)
            else:
                rig = dataclasses.replace(self, rigid={**self.rigid, **theta_native})
        merged = {e.name: e for e in rig.effects}
        merged.update({e.name: e for e in effects})
        return dataclasses.replace(rig, effects=tuple(merged.values()))

    def to_dict(self) -> dict[str, Any]:
        out: dict[str, Any] = {"model": self.model, "joint": self.joint, "free": list(self.free),
                               "effects": [e.to_dict() for e in self.effects],
                               "time_convention": self.time_convention}
        if self.log_map is not None:
            out["log"] = self.log_map.to_dict()
        if self.model == "testbed":
            out.update(fixture=self.fixture, overrides=self.overrides)
        else:
            out.update(values=self.rigid)
        return out


# ----------------------------------------------------------------------------------------------- loading


def load_rig(path: str | Path) -> Rig:
    """Read and validate a rig description (TOML); the file is only read."""
    path = Path(path)
    try:
        with path.open("rb") as fh:
            data = tomllib.load(fh)
    except FileNotFoundError:
        raise RigError(f"rig file {path} does not exist") from None
    except tomllib.TOMLDecodeError as exc:
        raise RigError(f"rig file {path} is not valid TOML: {exc}") from None
    except UnicodeDecodeError as exc:
        raise RigError(f"rig file {path} is not UTF-8 text (TOML): {exc.reason} at byte {exc.start}") from None
    try:
        return rig_from_dict(data, source=path.name)
    except RigError as exc:
        raise RigError(f"{path.name}: {exc}") from None


def rig_from_dict(data: dict[str, Any], source: str = "<rig>") -> Rig:
    """Validate a rig given as a dict (the TOML's content)."""
    data = dict(data)
    model = _required(data, "model", MODELS)
    effects = _effects(data.pop("effects", []))
    log_table = data.pop("log", None)
    try:
        log_map = None if log_table is None else log_map_from_dict(log_table)
    except LogMapError as exc:
        raise RigError(f"[log]: {exc}") from None
    free = data.pop("free", [])
    convention = data.pop("time_convention", None)
    if convention is not None and convention not in TIME_CONVENTIONS:
        raise RigError(f"time_convention = {convention!r}{did_you_mean(str(convention), TIME_CONVENTIONS)}: valid "
                       f"values are {', '.join(map(repr, TIME_CONVENTIONS))}")
    if not isinstance(free, list) or not all(isinstance(f, str) for f in free):
        raise RigError(f"free = {free!r}: expected a list of parameter names")
    if model == "testbed":
        rig = _testbed(data, source)
        valid = TESTBED_FREE
    else:
        rig = _rigid(data, source)
        valid = {k: v for k, v in RIGID_FREE.items() if _rigid_name_applies(k, rig.joint)}
    for name in free:
        if name not in valid:
            raise RigError(f"free: {name!r} cannot be re-fitted{did_you_mean(name, valid)}; valid names: "
                           f"{', '.join(valid)}")
    for effect in effects:
        if not EFFECTS[effect.name].applies(rig):
            raise RigError(f"effects: {effect.name!r} does not apply to a {rig_kind(rig)} rig (it applies to: "
                           f"{', '.join(sorted(EFFECTS[effect.name].rigs))})")
    return dataclasses.replace(rig, free=tuple(free), effects=tuple(effects), time_convention=convention,
                               log_map=log_map)


def _required(data: dict[str, Any], key: str, valid: tuple[str, ...]) -> str:
    """``data[key]`` (popped) if it is one of ``valid``; a RigError naming a misspelt key where one is close."""
    value = data.pop(key, None)
    if value in valid:
        return value
    choices = ", ".join(map(repr, valid))
    if value is None:
        close = difflib.get_close_matches(key, list(data), n=1, cutoff=0.6)
        hint = f" ({close[0]!r} = {data[close[0]]!r} is given: did you mean {key!r}?)" if close else ""
        raise RigError(f"{key} is missing{hint}; valid values: {choices}")
    raise RigError(f"{key} = {value!r}{did_you_mean(str(value), valid)}: valid values are {choices}")


def _effects(tables: Any) -> list[AddedEffect]:
    if not isinstance(tables, list):
        raise RigError("effects must be an array of tables ([[effects]])")
    out = []
    for i, table in enumerate(tables):
        if not isinstance(table, dict) or "name" not in table:
            raise RigError(f"effects[{i}] needs a name; valid names: {', '.join(EFFECTS)}")
        name = table["name"]
        if name not in EFFECTS:
            raise RigError(f"effects[{i}].name = {name!r} is not in the library{did_you_mean(str(name), EFFECTS)}; "
                           f"valid names: "
                           f"{', '.join(EFFECTS)}")
        specs = {p.key: p for p in EFFECTS[name].params}
        values = {}
        for key, value in table.items():
            if key == "name":
                continue
            if key not in specs:
                raise RigError(f"effects[{i}] ({name}): unknown parameter {key!r}{did_you_mean(key, specs)}; valid: "
                               f"{', '.join(specs)}")
            p = specs[key]
            values[key] = _number(f"effects[{i}].{key}", value, *p.valid, p.unit_hinge)
        missing = [k for k in specs if k not in values]
        if missing:
            raise RigError(f"effects[{i}] ({name}): missing parameter(s) {', '.join(missing)}")
        out.append(AddedEffect(name, values))
    return out


def _number(name: str, value: Any, low: float, high: float, unit: str) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise RigError(f"{name} = {value!r}: expected a number [{unit}] in [{low:g}, {high:g}]")
    value = float(value)
    if not (math.isfinite(value) and low <= value <= high):
        raise RigError(f"{name} = {value!r} {unit} is out of its valid range [{low:g}, {high:g}]")
    return value


def _testbed(data: dict[str, Any], source: str) -> Rig:
    fixture = _required(data, "fixture", FIXTURES)
    joint = data.pop("joint", "hinge")
    if joint != "hinge":
        raise RigError(f"joint = {joint!r}: the testbed is a hinge (valid value 'hinge')")
    groups = {f.name for f in dataclasses.fields(TestbedParams)}
    overrides: dict[str, dict[str, Any]] = {}
    lever = data.pop("lever_length_m", None)
    for key, value in data.items():
        if key in groups:
            if not isinstance(value, dict):
                raise RigError(f"[{key}] must be a table of parameters")
            overrides[key] = dict(value)
        else:
            hint = did_you_mean(key, [*groups, "fixture", "free", "effects", "lever_length_m"])
            raise RigError(f"unknown key {key!r} for model 'testbed'{hint}; valid keys: model, fixture, "
                           f"lever_length_m, free, effects, time_convention, log, and the parameter groups "
                           f"{', '.join(sorted(groups))}")
    if lever is not None:
        stated = overrides.get("lever", {}).get("length_m")
        if stated is not None and stated != lever:
            raise RigError(f"lever_length_m = {lever!r} and [lever] length_m = {stated!r} disagree; state the lever "
                           f"length once")
        overrides.setdefault("lever", {})["length_m"] = lever
    try:
        params = from_dict(overrides)
        check_time_constants(params, (fixture,), source=source)
    except ParameterError as exc:
        raise RigError(str(exc)) from None
    return Rig("testbed", "hinge", params=params, fixture=fixture, overrides=overrides, source=source)


def _rigid_name_applies(name: str, joint: str) -> bool:
    if name in _HINGE_ONLY:
        return joint == "hinge"
    if name == "mass_kg":
        return joint == "slide"
    return True


def _rigid(data: dict[str, Any], source: str) -> Rig:
    joint = _required(data, "joint", JOINTS)
    values: dict[str, float] = {}
    friction = data.pop("friction", {})
    if not isinstance(friction, dict):
        raise RigError("[friction] must be a table")
    for key, value in data.items():
        if key not in _RIGID_FIELDS or not _rigid_name_applies(key, joint):
            valid = [k for k in _RIGID_FIELDS if _rigid_name_applies(k, joint)]
            hint = f" ({_HINGE_ONLY[key]})" if key in _HINGE_ONLY and joint == "slide" else did_you_mean(key, valid)
            raise RigError(f"unknown key {key!r} for a rigid {joint} joint{hint}; valid keys: model, joint, log, "
                           f"free, effects, friction, time_convention, {', '.join(valid)}")
        theta_key, unit_h, unit_s, low, high = _RIGID_FIELDS[key]
        values[theta_key] = _number(key, value, low, high, unit_s if joint == "slide" else unit_h)
    inertia_name = "mass_kg" if joint == "slide" else "inertia_kgm2"
    if values.get("inertia", 0.0) <= 0.0:
        raise RigError(f"{inertia_name} is required for a rigid {joint} joint: valid range (0, 1e6]")
    if values.get("effort_gain", 0.0) <= 0.0:
        raise RigError("effort_gain is required: delivered effort per unit of tau_cmd, valid range (0, 1e6]")
    for theta_key, default in _RIGID_DEFAULTS.items():
        values.setdefault(theta_key, default)
    for key, value in friction.items():
        if key not in _RIGID_FRICTION:
            raise RigError(f"unknown key friction.{key!r}{did_you_mean(key, _RIGID_FRICTION)}; valid keys: "
                           f"{', '.join(_RIGID_FRICTION)}")
        theta_key, unit_h, unit_s, low, high = _RIGID_FRICTION[key]
        values[theta_key] = _number(f"friction.{key}", value, low, high, unit_s if joint == "slide" else unit_h)
    values.setdefault("coulomb", 0.0)
    values.setdefault("viscous", 0.0)
    values.setdefault("breakaway", values["coulomb"])
    if values["breakaway"] < values["coulomb"]:
        raise RigError(f"friction.breakaway = {values['breakaway']} must not be below friction.coulomb = "
                       f"{values['coulomb']} (valid range [coulomb, 1e4])")
    if values["breakaway"] > values["coulomb"] and values.get("stribeck_velocity", 0.0) <= 0.0:
        stated = (f" = {values['stribeck_velocity']!r}" if "stribeck_velocity" in values else " is missing")
        raise RigError(f"friction.stribeck_velocity{stated}: a breakaway above the Coulomb level needs one, valid "
                       f"range (0, 1e3]")
    values.setdefault("stribeck_velocity", 1.0)  # irrelevant while breakaway == coulomb
    return Rig("rigid-joint", joint, rigid=values, source=source)


# -------------------------------------------------------------------------------------- matching the log


def check_rig_matches_log(rig: Rig, log: RunLog) -> None:
    """Refuse a rig that cannot have produced ``log`` (wrong joint, columns it cannot have, fixture)."""
    names = set(log.columns)
    unit = log.units.get("tau_cmd")
    expected = "N" if rig.joint == "slide" else "N·m"
    if unit != expected:
        raise RigError(f"rig {rig.source} is a {rig.joint} joint (tau_cmd in {expected}) but the log's tau_cmd is "
                       f"in {unit!r}; read a slide log with read_log(path, joint='slide')")
    if rig.model == "rigid-joint":
        for column, why in (("q_motor", "a rigid joint has no gear: q_motor [rad] belongs to the testbed"),
                            ("force_loadcell", "a rigid joint has no load cell")):
            if column in names:
                raise RigError(f"the log has column {column!r} but rig {rig.source} is a rigid {rig.joint} joint: "
                               f"{why}; describe the rig with model = 'testbed' or drop the column")
        if "q" not in names:
            raise RigError(f"rig {rig.source} (rigid joint) needs the log's position column 'q'")
        return
    meta_fixture = log.meta.get("fixture")
    if meta_fixture is not None and meta_fixture != rig.fixture:
        raise RigError(f"the log was recorded in fixture {meta_fixture!r} (meta) but rig {rig.source} says "
                       f"fixture = {rig.fixture!r}")
    if rig.fixture == "free" and "force_loadcell" in names and "fixture" not in log.meta:
        raise RigError(f"the log has column 'force_loadcell' but rig {rig.source} says fixture = 'free' (the lever "
                       f"turns freely, no load cell); use fixture = 'locked'")
    if "q_motor" not in names and "q" not in names:
        raise RigError("the testbed analysis needs a position: column 'q_motor' (motor encoder) or 'q'")
    if rig.fixture == "locked" and not ({"force_loadcell", "tau_sensor"} & names):
        raise RigError("a locked-fixture log needs the load on the lever: column 'force_loadcell' or 'tau_sensor'")
    if rig.fixture == "free" and not ({"q", "q_motor"} & names):
        raise RigError("a free-fixture log needs the lever motion: column 'q' or 'q_motor'")


# --------------------------------------------------------------------------------------------- saving


def rig_field(rig: Rig, key: str, value: float) -> tuple[str, float] | None:
    """The rig-file field that states theta entry ``key`` and its value there for ``value`` (SI), or None if the
    rig states no such field. The testbed's inertia in theta is the output-referred N²·J_rotor + J_out; its file
    states the rotor's."""
    if rig.model != "testbed":
        name = next((k for k, spec in {**_RIGID_FIELDS, **_RIGID_FRICTION}.items()
                     if spec[0] == key and _rigid_name_applies(k, rig.joint)), None)
        if name is None:
            return None
        return (name if name in _RIGID_FIELDS else f"friction.{name}"), value
    path = {v: k for k, v in TESTBED_FREE.items()}.get(key)
    if path is None:
        return None
    if key == "inertia":
        assert rig.params is not None
        value = (value - derive(rig.params).output_inertia_kgm2) / rig.params.motor.gear_ratio ** 2
    return path, value


def _testbed_with_theta(rig: Rig, theta: dict[str, float]) -> Rig:
    assert rig.params is not None
    overrides = {g: dict(v) for g, v in rig.overrides.items()}
    for key, value in theta.items():
        field_value = rig_field(rig, key, value)
        if field_value is None:
            continue
        group, name = field_value[0].split(".")
        overrides.setdefault(group, {})[name] = float(field_value[1])
    try:
        params = from_dict(overrides)
    except ParameterError as exc:
        raise RigError(f"the fitted values do not form a valid parameter set: {exc}") from None
    return dataclasses.replace(rig, params=params, overrides=overrides)


def _toml_value(value: Any) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, (int, float)):
        return repr(float(value)) if isinstance(value, float) else str(value)
    if isinstance(value, str):  # a TOML basic string: JSON's escapes, and DEL, which JSON leaves as it is
        return json.dumps(value, ensure_ascii=False).replace("\x7f", "\\u007f")
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(_toml_value(v) for v in value) + "]"
    if isinstance(value, dict):
        return "{" + ", ".join(f"{_toml_key(k)} = {_toml_value(v)}" for k, v in value.items()) + "}"
    raise TypeError(f"cannot write {value!r} to TOML")


def _toml_key(key: str) -> str:
    return key if re.fullmatch(r"[A-Za-z0-9_-]+", key) else _toml_value(key)


def rig_to_toml(rig: Rig, header: str = "") -> str:
    """TOML text of ``rig`` that :func:`load_rig` reads back to the same rig (units in comments)."""
    lines = [f"# {line}" for line in header.splitlines()]
    lines.append(f"model = {_toml_value(rig.model)}")
    if rig.time_convention is not None:
        lines.append(f"time_convention = {_toml_value(rig.time_convention)}")
    if rig.model == "testbed":
        lines.append(f"fixture = {_toml_value(rig.fixture)}")
    else:
        lines.append(f"joint = {_toml_value(rig.joint)}")
        inverse = {spec[0]: key for key, spec in _RIGID_FIELDS.items() if _rigid_name_applies(key, rig.joint)}
        for theta_key, key in inverse.items():
            if theta_key in rig.rigid:
                _, unit_h, unit_s, *_ = _RIGID_FIELDS[key]
                unit = unit_s if rig.joint == "slide" else unit_h
                lines.append(f"{key} = {_toml_value(rig.rigid[theta_key])}  # {unit}")
    lines.append(f"free = {_toml_value(list(rig.free))}")
    if rig.model == "testbed":
        for group, values in rig.overrides.items():
            lines.append(f"\n[{group}]")
            for key, value in values.items():
                lines.append(f"{key} = {_toml_value(value)}")
    else:
        lines.append("\n[friction]")
        for key, (theta_key, unit_h, unit_s, *_) in _RIGID_FRICTION.items():
            no_drop = theta_key == "stribeck_velocity" and rig.rigid["breakaway"] <= rig.rigid["coulomb"]
            if theta_key in rig.rigid and not no_drop:  # a Stribeck velocity without a drop is no value of the rig
                lines.append(f"{key} = {_toml_value(rig.rigid[theta_key])}  # "
                             f"{unit_s if rig.joint == 'slide' else unit_h}")
    if rig.log_map is not None:
        lines.append("\n[log]")
        lines.extend(f"{key} = {_toml_value(value)}" for key, value in rig.log_map.to_dict().items())
    for effect in rig.effects:
        lines.append("\n[[effects]]")
        lines.append(f"name = {_toml_value(effect.name)}")
        units = {p.key: p.unit(rig.joint) for p in EFFECTS[effect.name].params}
        for key, value in effect.parameters.items():
            lines.append(f"{key} = {_toml_value(value)}  # {units[key]}")
    return "\n".join(lines) + "\n"


def save_rig(rig: Rig, path: str | Path, *, header: str = "", overwrite: bool = False) -> Path:
    """Write ``rig`` as TOML; refuses to replace an existing file unless ``overwrite``."""
    path = Path(path)
    text = rig_to_toml(rig, header)
    rig_from_dict(tomllib.loads(text))  # what we write must load back
    if not path.parent.is_dir():
        raise FileNotFoundError(f"cannot write {path}: directory {path.parent} does not exist")
    with path.open("w" if overwrite else "x", encoding="utf-8") as fh:
        fh.write(text)
    return path
