"""Stribeck friction named where its low speeds show: at a rigid joint's breakaways and reversals, from a rig that
states no friction at all, and, where the log never slides slowly enough to show the Stribeck velocity, the
breakaway named with the bound the log puts on that velocity.

Logs of the independent simulator (tests/independent/rigsim.py: Karnopp stick-slip at 20 kHz, quantised encoder).
"""

from __future__ import annotations

import tomllib

import pytest

from sim.discrepancy.analysis import analyse
from sim.discrepancy.rig import rig_from_dict
from tests.independent import battery, rigsim

N = 15_000  # 15 s at 1 kHz
TOLERANCE = 0.2


def _log(joint: str, excitation: str, seed: int, ratio: float, stribeck_velocity: float):
    values = battery.baseline(joint, seed)
    plant = battery.plant_of(joint, values, breakaway=ratio * values["coulomb"],
                             stribeck_velocity=stribeck_velocity)
    ref = battery.reference(joint, excitation, seed, N)
    run = rigsim.simulate(plant, rigsim.PID.tuned(ref, values["mass"], 5.0, plant.peak_effort), N, seed=seed)
    return run.to_log(), values


def _frictionless_rig(joint: str, values: dict):
    """The rig with its mass, viscous friction and peak effort, and no dry friction stated."""
    return rig_from_dict(tomllib.loads(battery.rig_toml({"joint": joint, **values, "coulomb": 0.0}, "no friction")))


@pytest.mark.parametrize(("joint", "vs"), [("hinge", 0.06), ("slide", 0.012)])
def test_stribeck_friction_is_named_on_a_multisine_from_a_rig_without_friction(joint, vs):
    """The reversals of a multisine are the only low speeds: Coulomb friction is found first, then the Stribeck
    drop at its level, breakaway and Stribeck velocity within 20 %."""
    log, values = _log(joint, "multisine", 61 if joint == "hinge" else 62, 1.5, vs)
    result = analyse(log, _frictionless_rig(joint, values))
    assert result.found[:2] == ["coulomb_friction", "stribeck_friction"]
    stribeck = result.findings[1].parameters
    assert stribeck["breakaway"]["value"] == pytest.approx(1.5 * values["coulomb"], rel=TOLERANCE)
    assert stribeck["stribeck_velocity"]["value"] == pytest.approx(vs, rel=TOLERANCE)
    assert "bound" not in stribeck["stribeck_velocity"]
    assert result.findings[1].evidence["low_speed"]["fit"]["resolved"]


def test_a_stribeck_velocity_the_log_cannot_resolve_is_stated_as_a_bound_beside_the_breakaway():
    """Point-to-point moves of a hinge whose friction drops within 1 mrad/s of rest: the breakaway is named, and
    the Stribeck velocity is stated as bounded from above, not refused for sitting at the end of its range."""
    log, values = _log("hinge", "point_to_point", 63, 1.5, 0.001)
    rig = rig_from_dict(tomllib.loads(battery.rig_toml({"joint": "hinge", **values}, "baseline")))
    result = analyse(log, rig)
    assert "stribeck_friction" in result.found
    stribeck = result.findings[result.found.index("stribeck_friction")].parameters
    assert stribeck["breakaway"]["value"] == pytest.approx(1.5 * values["coulomb"], rel=0.05)
    velocity = stribeck["stribeck_velocity"]
    assert velocity["resolved"] is False and velocity["bound"].startswith("v_s below")
