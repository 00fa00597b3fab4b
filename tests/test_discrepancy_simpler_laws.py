"""The simplest adequate law: where a fitted law degenerates into a simpler one over the span of the log, the
analysis names the simpler law (rule 'simpler'), one pair of laws per test.

Logs of the independent simulator (tests/independent/rigsim.py), each made with the simpler law (or with the
complex one in its degenerate range), so that the truth is known without the analysis's own formulas.
"""

from __future__ import annotations

import tomllib

import numpy as np
import pytest

from sim.discrepancy.analysis import Source, analyse, join_and_prepare, read_stage
from sim.discrepancy.model import Surrogate
from sim.discrepancy.rig import rig_from_dict
from sim.discrepancy.selection import fit_candidate
from sim.discrepancy.signals import AnalysisConfig
from tests.independent import battery, rigsim

CONFIG = AnalysisConfig()
N = 12_000  # 12 s at 1 kHz


def _run(joint: str, seed: int, n: int = N, excitation: str = "multisine", **truth: float):
    """A PID-tracked run of the battery's baseline rig with ``truth`` (Plant fields) changed, and that rig."""
    values = battery.baseline(joint, seed)
    plant = battery.plant_of(joint, values, **truth)
    ref = battery.reference(joint, excitation, seed, n)
    run = rigsim.simulate(plant, rigsim.PID.tuned(ref, values["mass"], 5.0, plant.peak_effort), n, seed=seed)
    rig = rig_from_dict(tomllib.loads(battery.rig_toml({"joint": joint, **values}, "baseline")))
    return run.to_log(), rig


def _candidates(result, effect: str) -> list[dict]:
    return [c for scores in result.baseline["candidates"] for c in scores if c["effect"] == effect]


def test_a_constant_force_is_named_as_such_not_as_a_spring_anchored_far_outside_the_motion():
    """A slide pushed by a constant force (2.5 N): a spring can fit it only with its rest position far outside the
    motion, where it is that constant; the constant is named, the spring refused by rule 'simpler'."""
    log, rig = _run("slide", 41, gravity_amplitude=2.5)
    result = analyse(log, rig)
    assert result.found[:1] == ["constant_effort"] and "position_spring" not in result.found
    assert result.findings[0].parameters["constant_effort"]["value"] == pytest.approx(2.5, rel=0.05)
    springs = [c for c in _candidates(result, "position_spring") if c["rejected_by"] == "simpler"]
    assert springs and all("outside the motion" in c["note"] for c in springs)


def test_a_spring_anchored_outside_the_motion_whose_slope_shows_stays_a_spring():
    """A soft spring anchored 2 m away (k·(x - x0) over ±0.1 m: 2.4 N and a slope of ±0.12 N across the span,
    far above this log's noise): it explains significantly more than a constant, and is named, with its rest."""
    log, rig = _run("slide", 41, spring_stiffness=1.2, spring_rest_position=-2.0)
    result = analyse(log, rig)
    assert result.found[:1] == ["position_spring"]
    parameters = result.findings[0].parameters
    assert parameters["spring_stiffness"]["value"] == pytest.approx(1.2, rel=0.05)
    assert parameters["spring_rest_position"]["value"] == pytest.approx(-2.0, rel=0.05)


def test_a_spring_inside_the_motion_stays_a_spring():
    log, rig = _run("slide", 42, spring_stiffness=20.0, spring_rest_position=0.02)
    assert analyse(log, rig).found[:1] == ["position_spring"]


def test_a_breakaway_no_higher_than_the_coulomb_level_is_named_as_coulomb_friction():
    """The rig's Coulomb level 30 % low and no Stribeck drop in the truth: a Stribeck candidate fits F_s = F_c and
    is the Coulomb level it degenerates into."""
    values = battery.baseline("hinge", 43)
    log, rig = _run("hinge", 43, excitation="point_to_point", coulomb=1.3 * values["coulomb"])
    result = analyse(log, rig)
    assert result.found[:1] == ["coulomb_friction"] and "stribeck_friction" not in result.found
    model = read_stage((log,), ("log",), ["estimation"], rig, CONFIG).model
    theta = {**model.theta0, "coulomb": 1.3 * values["coulomb"], "breakaway": 1.3 * values["coulomb"]}
    from sim.discrepancy.selection import held_out_score

    candidate = fit_candidate(model, "stribeck_friction", theta, ("coulomb",), {"effort": 1.0},
                              held_out_score(model, theta))
    assert candidate.rejected_by in ("simpler", "gain", "bic")
    if candidate.rejected_by == "simpler":
        assert "no drop" in candidate.note


def test_a_compliance_resonating_above_the_analysis_band_is_an_inertia():
    """A mass 25 % above the rig's, a fifth of it behind a spring resonating at 60 Hz (above the 25 Hz band):
    below its resonance the drivetrain is rigid, an inertia re-fit."""
    values = battery.baseline("slide", 44)
    log, rig = _run("slide", 44, mass=1.25 * values["mass"], compliant_fraction=0.2, resonance_frequency=60.0,
                    damping_ratio=0.1)
    result = analyse(log, rig)
    assert result.found[:1] == ["inertia"] and "drivetrain_compliance" not in result.found
    assert result.findings[0].parameters["inertia"]["value"] == pytest.approx(1.25 * values["mass"], rel=0.05)


def test_records_sharing_one_zero_are_named_as_a_constant_effort_not_as_record_offsets():
    """Two records of a slide with the same constant force (2 N): one shared constant, not a zero per record."""
    first, rig = _run("slide", 45, spring_stiffness=0.0, gravity_amplitude=2.0)
    second, _ = _run("slide", 46, n=8000, gravity_amplitude=2.0)
    result = analyse(first, rig, validation=(second,))
    assert "constant_effort" in result.found and "record_offsets" not in result.found
    offsets = _candidates(result, "record_offsets")
    assert offsets and all(c["rejected_by"] is not None for c in offsets)


def test_records_zeroed_anew_are_named_as_record_offsets():
    """The same rig, its effort read by a sensor zeroed anew before each record (+0.5, -0.4 and +0.1 N)."""
    logs = []
    for seed, n, zero in ((47, N, 0.5), (48, N, -0.4), (49, 8000, 0.1)):
        log, rig = _run("slide", seed, n=n)
        logs.append(type(log)({**log.columns, "tau_cmd": log["tau_cmd"] + zero}, log.units, log.meta))
    result = analyse(logs[0], rig, also=(logs[1],), validation=(logs[2],))
    assert "record_offsets" in result.found
    zeros = [entry["effort"]["value"] for entry in result.final["record_offsets"]]
    assert np.diff(zeros) == pytest.approx(np.diff([0.5, -0.4, 0.1]), abs=0.05)


def test_the_record_offsets_of_the_surrogate_are_each_records_mean_on_its_own_samples():
    """Profiled zeros: the mean effort residual of each record on the samples it is fitted on."""
    first, rig = _run("slide", 47)
    second, _ = _run("slide", 48)
    second = type(second)({**second.columns, "tau_cmd": second["tau_cmd"] + 1.0}, second.units, second.meta)
    sources = [Source("a", "estimation", first), Source("b", "validation", second)]
    _, segments, _, data = join_and_prepare(sources, rig, CONFIG)
    model = Surrogate(data, rig, CONFIG)
    zeros = model.record_offsets({**model.theta0, "record_offsets": 1.0})["effort"]
    assert zeros[1] - zeros[0] == pytest.approx(1.0, abs=0.05)
