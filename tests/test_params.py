"""The parameter set: units and sources everywhere, and clear errors for bad values."""

import dataclasses
import math

import pytest

from models.gim8108_testbed.build import build_xml
from sim.params import ParameterError, TestbedParams, bound_source, bounded_fields, load_params, quantity, source_bound


def test_every_parameter_has_unit_source_and_a_default_inside_its_range():
    """Each field carries a unit and a source; the defaults validate."""
    p = TestbedParams()
    rows = p.rows()
    assert len(rows) > 40
    for name, _value, unit, source in rows:
        assert unit, name
        kind = source.split(":")[0]
        assert kind.startswith("paper ") or kind in {"assumed", "tuned", "rule", "TI TMP117 datasheet"}, (
            name, source)


def test_every_source_says_where_its_value_comes_from_in_at_most_300_characters():
    """A source is one or two sentences; longer derivations live in the model README (its Derivations)."""
    for name, _value, _unit, source in TestbedParams().rows():
        assert source.strip(), name
        assert len(source) <= 300, (name, len(source))


def test_toml_override_applies_and_leaves_the_file_untouched(tmp_path):
    """A TOML file overrides fields by [group] and is only read."""
    path = tmp_path / "rig.toml"
    text = "[friction]\nbreakaway_torque_nm = 0.2\n[lever]\nlength_m = 0.15\n"
    path.write_text(text)
    p = load_params(path)
    assert p.friction.breakaway_torque_nm == 0.2
    assert p.lever.length_m == 0.15
    assert p.motor == TestbedParams().motor
    assert path.read_text() == text


@pytest.mark.parametrize("text, fragment", [
    ("[friction]\nbreakaway_torqe_nm = 0.2\n", "unknown parameter friction.breakaway_torqe_nm"),
    ("[gearbox]\nratio = 8\n", "unknown parameter group [gearbox]"),
    ("[motor]\ngear_ratio = 'eight'\n", "motor.gear_ratio = 'eight': expected a number"),
    ("[flexure]\nspoke_count = 4.5\n", "flexure.spoke_count = 4.5: expected an integer"),
    ("[friction]\npresliding_stiffness_nm_per_rad = -10.0\n", "valid range (0, inf)"),
    ("[motor]\nrotor_inertia_kgm2 = 0\n", "motor.rotor_inertia_kgm2 = 0.0 kg·m² is out of its valid range (0, 1]"),
    ("[photoreflector]\nreference_gain_error = 0.02\n",
     "photoreflector.reference_gain_error = 0.02 is out of its valid range [-0.01, 0.01]"),
    ("[friction]\nbreakaway_torque_nm = 25.0\n", "larger than the motor can overcome"),
    ("[friction]\ncoulomb_torque_nm = 0.2\n", "must not exceed friction.breakaway_torque_nm"),
    ("[flexure]\nbeam_length_m = 0.04\n", "r_i + l must stay inside"),
    ("motor = 3\n", "[motor] must be a table"),
    ("[loadcell]\namplifier_bandwidth_hz = 0.0\n",
     "loadcell.amplifier_bandwidth_hz = 0.0 Hz is out of its valid range (0, 1e+06]"),
])
def test_invalid_toml_is_rejected_naming_the_field(tmp_path, text, fragment):
    """Unknown keys, wrong types and out-of-range values name the field, value and valid range."""
    path = tmp_path / "bad.toml"
    path.write_text(text)
    with pytest.raises(ParameterError) as info:
        load_params(path)
    assert fragment in str(info.value)
    assert str(path) in str(info.value)


def test_missing_and_malformed_files_say_so(tmp_path):
    """A missing or non-TOML file is a ParameterError naming the file."""
    with pytest.raises(ParameterError, match="does not exist"):
        load_params(tmp_path / "nope.toml")
    bad = tmp_path / "bad.toml"
    bad.write_text("[motor\n")
    with pytest.raises(ParameterError, match="not valid TOML"):
        load_params(bad)


def test_stop_time_constant_below_two_physics_steps_is_rejected():
    """The backlash stop's solref must be resolvable by the derived step."""
    p = TestbedParams().replace(backlash={"stop_time_constant_s": 1e-5})
    with pytest.raises(ParameterError, match="backlash.stop_time_constant_s"):
        build_xml(p, "locked")


def test_parameters_are_frozen():
    """A parameter set cannot be changed in place (one source of truth)."""
    p = TestbedParams()
    with pytest.raises(dataclasses.FrozenInstanceError):
        p.motor.gear_ratio = 9.0


def test_source_bound_of_a_field_without_one_is_a_key_error_naming_it():
    """Asking for the bound of an unbounded or unknown field names the path and lists the bounded fields."""
    for path in ("simulation.control_period_s", "friction.no_such_field"):
        for lookup in (source_bound, bound_source):
            with pytest.raises(KeyError, match=path.replace(".", r"\.")) as info:
                lookup(path)
            assert all(name in str(info.value) for name in bounded_fields())
    assert source_bound("friction.coulomb_torque_nm") == (0.065, 0.13)
    assert bound_source("friction.coulomb_torque_nm").startswith("assumed: ")


def test_a_bound_without_its_source_is_refused():
    """quantity() takes bound and bound_source together, lo <= hi."""
    with pytest.raises(ValueError, match="bound_source"):
        quantity(1.0, "m", "assumed: x", bound=(0.5, 2.0))
    with pytest.raises(ValueError, match="lo > hi"):
        quantity(1.0, "m", "assumed: x", bound=(2.0, 0.5), bound_source="assumed: y")


def _field(path: str) -> tuple[object, dataclasses.Field]:
    group, name = path.split(".")
    obj = getattr(TestbedParams(), group)
    return getattr(obj, name), next(f for f in dataclasses.fields(obj) if f.name == name)


# Defaults outside the bound their source allows. The bound stays honest and the default stays until the
# identification that sets the defaults moves it; strict, so a fix shows up as an unexpected pass.
OUTSIDE_SOURCE_BOUND = ("friction.load_friction_coefficient",)


def _default_in_bound_case(path: str):
    if path not in OUTSIDE_SOURCE_BOUND:
        return path
    value, f = _field(path)
    reason = (f"{path} = {value:g} lies outside its source bound {list(f.metadata['bound'])} "
              f"({f.metadata['bound_source']})")
    return pytest.param(path, marks=pytest.mark.xfail(strict=True, reason=reason))


@pytest.mark.parametrize("path", [_default_in_bound_case(p) for p in bounded_fields()])
def test_every_default_lies_inside_the_bound_its_source_allows(path):
    """A default [lo, hi] from its source's spread (datasheet, paper, or a stated assumption)."""
    value, _ = _field(path)
    lo, hi = source_bound(path)
    assert lo <= value <= hi, (path, value, (lo, hi))


def test_every_source_bound_lies_inside_the_valid_range_and_says_where_it_comes_from():
    """A bound is a sub-interval of the sanity range (open ends respected) with a one-sentence source."""
    assert len(bounded_fields()) >= 30
    for path in bounded_fields():
        _, f = _field(path)
        lo, hi = source_bound(path)
        md = f.metadata
        assert (lo > md["low"] if md["low_open"] else lo >= md["low"]) and hi <= md["high"], (path, lo, hi)
        assert math.isfinite(lo) and math.isfinite(hi), path
        text = md["bound_source"]
        assert text.startswith(("assumed:", "paper")) or text[0].isupper(), (path, text)  # or a named datasheet
        assert 0 < len(md["bound_source"]) <= 200, (path, len(md["bound_source"]))


# Numerical, not physical: solver time constants and impedances that only set how MuJoCo resolves a contact.
NUMERICAL = {"friction.load_friction_time_constant_s", "friction.load_friction_impedance",
             "backlash.stop_time_constant_s", "backlash.stop_impedance"}


def test_every_tuned_physical_parameter_has_a_source_bound_to_tune_within():
    """A value chosen against the paper's figures needs the interval its source allows; numerical ones do not."""
    tuned = {name for name, _value, _unit, source in TestbedParams().rows() if source.startswith("tuned:")}
    assert tuned >= NUMERICAL
    assert sorted(tuned - NUMERICAL - set(bounded_fields())) == []
    assert not NUMERICAL & set(bounded_fields())
