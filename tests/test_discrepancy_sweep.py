"""Hidden-effect sweep (slow): every effect of the library across seeds, false positives, pairs of effects.

Each effect is hidden in the experiment that makes it identifiable (docs/discrepancy.md), at a value drawn
from its realistic range (experiments.synthetic_logs.draw_effect) with the seed; the analysis gets only the log
and the baseline rig. Tolerances are stated per effect; the looser ones say why.
"""

import dataclasses
import tomllib

import pytest

from experiments.synthetic_logs import (
    EXPERIMENTS,
    FINE_MOTOR_ENCODER_COUNTS,
    GRID_BEST_OVERRIDES,
    REVEALING_EXPERIMENT,
    TESTBED_EXPERIMENTS,
    hidden_effect_log,
    random_baseline_overrides,
)
from sim.discrepancy.analysis import analyse as analyse_log
from sim.discrepancy.analysis import read_stage
from sim.discrepancy.rig import rig_from_dict, rig_to_toml
from sim.discrepancy.signals import AnalysisConfig

SEEDS = (21, 22, 23)
DURATION_S = 10.0
TIGHT = 0.05  # relative error of parameters the experiment excites well

# effect -> {parameter: (tolerance, 'relative' | 'absolute')}
TOLERANCES = {
    "coulomb_friction": {"coulomb": (TIGHT, "relative")},
    "viscous_friction": {"viscous": (TIGHT, "relative")},
    # F_s and v_s trade off along the low-speed curve (measured errors 35 % on F_s at 8 s): a 50 % tolerance
    "stribeck_friction": {"breakaway": (0.5, "relative"), "stribeck_velocity": (0.5, "relative")},
    "constant_effort": {"constant_effort": (TIGHT, "relative")},
    "load_dependent_friction": {"load_coefficient": (TIGHT, "relative")},
    "backlash": {"backlash_width": (TIGHT, "relative")},
    "cogging": {"cogging_amplitude": (TIGHT, "relative"), "cogging_period": (1e-9, "relative")},
    "torque_constant_nonlinearity": {"torque_rolloff": (0.1, "relative")},  # 10 %: one swing of ±8 N·m
    "transport_delay": {"delay": (3e-4, "absolute")},  # [s], a third of a sample
    "gravity": {"gravity_amplitude": (TIGHT, "relative"), "gravity_angle": (0.1, "absolute")},
    "sensor_offset": {"sensor_offset": (TIGHT, "relative")},
    "sensor_gain": {"sensor_gain": (0.005, "absolute")},  # [1]: the drawn errors are 2-5 %
    "sensor_thermal_drift": {"sensor_tempco": (TIGHT, "relative")},
    "sensor_hysteresis": {"sensor_hysteresis": (0.1, "relative"), "sensor_hysteresis_span": (0.1, "relative")},
}
# the testbed's experiment for effects new to it (the rigid joints' are below)
TESTBED_NEW = {
    "effort_gain": {"effort_gain": (0.01, "absolute")},  # [1]: the drawn errors are 5-15 %
    "quadratic_drag": {"drag_coefficient": (0.1, "relative")},
    "position_spring": {"spring_stiffness": (TIGHT, "relative")},
    "periodic_disturbance": {"disturbance_amplitude": (TIGHT, "relative"),
                             "disturbance_frequency": (0.01, "relative")},
}
# effect -> (experiment that reveals it, its tolerances)
CASES = {effect: (REVEALING_EXPERIMENT[effect], tol) for effect, tol in {**TOLERANCES, **TESTBED_NEW}.items()}
SLIDE_CASES = {
    "coulomb_friction": {"coulomb": (TIGHT, "relative")},
    "constant_effort": {"constant_effort": (TIGHT, "relative")},
}
# Rigid hinge and slide: every effect that applies to a rigid joint (gravity: a hinge's; a slide's is a constant
# effort), with the tolerances above; the new ones:
RIGID_TOLERANCES = {
    "inertia": {"inertia": (TIGHT, "relative")},
    "effort_gain": {"effort_gain": (0.01, "absolute")},
    "coulomb_friction": {"coulomb": (TIGHT, "relative")},
    "viscous_friction": {"viscous": (TIGHT, "relative")},
    # the Stribeck velocity is not asserted: on a rigid joint its low speeds lie mostly within the guards around
    # stick-slip transitions, whose samples do not count (measured on the MuJoCo moves: F_s -23 to +12 %, v_s -82
    # to +9 %; on the independent simulator's point-to-point logs both within 2 %)
    "stribeck_friction": {"breakaway": (0.3, "relative")},
    "constant_effort": {"constant_effort": (0.1, "relative")},
    "quadratic_drag": {"drag_coefficient": (0.1, "relative")},
    "cogging": {"cogging_amplitude": (0.1, "relative"), "cogging_period": (0.01, "relative")},
    "torque_constant_nonlinearity": {"torque_rolloff": (0.1, "relative")},
    "transport_delay": {"delay": (3e-4, "absolute")},
    "gravity": {"gravity_amplitude": (TIGHT, "relative")},
    "position_spring": {"spring_stiffness": (0.1, "relative")},
    "periodic_disturbance": {"disturbance_amplitude": (0.1, "relative"), "disturbance_frequency": (0.01, "relative")},
    "drivetrain_compliance": {"compliant_fraction": (0.2, "relative"), "resonance_frequency": (0.1, "relative")},
}
RIGID_CASES = [(effect, joint) for effect in RIGID_TOLERANCES for joint in ("hinge", "slide")
               if not (effect == "gravity" and joint == "slide")]
# the swing reveals every rigid effect but Stribeck friction, which needs the low speeds of point-to-point moves
RIGID_EXPERIMENT = {"stribeck_friction": "{joint}_moves"}


def analyse(log, rig, config=None):
    """The analysis, with its promise checked on every log of the sweep: its saved rig, written as TOML and read
    back, reads the log as the analysis's final model (the same held-out RMSE per channel)."""
    config = config or AnalysisConfig()
    result = analyse_log(log, rig, config)
    saved = rig_from_dict(tomllib.loads(rig_to_toml(result.extended_rig)))
    again = read_stage((log,), ("log 1",), ["estimation"], saved, config).score.rmse
    assert again == pytest.approx(result.final["rmse_heldout"], rel=1e-9, nan_ok=True)
    return result


def _check(result, truth, effect, tolerances):
    assert result.found, f"{effect}: nothing found"
    assert result.found[0] == effect, f"{effect} hidden, found {result.found}"
    first = result.findings[0]
    for key, (tol, kind) in tolerances.items():
        found, true = first.parameters[key]["value"], truth.effects[effect][key]
        error = abs(found - true) / abs(true) if kind == "relative" else abs(found - true)
        assert error < tol, f"{effect}.{key}: found {found:.6g}, truth {true:.6g}"
    assert first.gain > 0 and first.rmse_heldout_after < first.rmse_heldout_before


@pytest.mark.slow
@pytest.mark.parametrize("seed", SEEDS)
@pytest.mark.parametrize("effect", list(CASES))
def test_every_effect_is_named_first_and_recovered(effect, seed):
    """Each library effect hidden alone is the first finding, with its parameters within tolerance."""
    experiment, tolerances = CASES[effect]
    log, rig, truth = hidden_effect_log(experiment, [effect], seed, DURATION_S)
    _check(analyse(log, rig), truth, effect, tolerances)


@pytest.mark.slow
@pytest.mark.parametrize("seed", SEEDS)
@pytest.mark.parametrize("effect", list(SLIDE_CASES))
def test_slide_rig_effects_are_found(effect, seed):
    """On a rigid slide joint, hidden Coulomb friction and a constant force are found and recovered."""
    log, rig, truth = hidden_effect_log("slide", [effect], seed, DURATION_S)
    _check(analyse(log, rig), truth, effect, SLIDE_CASES[effect])


@pytest.mark.slow
@pytest.mark.parametrize("seed", SEEDS[:2])
@pytest.mark.parametrize("effect, joint", RIGID_CASES)
def test_every_effect_is_named_first_on_rigid_hinge_and_slide(effect, joint, seed):
    """Each effect that applies to a rigid joint, hidden alone on the rigid hinge and the slide, is the first
    finding with its parameters within tolerance."""
    experiment = RIGID_EXPERIMENT.get(effect, "{joint}").format(joint=joint)
    log, rig, truth = hidden_effect_log(experiment, [effect], seed, DURATION_S)
    _check(analyse(log, rig), truth, effect, RIGID_TOLERANCES[effect])


@pytest.mark.slow
@pytest.mark.parametrize("joint", ["hinge", "slide"])
@pytest.mark.parametrize("parameter, factor", [("coulomb", 1.3), ("inertia", 1.25)])
def test_a_misspecified_rig_is_named_as_a_re_fit(joint, parameter, factor):
    """A rig file whose Coulomb level is 30 % off, or whose mass 25 % off, is named as a re-fit of that rig
    parameter (kind 're-fit', the rig's value beside it), recovered within 5 %, not as another effect."""
    log, truth_rig, _ = hidden_effect_log(joint, [], 24, DURATION_S)
    wrong = dict(truth_rig.rigid)
    wrong[parameter] *= factor
    if parameter == "coulomb":
        wrong["breakaway"] = wrong["coulomb"]
    rig = dataclasses.replace(truth_rig, rigid=wrong)
    result = analyse(log, rig)
    effect = "coulomb_friction" if parameter == "coulomb" else "inertia"
    assert result.found[:1] == [effect]
    first = result.findings[0]
    assert first.kind == "re-fit" and first.parameters[parameter]["baseline"] == wrong[parameter]
    true = truth_rig.rigid[parameter]
    assert abs(first.parameters[parameter]["value"] - true) < TIGHT * true


@pytest.mark.slow
@pytest.mark.parametrize("joint", ["hinge", "slide"])
def test_an_effect_outside_the_library_ends_unexplained(joint):
    """A log of a joint whose inertia varies with position (outside the library; the independent simulator of
    tests/independent, the battery's 30 s log) ends in 'unexplained', with no confident finding."""
    from tests.independent import battery

    case = next(c for c in battery.cases() if c.name.startswith(f"outside-position_dependent_inertia-{joint}"))
    run, rig_values, _ = battery.build(case, battery.DEFAULT_DURATION_S)
    log, rig = battery.as_log_and_rig(run, rig_values, joint)
    result = analyse(log, rig)
    assert result.found == [] and result.verdict == "unexplained", (result.found, result.verdict)


@pytest.mark.slow
@pytest.mark.parametrize("seed", SEEDS)
def test_slide_dead_time_is_recovered(seed):
    """A dead time hidden in the slide's drive is found and recovered within a third of a sample.

    It came out 0.6-0.8 ms long while the slide's effort samples next to stick-slip transitions counted (the
    friction jump smeared by the filter) and MuJoCo's zero-order-hold delay rounded the dead time up to a
    physics step; see RIGID_TRANSITION_GUARD_PERIODS (sim.discrepancy.model) and rigid_xml's interpolation.
    """
    log, rig, truth = hidden_effect_log("slide", ["transport_delay"], seed, DURATION_S)
    _check(analyse(log, rig), truth, "transport_delay", {"delay": (3e-4, "absolute")})


@pytest.mark.slow
def test_presliding_is_declared_unrevealable_at_the_encoder_resolution():
    """With the 16-bit motor encoder, the analysis says presliding cannot be revealed instead of guessing."""
    log, rig, _ = hidden_effect_log("locked", ["presliding_friction"], 21, DURATION_S)
    result = analyse(log, rig)
    assert "resolution" in result.baseline["not_identifiable"]["presliding_friction"]
    assert "presliding_friction" not in result.found


# Presliding with a fine motor encoder (22 bits per motor turn), hidden in the closed-loop current-feedback log:
# the torque loop holds the motor stuck through many small load reversals. Measured relative errors of σ0 on
# seeds 21/22/23: -4.6 %, -3.4 %, -4.4 % (seeds 24-27 outside the suite: -4.9, -3.4, -3.3, -3.8 %; an ideal
# encoder -6.7 to -7.5 %). The open-loop locked swing does not reveal it even with an ideal encoder (σ0 9 % off,
# an 8.4 % held-out gain, below the gain rule).
PRESLIDING_TOLERANCE = 0.08


@pytest.mark.slow
@pytest.mark.parametrize("seed", SEEDS)
def test_presliding_is_recovered_with_a_fine_motor_encoder(seed):
    """With a 22-bit motor encoder the same analysis declares presliding revealable, names it and recovers σ0."""
    log, rig, truth = hidden_effect_log("locked_pi_current", ["presliding_friction"], seed, DURATION_S,
                                        motor_encoder_counts=FINE_MOTOR_ENCODER_COUNTS)
    result = analyse(log, rig)
    assert "presliding_friction" not in result.baseline["not_identifiable"]
    _check(result, truth, "presliding_friction", {"presliding_stiffness": (PRESLIDING_TOLERANCE, "relative")})


# Sensor-feedback PI logs with the 22-bit encoder give a Coulomb level ~13 % low (seed 31: 0.078 for 0.09 N·m):
# the surrogate's bias, not a discrepancy. Its held-out gain is at most 9.6 % (seeds 31-37), under the gain rule;
# rule 'moved' would also reject it, measuring the move from the same fit on the model's own log (seed 31: 0.077).
@pytest.mark.slow
@pytest.mark.parametrize("seed", (31, 32, 33, 35))
@pytest.mark.parametrize("experiment", TESTBED_EXPERIMENTS)  # the rigid joints have no motor encoder
def test_no_false_positives_with_a_fine_motor_encoder(experiment, seed):
    """Baseline logs with the 22-bit motor encoder give no finding.

    Without the minimum parameter change of the significance rule (AnalysisConfig.min_parameter_change) the free
    swing's logs gave a Coulomb level 0.8 % off the baseline's with a 16 % held-out gain (seeds 31-35).
    """
    log, rig, _ = hidden_effect_log(experiment, [], seed, DURATION_S, motor_encoder_counts=FINE_MOTOR_ENCODER_COUNTS)
    assert analyse(log, rig).found == []


@pytest.mark.slow
@pytest.mark.parametrize("seed", (31, 32, 33, 34, 35))
@pytest.mark.parametrize("experiment", EXPERIMENTS)
def test_no_false_positives(experiment, seed):
    """Logs of the baseline itself, in every experiment, give no finding."""
    log, rig, _ = hidden_effect_log(experiment, [], seed, DURATION_S)
    assert analyse(log, rig).found == []


@pytest.mark.slow
@pytest.mark.parametrize("seed", SEEDS)
@pytest.mark.parametrize("experiment, effects", [
    ("free", ["coulomb_friction", "cogging"]),
    ("locked", ["backlash", "sensor_gain"]),
    ("locked", ["torque_constant_nonlinearity", "sensor_thermal_drift"]),
])
def test_two_hidden_effects_are_both_found(experiment, effects, seed):
    """Two effects hidden at once are both found."""
    log, rig, truth = hidden_effect_log(experiment, effects, seed, DURATION_S)
    assert set(effects) <= set(analyse(log, rig).found)


# ------------------------------------------------------------------ baselines other than the defaults of sim.params
# Random baselines drawn from synthetic_logs.BASELINE_RANGES (breakaway, Coulomb/breakaway, Stribeck velocity,
# viscous, load-dependent friction, torque saturation, backlash 0.5-3.5 mrad) with explicit seeds; the log's noise
# seed is 1000 + the baseline's. Zero findings are required on every one.
RANDOM_BASELINES = tuple(range(40))
CLOSED_LOOP_RANDOM_BASELINES = tuple(range(10))


@pytest.mark.slow
@pytest.mark.parametrize("baseline_seed", RANDOM_BASELINES)
@pytest.mark.parametrize("fixture", ["locked", "free"])
def test_no_false_positives_on_random_baselines(fixture, baseline_seed):
    """Logs of a baseline drawn across the plausible ranges, analysed against that rig, give no finding."""
    log, rig, _ = hidden_effect_log(fixture, [], 1000 + baseline_seed, DURATION_S,
                                    baseline=random_baseline_overrides(baseline_seed))
    assert analyse(log, rig).found == []


CLOSED_LOOP_EXPERIMENTS = ("locked_pi_sensor", "locked_pi_current")


@pytest.mark.slow
@pytest.mark.parametrize("baseline_seed", CLOSED_LOOP_RANDOM_BASELINES)
@pytest.mark.parametrize("experiment", CLOSED_LOOP_EXPERIMENTS)
def test_no_false_positives_on_random_baselines_in_closed_loop(experiment, baseline_seed):
    """Both feedback modes of the torque loop, on random baselines, give no finding."""
    log, rig, _ = hidden_effect_log(experiment, [], 1000 + baseline_seed, DURATION_S,
                                    baseline=random_baseline_overrides(baseline_seed))
    assert analyse(log, rig).found == []


@pytest.mark.slow
@pytest.mark.parametrize("seed", (31, 32, 33))
@pytest.mark.parametrize("experiment", TESTBED_EXPERIMENTS)
def test_no_false_positives_on_the_grid_best_baseline(experiment, seed):
    """The parameter set identify_defaults prefers gives no finding on its own logs, in every testbed experiment."""
    log, rig, _ = hidden_effect_log(experiment, [], seed, DURATION_S, baseline=GRID_BEST_OVERRIDES)
    assert analyse(log, rig).found == []


# non-default baselines of the recovery sweep: the grid-best set and two random draws
RECOVERY_BASELINES = {"grid_best": GRID_BEST_OVERRIDES, "random_7": random_baseline_overrides(7),
                      "random_19": random_baseline_overrides(19)}


# The stuck band's upward bias on a low μ: where most samples are stuck, the band ±μ|τ| absorbs any other residual,
# so a larger μ always lowers it. On random_7 a μ drawn below the baseline's comes out 4.4-7.0 % high on seeds 21,
# 23, 27, 28; drawn above it, within 1 %.
LOW_MU_BIAS = pytest.mark.xfail(strict=True, reason="the surrogate's low-μ bias exceeds the 5 % tolerance")


@pytest.mark.slow
@pytest.mark.parametrize("effect, baseline", [
    pytest.param(e, b, marks=LOW_MU_BIAS, id=f"{e}-{b}") if (e, b) == ("load_dependent_friction", "random_7")
    else pytest.param(e, b, id=f"{e}-{b}") for e in CASES for b in RECOVERY_BASELINES])
def test_every_effect_is_recovered_on_non_default_baselines(effect, baseline):
    """Each library effect hidden alone on a non-default baseline (changed relative to that rig where the rig
    carries it) is the first finding, with its parameters within the same tolerances as on the defaults."""
    experiment, tolerances = CASES[effect]
    log, rig, truth = hidden_effect_log(experiment, [effect], 21, DURATION_S, baseline=RECOVERY_BASELINES[baseline])
    _check(analyse(log, rig), truth, effect, tolerances)
