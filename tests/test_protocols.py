"""The paper's protocols (sim.protocols): defined once, as the paper states them, shared by the environment."""

import numpy as np
import pytest

from envs.references import make_reference
from sim.protocols import DISTURBANCE, PROTOCOLS, PUSHES, STEPS_NM, WAVEFORMS, Push


def test_the_registry_holds_the_papers_protocols_in_its_order():
    assert list(PROTOCOLS) == ["step 0.05 N·m", "step 0.1 N·m", "step 0.2 N·m", "disturbance",
                               "0.05 N·m sine 0.2 Hz", "0.1 N·m square 1 Hz", "10 N·m sine 0.2 Hz",
                               "slow push", "fast push"]
    assert STEPS_NM == (0.05, 0.1, 0.2)  # Table VI
    assert [(w.shape, w.amplitude_nm, w.frequency_hz) for w in WAVEFORMS] == [
        ("sine", 0.05, 0.2), ("square", 0.1, 1.0), ("sine", 10.0, 0.2)]  # Table VII
    assert DISTURBANCE.regulated_nm == 0.5 and DISTURBANCE.max_nm > 2.0  # Sec. IV-A: "past 2 N·m"


def test_the_disturbance_ramps_from_its_start_at_its_rate_to_its_largest_torque():
    t = np.array([0.0, DISTURBANCE.pre_s, DISTURBANCE.pre_s + 10.0, DISTURBANCE.duration_s, 1e4])
    expected = [0.0, 0.0, -10.0 * DISTURBANCE.rate_nm_per_s, -DISTURBANCE.max_nm, -DISTURBANCE.max_nm]
    np.testing.assert_allclose(DISTURBANCE.hub_torque(t), expected, rtol=1e-12)


def test_a_push_follows_a_minimum_jerk_path_and_its_hand_is_a_spring_and_damper():
    push = PUSHES[0]
    angle, velocity = push.path(np.array([0.0, push.before_s + push.push_s / 2, push.duration_s]))
    assert angle.tolist() == pytest.approx([0.0, push.angle_rad / 2, push.angle_rad])
    assert velocity[1] == pytest.approx(1.875 * push.angle_rad / push.push_s)  # 30/16 at mid-path
    at_rest = Push("still", 1.0, stiffness_nm_per_rad=5.0, damping_nms_per_rad=0.05)
    assert at_rest.torque_nm(0.0, 0.1, 2.0) == pytest.approx(-5.0 * 0.1 - 0.05 * 2.0)


@pytest.mark.parametrize("task", ["step", "sine", "square"])
def test_the_environments_paper_tasks_are_drawn_from_the_registry(task):
    rng = np.random.default_rng(0)
    for _ in range(20):
        ref = make_reference(task, 2000, 1e-3, rng)
        if task == "step":
            assert ref.amplitude_nm in STEPS_NM
        else:
            assert (ref.amplitude_nm, ref.frequency_hz) in {(w.amplitude_nm, w.frequency_hz) for w in WAVEFORMS
                                                           if w.shape == task}
