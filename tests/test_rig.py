"""Rig descriptions: valid rigs load, bad ones are refused naming the field and range, rigs must match logs."""

import hashlib
import tomllib

import numpy as np
import pytest

from sim.discrepancy.rig import AddedEffect, RigError, check_rig_matches_log, load_rig, rig_from_dict, save_rig
from sim.logio import SlideRunLog
from sim.runlog import RunLog

TESTBED_TOML = """
model = "testbed"
fixture = "locked"
lever_length_m = 0.12
free = ["friction.coulomb_torque_nm", "motor.command_delay_s"]
[friction]
breakaway_torque_nm = 0.15
"""


def _log(columns: dict[str, np.ndarray], slide: bool = False) -> RunLog:
    units = {"time": "s", "tau_cmd": "N" if slide else "N·m", "q": "m" if slide else "rad", "q_motor": "rad",
             "force_loadcell": "N", "tau_sensor": "N·m"}
    cls = SlideRunLog if slide else RunLog
    return cls(columns, {k: units[k] for k in columns})


def test_testbed_rig_reads_overrides_lever_and_free(tmp_path):
    """A testbed rig applies its parameter overrides and lever length, and lists its free parameters."""
    path = tmp_path / "rig.toml"
    path.write_text(TESTBED_TOML)
    rig = load_rig(path)
    assert rig.params.friction.breakaway_torque_nm == 0.15
    assert rig.params.lever.length_m == 0.12
    assert rig.free_keys == ("coulomb", "delay")


def test_rig_file_is_only_read(tmp_path):
    """Loading a rig leaves its file byte for byte unchanged."""
    path = tmp_path / "rig.toml"
    path.write_text(TESTBED_TOML)
    before = hashlib.sha256(path.read_bytes()).hexdigest()
    load_rig(path)
    assert hashlib.sha256(path.read_bytes()).hexdigest() == before


@pytest.mark.parametrize("data, words", [
    ({"model": "robot"}, ["model", "'testbed'", "'rigid-joint'"]),
    ({"model": "testbed", "fixture": "clamped"}, ["fixture", "'locked'", "'free'"]),
    ({"model": "testbed", "fixture": "locked", "friction": {"coulomb_torque_nm": -1.0}},
     ["friction.coulomb_torque_nm", "valid range"]),
    ({"model": "testbed", "fixture": "locked", "free": ["friction.coulomb"]},
     ["friction.coulomb", "friction.coulomb_torque_nm"]),
    ({"model": "rigid-joint", "joint": "slide", "effort_gain": 1.0}, ["mass_kg", "(0, 1e6]"]),
    ({"model": "rigid-joint", "joint": "slide", "mass_kg": 1.0, "effort_gain": 1.0, "delay_s": 1.0},
     ["delay_s", "[0, 0.05]"]),
    ({"model": "rigid-joint", "joint": "hinge", "inertia_kgm2": 1.0, "effort_gain": 1.0, "mass_kg": 2.0},
     ["mass_kg", "inertia_kgm2"]),
    ({"model": "testbed", "fixture": "locked", "effects": [{"name": "coging"}]}, ["coging", "cogging"]),
    ({"model": "testbed", "fixture": "locked",
      "effects": [{"name": "sensor_gain", "sensor_gain": 7.0}]}, ["sensor_gain", "[0.5, 2]"]),
])
def test_bad_rig_is_refused_naming_field_and_range(data, words):
    """Every invalid field raises a RigError whose message names the field and its valid values or range."""
    with pytest.raises(RigError) as err:
        rig_from_dict(data)
    for word in words:
        assert word in str(err.value)


def test_slide_rig_refuses_a_log_with_motor_encoder():
    """A rigid slide rig refuses a log carrying q_motor (a geared testbed's column), naming the column."""
    rig = rig_from_dict({"model": "rigid-joint", "joint": "slide", "mass_kg": 1.0, "effort_gain": 1.0})
    t = np.arange(1, 11) * 1e-3
    log = _log({"time": t, "tau_cmd": t, "q": t, "q_motor": t}, slide=True)
    with pytest.raises(RigError, match="q_motor"):
        check_rig_matches_log(rig, log)


def test_hinge_rig_refuses_a_slide_log():
    """A testbed (hinge) rig refuses a log whose effort is in newtons."""
    rig = rig_from_dict({"model": "testbed", "fixture": "locked"})
    t = np.arange(1, 11) * 1e-3
    with pytest.raises(RigError, match="slide"):
        check_rig_matches_log(rig, _log({"time": t, "tau_cmd": t, "q": t}, slide=True))


def test_locked_rig_needs_a_load_measurement():
    """A locked-fixture rig refuses a log with neither load cell nor torque sensor."""
    rig = rig_from_dict({"model": "testbed", "fixture": "locked"})
    t = np.arange(1, 11) * 1e-3
    with pytest.raises(RigError, match="force_loadcell"):
        check_rig_matches_log(rig, _log({"time": t, "tau_cmd": t, "q_motor": t}))


def test_saved_rig_loads_back_with_effects_and_new_values(tmp_path):
    """A rig with a changed native value and an added effect, saved and loaded, is the same rig."""
    rig = rig_from_dict(tomllib.loads(TESTBED_TOML))
    extended = rig.with_effects((AddedEffect("sensor_offset", {"sensor_offset": 0.05}),), {"coulomb": 0.07})
    path = save_rig(extended, tmp_path / "extended.toml")
    back = load_rig(path)
    assert back.params == extended.params and back.params.friction.coulomb_torque_nm == 0.07
    assert back.effects == extended.effects
    with pytest.raises(FileExistsError):
        save_rig(extended, path)


def test_a_rig_file_that_is_not_text_is_refused_naming_it(tmp_path):
    """A binary file given as a rig is a RigError naming the file and saying it is not UTF-8 text."""
    path = tmp_path / "bin.toml"
    path.write_bytes(b"\x89PNG\r\n\x1a\n\xff\xfe")
    with pytest.raises(RigError, match=f"rig file {path} is not UTF-8 text"):
        load_rig(path)
