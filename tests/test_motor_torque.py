"""The motor's current-to-torque map (sim.motor_torque): the driver's estimate inverts what the motor delivers."""

import pytest
from hypothesis import given
from hypothesis import strategies as st

from sim.motor_torque import CurrentToTorqueMap
from sim.params import TestbedParams

BETA_PER_NM = TestbedParams().motor.torque_saturation_per_nm  # the default, 0.015 /(N·m)


@given(command_nm=st.floats(-1.0 / (2.0 * BETA_PER_NM), 1.0 / (2.0 * BETA_PER_NM)))
def test_the_inverse_map_recovers_the_command_on_the_monotonic_branch(command_nm):
    motor = CurrentToTorqueMap(BETA_PER_NM)
    # 1 µN·m: at the branch point (command 1/(2β)) the inverse's square root loses half the digits,
    # sqrt(2e-16)/(2β) ≈ 0.5 µN·m
    assert motor.command_nm(motor.delivered_nm(command_nm)) == pytest.approx(command_nm, abs=1e-6)


def test_beyond_the_maps_maximum_the_inverse_is_the_command_that_reaches_it():
    motor = CurrentToTorqueMap(BETA_PER_NM)
    peak_delivered_nm = 1.0 / (4.0 * BETA_PER_NM)  # 16.7 N·m at a command of 1/(2β) = 33.3 N·m
    assert motor.delivered_nm(1.0 / (2.0 * BETA_PER_NM)) == pytest.approx(peak_delivered_nm)
    assert motor.command_nm(-1.01 * peak_delivered_nm) == pytest.approx(-1.0 / (2.0 * BETA_PER_NM))


def test_a_linear_motor_delivers_its_command():
    motor = CurrentToTorqueMap(0.0)
    assert motor.delivered_nm(-7.5) == motor.command_nm(-7.5) == -7.5
