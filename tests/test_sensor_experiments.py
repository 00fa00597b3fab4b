"""The paper's sensor experiments: the QP's resolution gain, the chamber run's physics, the CLIs."""

import json

import numpy as np
import pytest

from experiments import calibration as calibration_cli
from experiments import thermal as thermal_cli
from experiments.qp_gain import MIN_GAIN as MIN_QP_GAIN
from experiments.qp_gain import random_sensor, run_draw, run_qp_gain
from sensor import drift_fit
from sensor.chamber import CHAMBER_SETPOINTS_C, chamber_params, chamber_run
from sensor.evaluation import evaluate_sensor, resolution_gain
from sensor.photoreflector import draw_unit
from sensor.readout import factory_calibration
from sim.executor import Executor
from sim.params import TestbedParams, source_bound


@pytest.mark.parametrize("seed", range(20))
def test_qp_resolution_gain_over_ls_holds_across_seeds_and_units(seed):
    """Each seed is a different manufactured unit (unit_seed) and noise draw: LS std / QP std >= 1.5."""
    params = TestbedParams().replace(photoreflector={"unit_seed": 1000 + seed})
    ls_std, qp_std = resolution_gain(params, seed)
    assert ls_std / qp_std >= MIN_QP_GAIN


@pytest.mark.parametrize("draw", range(20))
def test_qp_resolution_gain_holds_for_random_sensor_parameter_sets(draw):
    """Sensor parameter sets drawn at random within their source bounds (``experiments.qp_gain.random_sensor``,
    draws 0-19 of ``--seed 500``) keep LS std / QP std >= 1.5 (measured 1.60-7.04 over these 20). Not a proof
    for the whole box: ``python -m experiments.qp_gain`` gives the share below (docs/fidelity.md)."""
    assert run_draw(500, draw).gain >= MIN_QP_GAIN


def test_the_monte_carlo_is_the_same_on_two_processes_and_draws_within_the_source_bounds():
    """Draw k is random_sensor(default_rng(seed + k)) run with noise seed k, wherever it runs; every drawn
    photo-reflector parameter lies in its source bound (the larger of a pair within its own)."""
    one = run_qp_gain(draws=3, seed=500)
    assert run_qp_gain(draws=3, seed=500, executor=Executor(2)) == one
    assert [d.gain for d in one.draws] == [run_draw(500, k).gain for k in range(3)]
    summary = one.summary()
    assert summary["draws"] == 3 and summary["gain_min"] == min(d.gain for d in one.draws)
    assert sum(b["draws"] for b in summary["by_largest_slip_fraction"]) == 3
    for k in range(50):
        pr = random_sensor(np.random.default_rng(k)).photoreflector
        for name in ("sensitivity_min_v_per_m", "noise_min_v", "slip_fraction_min", "quadratic_fraction_max",
                     "cubic_fraction_max", "quartic_fraction_max", "crosstalk_spread"):
            lo, hi = source_bound(f"photoreflector.{name}")
            assert lo <= getattr(pr, name) <= hi, (k, name)
        assert pr.sensitivity_max_v_per_m <= source_bound("photoreflector.sensitivity_max_v_per_m")[1]


@pytest.mark.parametrize("seed", range(3))
def test_qp_resolution_gain_survives_equal_channel_noise(seed):
    """All eight channels equally noisy (0.5 mV), default slip fractions: the QP still gains >= 1.5x over LS
    (measured 2.6-3.3x over units 1000-1005, seeds 0-5): unequal channel noise is not what makes the gain."""
    params = TestbedParams().replace(photoreflector={"unit_seed": 1000 + seed, "noise_min_v": 5e-4,
                                                     "noise_max_v": 5e-4})
    ls_std, qp_std = resolution_gain(params, seed)
    assert ls_std / qp_std >= MIN_QP_GAIN


@pytest.mark.parametrize("seed", range(3))
def test_qp_resolution_gain_vanishes_without_channel_specific_slip(seed):
    """Equal slip fractions (0.9 %) with the default 14x noise spread: the slip is the same fraction of the
    twist in every channel, no weighting cancels it, and LS is already near the QP (gain < 1.2; measured
    1.01-1.09x over units 1000-1005, seeds 0-5)."""
    params = TestbedParams().replace(photoreflector={"unit_seed": 1000 + seed, "slip_fraction_min": 0.009,
                                                     "slip_fraction_max": 0.009})
    ls_std, qp_std = resolution_gain(params, seed)
    assert ls_std / qp_std < 1.2


def test_ls_cancels_the_slip_by_channel_weighting_and_the_qp_trades_that_back_for_noise():
    """The mechanism, read off the two calibrations (default unit, seed 0): with w_k = dτ̂/dV_k at no load, the
    slip reaching the output relative to the twist, Σ w_k s_k S_k f_k / Σ w_k s_k S_k, is below every
    channel's own fraction f_k for LS (it weights the channels to cancel the slip) and at least twice as large
    for the QP, whose predicted no-load noise sqrt(Σ w_k² σ_k²) is below LS's by the gain the tests require
    (measured 0.0097 against 0.0173 N·m: 1.78x)."""
    ev = evaluate_sensor(seed=0)
    unit = draw_unit(TestbedParams())
    v0 = ev.resolution_record.voltages_v.mean(axis=0)

    def slip_ratio_and_noise(cal):
        th = cal.theta
        w = 3 * th[0:8] * v0 ** 2 + 2 * th[8:16] * v0 + th[16:24]
        k = w * unit.signs * unit.sensitivity_v_per_m
        return np.sum(k * unit.slip_fraction) / np.sum(k), np.sqrt(np.sum(w ** 2 * unit.noise_v ** 2))

    ls_slip, ls_noise = slip_ratio_and_noise(ev.ls)
    qp_slip, qp_noise = slip_ratio_and_noise(ev.qp)
    assert abs(ls_slip) < unit.slip_fraction.min()
    assert qp_slip > 2 * abs(ls_slip)
    assert qp_noise < ls_noise / MIN_QP_GAIN


def test_evaluation_is_deterministic_for_a_seed():
    """Same parameters and seed: identical figures."""
    a, b = evaluate_sensor(seed=4), evaluate_sensor(seed=4)
    assert a.figures == b.figures


def test_evaluation_dict_is_identical_for_a_seed():
    """Same parameters and seed: the JSON of two runs is byte-identical (no wall times in it)."""
    a, b = (json.dumps(evaluate_sensor(seed=3).to_dict()) for _ in range(2))
    assert a == b


def test_chamber_board_settles_at_the_set_point_plus_the_mcu_rise():
    """At the end of each 20 min hold the TMP117 reads the network's steady state within 0.05 K."""
    from sim.thermal import ThermalState
    params = TestbedParams()
    in_chamber = chamber_params(params)
    rec = chamber_run(params, factory_calibration(params), seed=1)
    n_hold = len(rec.time_s) // len(CHAMBER_SETPOINTS_C)
    for k, setpoint in enumerate(CHAMBER_SETPOINTS_C):
        steady = ThermalState(in_chamber.thermal, ambient_c=setpoint).board_c
        assert rec.tmp117_c[(k + 1) * n_hold - 1] == pytest.approx(steady, abs=0.05)


def _rows(path):
    rows = json.loads(path.read_text())["rows"]
    for r in rows:
        assert set(r) >= {"table", "quantity", "unit", "paper", "sim", "ratio"}
        if r["sim"] is None:  # a figure the paper lists that is not simulated (the DYJN-104's)
            assert r["ratio"] is None and "not modelled" in r["quantity"]
        else:
            assert r["ratio"] == pytest.approx(r["sim"] / r["paper"])
    return rows


def test_calibration_cli_prints_the_table_and_writes_json_and_figures(tmp_path, capsys):
    """One row per line of the paper's table, then one per alternative reading with its reason and the paper
    value converted to it (% of the 50 N·m span, of the 25 N·m moment), PNG figures written."""
    assert calibration_cli.main(["--json", str(tmp_path / "c.json"), "--plot", str(tmp_path)]) == 0
    rows = _rows(tmp_path / "c.json")
    primary, alternatives = _split(rows, len(calibration_cli.PAPER_FIGURES))
    assert len(alternatives) == len(calibration_cli.ALTERNATIVE_FIGURES) == 8
    paper = {r["quantity"]: r["paper"] for r in alternatives}
    assert [paper[q] for q in paper if "%" in q or "hold" in q] == pytest.approx(
        [0.0830, 0.0555, 0.0695, 0.04245, 0.037, 0.0315])  # max error; NL, hysteresis, repeatability; crosstalk
    tz_only = [r for r in alternatives if "T_z loading record alone" in r["quantity"]]
    assert [r["paper"] for r in tz_only] == [0.148, 0.126]  # the same % FS figure, another calibration
    assert all(r["sim"] > 3.0 * sim_r["sim"] for r, sim_r in zip(tz_only, primary[5:7], strict=True))
    sim = {r["quantity"]: r["sim"] for r in primary}
    for r in alternatives[1:4]:  # the same deviation in N·m: the 80 N·m % FS figure x 0.8
        assert r["sim"] == pytest.approx(sim[r["quantity"].split(",")[0]] * 0.8)
    assert alternatives[0]["sim"] < sim["max error"]  # hold means average the samples' noise away
    out = capsys.readouterr().out
    assert "QP improvement" in out and "why: Eq. 14 calls FS 'the full-scale span'" in out
    assert len(list(tmp_path.glob("*.png"))) == 3


def _split(rows, n_primary):
    """The primary rows (the first ``n_primary``, without a reading) and the alternatives after them (each with
    its reason)."""
    primary, alternatives = rows[:n_primary], rows[n_primary:]
    assert all("reading" not in r and "reason" not in r for r in primary)
    assert all(r["reading"] == "alternative" and r["reason"].endswith(".") for r in alternatives)
    return primary, alternatives


def test_a_nearly_straight_drift_is_compensated_with_a_pole_free_rational_fit():
    """Unit 3's chamber record (a nearly straight zero drift plus noise): the rational fit has no denominator
    root on the chamber's range, and the compensation uses it."""
    params = TestbedParams().replace(photoreflector={"unit_seed": 3})
    result = thermal_cli.run_thermal(params, seed=0)
    assert result.models.failures == {} and result.compensation_model == "rational"
    a4, a5 = result.models.fits["rational"].coefficients[3:]
    t = np.linspace(result.chamber.tmp117_c.min(), result.chamber.tmp117_c.max(), 10_001)
    assert np.all(a4 * t * t + a5 * t + 1.0 > 0.0)


def test_a_rejected_rational_fit_is_replaced_by_the_best_other_model(monkeypatch):
    """With the rational fit rejected the experiment completes, compensates with the best of the others, and
    its one-hour errors are against the applied torque (the MINI85's own row is its noise)."""

    def rejected(t_c, drift_nm):
        raise drift_fit.DriftFitError("rejected for this test")

    monkeypatch.setitem(drift_fit._FITTERS, "rational", rejected)
    result = thermal_cli.run_thermal(TestbedParams().replace(photoreflector={"unit_seed": 3}), seed=0)
    assert result.models.failures == {"rational": "rejected for this test"}
    assert result.compensation_model == result.models.best != "rational"
    rec = result.drift_tests[10.0]
    mini85 = result.figures_by_name["mini85_drift_rms_10nm"][0]
    assert mini85 == pytest.approx(float(np.sqrt(np.mean((rec.tau_reference_nm - 10.0) ** 2))))


def test_thermal_cli_prints_the_table_and_writes_json_and_a_figure(tmp_path, capsys):
    """One row per figure of Table V (the MINI85's simulated, the DYJN-104's not) and the drift per degree,
    the drift models compared, a PNG written."""
    assert thermal_cli.main(["--json", str(tmp_path / "t.json"), "--plot", str(tmp_path)]) == 0
    primary, alternatives = _split(_rows(tmp_path / "t.json"), len(thermal_cli.PAPER_FIGURES))
    assert len(alternatives) == 3 and {r["paper"] for r in alternatives} == {0.014}
    largest_tests, (largest_chamber, plateaus, span) = primary[-1]["sim"], (r["sim"] for r in alternatives)
    assert largest_chamber >= largest_tests  # the chamber's range holds the one-hour tests'
    assert span <= largest_chamber  # an average slope is at most the largest
    assert plateaus > 0.0
    out = capsys.readouterr().out
    assert "rational" in out and "poly4" in out and "gaussian" in out
    assert (tmp_path / "thermal_drift.png").exists()
