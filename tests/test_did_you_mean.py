"""A misspelt key in a rig file or a --params file is named with the key it was probably meant to be."""

import pytest

from sim.discrepancy.rig import RigError, rig_from_dict
from sim.params import ParameterError, from_dict

RIGID = {"model": "rigid-joint", "joint": "slide", "mass_kg": 1.0, "effort_gain": 1.0}


@pytest.mark.parametrize(("data", "expected"), [
    ({"modl": "rigid-joint"}, "model is missing ('modl' = 'rigid-joint' is given: did you mean 'model'?)"),
    ({"model": "testbed", "fixtur": "free"},
     "fixture is missing ('fixtur' = 'free' is given: did you mean 'fixture'?)"),
    ({**{k: v for k, v in RIGID.items() if k != "joint"}, "jiont": "slide"},
     "joint is missing ('jiont' = 'slide' is given: did you mean 'joint'?)"),
    ({"model": "testbed", "fixture": "fre"}, "fixture = 'fre' (did you mean 'free'?)"),
    ({"model": "testbed", "fixture": "free", "friction": {"breakaway_torqe_nm": 0.1}},
     "friction.breakaway_torqe_nm (did you mean 'breakaway_torque_nm'?)"),
    ({"model": "testbed", "fixture": "free", "frictoin": {}},
     "unknown key 'frictoin' for model 'testbed' (did you mean 'friction'?)"),
    ({**RIGID, "friction": {"coulmb": 1.0}}, "unknown key friction.'coulmb' (did you mean 'coulomb'?)"),
    ({**RIGID, "efort_gain": 1.0}, "(did you mean 'effort_gain'?)"),
    ({**RIGID, "time_convention": "hold-end"}, "time_convention = 'hold-end' (did you mean 'hold_end'?)"),
    ({**RIGID, "effects": [{"name": "cogging", "cogging_amplitude": 0.1, "cogging_perod": 0.01,
                            "cogging_phase": 0.0}]},
     "unknown parameter 'cogging_perod' (did you mean 'cogging_period'?)"),
])
def test_a_misspelt_rig_key_is_named_with_the_key_it_was_meant_to_be(data, expected):
    with pytest.raises(RigError) as err:
        rig_from_dict(data)
    assert expected in str(err.value)


@pytest.mark.parametrize(("overrides", "expected"), [
    ({"frictoin": {}}, "unknown parameter group [frictoin] (did you mean 'friction'?)"),
    ({"friction": {"breakaway_torqe_nm": 0.1}}, "friction.breakaway_torqe_nm (did you mean 'breakaway_torque_nm'?)"),
])
def test_a_misspelt_parameter_is_named_with_the_field_it_was_meant_to_be(overrides, expected):
    with pytest.raises(ParameterError) as err:
        from_dict(overrides)
    assert expected in str(err.value)
