"""The admittance controller's virtual dynamics against the mass-damper's closed forms; the PD law."""

import math

import numpy as np
import pytest

from controllers.admittance import AdmittanceController


def _virtual_response(c: AdmittanceController, tau: float, ticks: int) -> tuple[np.ndarray, np.ndarray]:
    theta, omega = np.empty(ticks), np.empty(ticks)
    for k in range(ticks):
        theta[k], omega[k] = c.reference_angle_rad, c.reference_velocity_rad_s
        c.update(tau, 0.0, 0.0)
    return theta, omega


def test_virtual_velocity_equals_the_discrete_closed_form():
    """Constant τ_ext: ω_r(k) = τ/B (1 - (1 - T B/M)^k) exactly (Eqs. 31-32, K_d = 0)."""
    c = AdmittanceController()
    tau, m, b, ts = 0.3, 0.03, 0.6, 1e-3
    _, omega = _virtual_response(c, tau, 500)
    k = np.arange(500)
    np.testing.assert_allclose(omega, tau / b * (1 - (1 - ts * b / m) ** k), rtol=0, atol=1e-12)


def test_virtual_dynamics_follow_the_analytic_mass_damper():
    """Constant τ_ext from rest: ω(t) = τ/B (1 - e^{-Bt/M}), θ(t) = τ/B (t - M/B (1 - e^{-Bt/M})), within the
    forward-Euler error O(T_s B/M) = 2 % of the response scale."""
    c = AdmittanceController()
    tau, m, b, ts = 0.3, 0.03, 0.6, 1e-3
    theta, omega = _virtual_response(c, tau, 2000)
    t = np.arange(2000) * ts
    decay = np.exp(-b * t / m)
    np.testing.assert_allclose(omega, tau / b * (1 - decay), rtol=0, atol=0.02 * tau / b)
    np.testing.assert_allclose(theta, tau / b * (t - m / b * (1 - decay)), rtol=0, atol=0.02 * tau / b * m / b)
    assert omega[-1] == pytest.approx(tau / b, rel=1e-6)  # terminal velocity τ/B


def test_virtual_spring_oscillates_at_its_natural_frequency():
    """With K_d > 0 and light damping (B_d = 0.01, the least forward Euler needs is T_s·K_d = 0.003) the virtual
    reference oscillates at sqrt(K_d/M_d) (zero crossings; the damped frequency is 0.01 % lower)."""
    c = AdmittanceController(desired_damping_nms_per_rad=0.01, desired_stiffness_nm_per_rad=3.0)
    c.reference_angle_rad = 0.1
    theta, _ = _virtual_response(c, 0.0, 3000)
    crossings = np.flatnonzero(np.diff(np.sign(theta)) != 0)
    period = 2 * np.mean(np.diff(crossings)) * 1e-3
    assert period == pytest.approx(2 * math.pi / math.sqrt(3.0 / 0.03), rel=0.01)


def test_command_is_the_pd_law_on_the_reference_error():
    """τ_cmd = K_p (θ_r - θ) + K_v (ω_r - ω) (Eq. 34) with the state before the update."""
    c = AdmittanceController(angle_gain_nm_per_rad=30.0, velocity_gain_nms_per_rad=0.9)
    c.reference_angle_rad, c.reference_velocity_rad_s = 0.2, 0.5
    assert c.update(0.0, 0.15, 0.1) == pytest.approx(30.0 * 0.05 + 0.9 * 0.4)


def test_unstable_discretisation_is_refused_naming_the_field():
    """T_s B_d / M_d >= 2 would make Eqs. 31-32 diverge: refused with the valid range."""
    with pytest.raises(ValueError, match="desired_damping_nms_per_rad = .*valid range"):
        AdmittanceController(desired_damping_nms_per_rad=100.0)


def test_virtual_spring_stiffer_than_the_damping_allows_is_refused_naming_the_field():
    """Forward Euler needs T_s K_d < B_d: at B_d 0.6 N·m·s/rad and 1 ms, K_d = 600 N·m/rad is the edge."""
    with pytest.raises(ValueError, match=r"desired_stiffness_nm_per_rad = 100000.0: .*valid range \[0, 600\)"):
        AdmittanceController(desired_stiffness_nm_per_rad=1e5)
    with pytest.raises(ValueError, match="desired_stiffness_nm_per_rad"):
        AdmittanceController(desired_damping_nms_per_rad=0.0, desired_stiffness_nm_per_rad=3.0)


def test_virtual_spring_just_inside_the_stability_limit_decays():
    """K_d = 590 N·m/rad (T_s K_d = 0.59 < B_d = 0.6): the virtual dynamics decay instead of diverging."""
    c = AdmittanceController(desired_stiffness_nm_per_rad=590.0)
    c.reference_angle_rad = 0.1
    theta, _ = _virtual_response(c, 0.0, 20000)
    assert np.max(np.abs(theta[-1000:])) < 0.1
