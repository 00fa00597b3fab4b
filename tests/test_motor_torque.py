"""The motor's current-to-torque map (sim.motor_torque): the driver's estimate inverts what the motor delivers."""

import math

import pytest
from hypothesis import given
from hypothesis import strategies as st

from sim.motor_torque import CurrentToTorqueMap
from sim.params import ParameterError, TestbedParams

MOTOR = TestbedParams().motor  # the default: α = 0.0176 /(N·m), 18 N·m peak


@given(command_nm=st.floats(-1e3, 1e3))
def test_the_inverse_map_recovers_the_command(command_nm):
    motor = CurrentToTorqueMap.from_params(TestbedParams())
    assert motor.command_nm(motor.delivered_nm(command_nm)) == pytest.approx(command_nm, rel=1e-12, abs=1e-12)


def test_the_driver_limit_is_the_command_that_delivers_the_papers_peak_torque():
    """Closed form: c/(1 + α c) = 18 N·m at c = 18/(1 - 18 α) (30.9 N·m at the default α); 10/(1 + 10 α) at 10 N·m."""
    motor = CurrentToTorqueMap.from_params(TestbedParams())
    alpha, peak = MOTOR.torque_saturation_per_nm, MOTOR.peak_torque_nm
    assert motor.command_limit_nm == pytest.approx(peak / (1.0 - alpha * peak), rel=1e-12)
    assert motor.delivered_nm(-motor.command_limit_nm) == pytest.approx(-peak, rel=1e-12)
    assert motor.delivered_nm(10.0) == pytest.approx(10.0 / (1.0 + 10.0 * alpha), rel=1e-12)


def test_a_torque_beyond_the_maps_asymptote_is_refused_with_the_asymptote():
    motor = CurrentToTorqueMap(0.02, 18.0)
    with pytest.raises(ValueError, match="at most 1/motor.torque_saturation_per_nm = 50 N·m"):
        motor.command_nm(-50.0)


def test_a_saturation_that_cannot_deliver_the_peak_torque_is_refused():
    with pytest.raises(ParameterError, match=r"motor.torque_saturation_per_nm = 0.025 .*valid range \[0, 0.02\)"):
        TestbedParams().replace(motor={"torque_saturation_per_nm": 0.025, "peak_torque_nm": 50.0})


def test_a_linear_motor_delivers_its_command():
    motor = CurrentToTorqueMap(0.0, 18.0)
    assert motor.delivered_nm(-7.5) == motor.command_nm(-7.5) == -7.5
    assert motor.command_limit_nm == 18.0
    assert CurrentToTorqueMap(0.0, math.inf).command_limit_nm == math.inf  # no 0·inf
