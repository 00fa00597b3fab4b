"""The PI torque controller against its closed-form discrete response; anti-windup bounds the integrator."""

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from controllers.pi import PAPER_KI_PER_S, PAPER_KP, PITorqueController


def test_paper_gains_are_the_defaults():
    """Kp = 0.12, Ki = 12.0 1/s, anti-windup 5 1/s, 1 kHz (paper Sec. IV)."""
    c = PITorqueController(output_limit_nm=18.0)
    assert (c.kp, c.ki_per_s, c.antiwindup_per_s, c.period_s) == (0.12, 12.0, 5.0, 1e-3)
    assert c.feedforward_gain == 1.0  # the reference is the driver's torque command (controllers.pi)


def test_open_loop_error_ramp_matches_the_discrete_pi_law():
    """A constant error e gives u_k = Kp e + k T_s Ki e exactly (no saturation)."""
    c = PITorqueController(output_limit_nm=100.0, feedforward_gain=0.0)
    e = 0.3
    u = [c.update(e, 0.0) for _ in range(50)]
    expected = PAPER_KP * e + np.arange(50) * 1e-3 * PAPER_KI_PER_S * e
    np.testing.assert_allclose(u, expected, rtol=0, atol=1e-12)


def test_closed_loop_on_an_ideal_unit_gain_plant_follows_the_closed_form():
    """Plant y_k = u_{k-1} (ideal actuator, one tick of delay): the loop is the linear recursion
    x_{k+1} = A x_k + B r with x = [y, i]; the simulated response equals its closed-form solution."""
    kp, ki, ts = PAPER_KP, PAPER_KI_PER_S, 1e-3
    c = PITorqueController(output_limit_nm=100.0, feedforward_gain=0.0)
    r, y, ys = 1.0, 0.0, []
    for _ in range(3000):
        u = c.update(r, y)
        y = u
        ys.append(y)
    # y_{k+1} = kp (r - y_k) + i_k ;  i_{k+1} = i_k + ts ki (r - y_k)
    a = np.array([[-kp, 1.0], [-ts * ki, 1.0]])
    b = np.array([kp, ts * ki]) * r
    x_inf = np.linalg.solve(np.eye(2) - a, b)
    k = np.arange(1, 3001)
    w, v = np.linalg.eig(a)
    coeff = np.linalg.solve(v, np.zeros(2) - x_inf)
    closed = (v @ (coeff[:, None] * w[:, None] ** k[None, :])).real[0] + x_inf[0]
    np.testing.assert_allclose(ys, closed, rtol=0, atol=1e-9)
    assert ys[-1] == pytest.approx(r, abs=1e-3)  # integral action removes the steady-state error


def test_feedforward_loop_on_a_lossy_plant_follows_the_closed_form():
    """Plant y_k = g u_{k-1} (an actuator delivering a fraction g, like a lossy gear), u = r + PI(r - y): the
    response equals the closed-form solution of x_{k+1} = A x_k + b and ends at r (integral action)."""
    kp, ki, ts, gain = PAPER_KP, PAPER_KI_PER_S, 1e-3, 0.4
    c = PITorqueController(output_limit_nm=100.0)
    r, y, ys = 0.2, 0.0, []
    for _ in range(4000):
        y = gain * c.update(r, y)
        ys.append(y)
    # y_{k+1} = g (r + kp (r - y_k) + i_k) ;  i_{k+1} = i_k + ts ki (r - y_k)
    a = np.array([[-gain * kp, gain], [-ts * ki, 1.0]])
    b = np.array([gain * (1.0 + kp) * r, ts * ki * r])
    x_inf = np.linalg.solve(np.eye(2) - a, b)
    w, v = np.linalg.eig(a)
    coeff = np.linalg.solve(v, -x_inf)
    k = np.arange(1, 4001)
    closed = (v @ (coeff[:, None] * w[:, None] ** k[None, :])).real[0] + x_inf[0]
    np.testing.assert_allclose(ys, closed, rtol=0, atol=1e-9)
    assert ys[0] == pytest.approx(gain * (1.0 + kp) * r)  # the first command is the reference plus Kp e
    assert ys[-1] == pytest.approx(r, abs=1e-4)


@settings(max_examples=60, deadline=None)
@given(limit=st.floats(0.05, 18.0), error=st.floats(-50.0, 50.0), kaw=st.floats(1.0, 50.0),
       ticks=st.integers(100, 4000))
def test_antiwindup_keeps_the_integrator_bounded_under_saturation(limit, error, kaw, ticks):
    """Held at a constant error beyond saturation, the integrator settles where the back-calculation
    balances Ki e, |i| <= u_max + Kp |e| + Ki |e| / K_aw, instead of growing as Ki e t."""
    c = PITorqueController(output_limit_nm=limit, antiwindup_per_s=kaw, feedforward_gain=0.0)
    for _ in range(ticks):
        u = c.update(error, 0.0)
        assert abs(u) <= limit
    bound = limit + PAPER_KP * abs(error) + PAPER_KI_PER_S * abs(error) / kaw
    assert abs(c.integrator_nm) <= bound + 1e-9


def test_without_antiwindup_the_integrator_winds_up():
    """The control case: with K_aw = 0 the integrator grows as Ki e t under saturation."""
    c = PITorqueController(output_limit_nm=0.1, antiwindup_per_s=0.0, feedforward_gain=0.0)
    for _ in range(1000):
        c.update(5.0, 0.0)
    assert c.integrator_nm == pytest.approx(PAPER_KI_PER_S * 5.0 * 1.0, rel=1e-9)


@pytest.mark.parametrize("field,value", [("output_limit_nm", 0.0), ("kp", -0.1), ("ki_per_s", float("nan")),
                                         ("period_s", 0.0), ("antiwindup_per_s", -1.0),
                                         ("feedforward_gain", -0.5), ("output_limit_nm", float("inf"))])
def test_invalid_gains_are_refused_with_the_field_and_range(field, value):
    """The error names the field and its valid range; an infinite end is shown open, as inf is refused."""
    kwargs = {"output_limit_nm": 18.0, field: value}
    with pytest.raises(ValueError, match=rf"{field} = .*valid range [(\[].*, inf\)"):
        PITorqueController(**kwargs)


@pytest.mark.parametrize("value", ["5", True, None])
def test_gains_that_are_not_numbers_are_refused(value):
    with pytest.raises(ValueError, match=r"kp = .*expected a number in \[0, inf\)"):
        PITorqueController(output_limit_nm=18.0, kp=value)


def test_feedforward_above_one_is_accepted_for_known_gear_losses():
    assert PITorqueController(output_limit_nm=18.0, feedforward_gain=1.2).feedforward_gain == 1.2


@pytest.mark.parametrize("ref,measured", [(0.1, float("nan")), (float("inf"), 0.0)])
def test_a_non_finite_input_is_refused_and_leaves_the_integrator_untouched(ref, measured):
    c = PITorqueController(output_limit_nm=18.0)
    c.update(0.1, 0.05)
    before = c.integrator_nm
    with pytest.raises(ValueError, match="must be finite"):
        c.update(ref, measured)
    assert c.integrator_nm == before
    assert math.isfinite(c.update(0.1, 0.1))
