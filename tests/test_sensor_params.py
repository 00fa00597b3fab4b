"""Sensor parameter sets whose fields are each in range but cannot work together are refused before a run,
by ``sensor.protocol.check_params``, with an error naming the field; a noise-free sensor runs."""

import math

import pytest

from sensor import evaluation
from sensor.calibration import E_MAX_NM, InfeasibleCalibrationError
from sensor.chamber import chamber_run, drift_run
from sensor.evaluation import evaluate_sensor, resolution_gain
from sensor.protocol import _protocol_voltage_range, check_params
from sensor.readout import factory_calibration
from sim.params import ParameterError, TestbedParams

P = TestbedParams()


def _pr(**fields) -> TestbedParams:
    return P.replace(photoreflector=fields)


@pytest.mark.parametrize("unit_seed", range(0, 60, 3))
def test_default_parameters_of_many_units_pass_the_check(unit_seed):
    """The default sensor, whatever unit is drawn, fits the ADC and the other constraints."""
    check_params(_pr(unit_seed=unit_seed))


def test_an_adc_reference_below_the_operating_point_names_the_field_and_the_smallest_value_that_works():
    """adc_reference_v = 0.5 V (in range) saturates the ADC at rest: the error names the field, its value and
    the smallest reference that covers the protocols' swing; that value passes, 1 % less does not."""
    with pytest.raises(ParameterError, match=r"photoreflector\.adc_reference_v = 0\.5 V.*saturates at rest"):
        check_params(_pr(adc_reference_v=0.5))
    _, hi, _, _ = _protocol_voltage_range(P)
    check_params(_pr(adc_reference_v=hi))
    with pytest.raises(ParameterError, match=rf"adc_reference_v >= {hi:.3g} V"):
        check_params(_pr(adc_reference_v=0.99 * hi))


def test_an_operating_point_that_clips_at_zero_names_the_operating_point():
    """A low operating point puts the channels below the ADC's 0 V floor: the error names operating_point_v."""
    with pytest.raises(ParameterError, match=r"photoreflector\.operating_point_v = 0\.3 V.*raise operating_point_v"):
        check_params(_pr(operating_point_v=0.3))


def test_a_noisy_mini85_that_breaks_the_quiet_segment_names_reference_noise():
    """reference_noise_nm = 1 N·m leaves no quiet segment; the error names the field and the limit (0.01)."""
    with pytest.raises(ParameterError, match=r"photoreflector\.reference_noise_nm = 1 N·m.*<= 0\.01 N·m"):
        check_params(_pr(reference_noise_nm=1.0))
    check_params(_pr(reference_noise_nm=0.01))


def test_a_bandwidth_too_low_for_the_protocols_loading_rate_names_bandwidth():
    """1 Hz lags the 10 N·m/s ramps by 1.6 N·m, 10x the paper's e_max: refused, naming bandwidth_hz."""
    with pytest.raises(ParameterError, match=r"photoreflector\.bandwidth_hz = 1 Hz.*lags.*> 9\.65 Hz"):
        check_params(_pr(bandwidth_hz=1.0))
    check_params(_pr(bandwidth_hz=9.7))


def test_the_full_scale_sets_the_error_bound_of_the_check_and_of_the_factory_calibration():
    """photoreflector.full_scale_nm sets e_max = 0.2 % FS: at twice the paper's 80 N·m the bandwidth check's
    bound doubles (9.6 Hz, refused at 80 N·m, passes) and the factory QP calibration is fitted to 0.32 N·m."""
    wide = {"full_scale_nm": 160.0}
    check_params(_pr(bandwidth_hz=9.6, **wide))
    cal = factory_calibration(_pr(**wide))
    assert cal.fs_nm == 160.0 and cal.e_max_nm == pytest.approx(2 * E_MAX_NM)
    with pytest.raises(ParameterError, match=r"photoreflector\.full_scale_nm"):
        _pr(full_scale_nm=0.0)


def test_the_refused_bandwidth_is_truly_infeasible(monkeypatch):
    """The bandwidth limit is necessary, not a guess: just below it (9.6 Hz), with the check bypassed, the
    QP calibration is infeasible and its smallest feasible e_max exceeds the paper's."""
    with pytest.raises(ParameterError):
        check_params(_pr(bandwidth_hz=9.6))
    monkeypatch.setattr(evaluation, "check_params", lambda params: None)
    with pytest.raises(InfeasibleCalibrationError) as info:
        resolution_gain(_pr(bandwidth_hz=9.6), 0)
    assert info.value.smallest_feasible_e_max_nm > E_MAX_NM


@pytest.mark.parametrize("entry", ["evaluate_sensor", "resolution_gain", "factory_calibration", "chamber_run",
                                   "drift_run"])
def test_every_sensor_entry_point_checks_the_parameters_first(entry):
    """Library users get the same named error as the command lines, from every sensor entry point."""
    bad = _pr(adc_reference_v=0.5)
    calls = {"evaluate_sensor": lambda: evaluate_sensor(bad, 0), "resolution_gain": lambda: resolution_gain(bad, 0),
             "factory_calibration": lambda: factory_calibration(bad),
             "chamber_run": lambda: chamber_run(bad, factory_calibration(P)),
             "drift_run": lambda: drift_run(bad, factory_calibration(P), 0.0)}
    with pytest.raises(ParameterError, match=r"photoreflector\.adc_reference_v"):
        calls[entry]()


def test_a_noise_free_sensor_runs_and_reports_the_resolution_gain_as_undefined():
    """noise_min_v = noise_max_v = 0 is an ideal sensor: the run completes, both stds are 0 and the QP's gain
    over LS is NaN (undefined), not a ZeroDivisionError."""
    ev = evaluate_sensor(_pr(noise_min_v=0.0, noise_max_v=0.0), 0)
    assert ev.figures["ls_std_nm"][0] == 0.0 and ev.figures["qp_std_nm"][0] == 0.0
    assert math.isnan(ev.figures["qp_improvement"][0])
    assert math.isnan(evaluation.improvement_ratio(*resolution_gain(_pr(noise_min_v=0.0, noise_max_v=0.0), 0)))
