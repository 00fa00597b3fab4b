"""The discrepancy analysis on stand-ins for real drive records (tests/independent/realistic.py: the independent
simulator recorded as real rigs record), judged as the stand-ins' own judges judge them: a servo's PWM duty
command with a torque-constant error, its clean record, a torque sensor zeroed anew before each record, a pendulum
swinging through gravity on a rig that states none, impedance control with little excitation."""

from __future__ import annotations

import pytest

from tests.independent import realistic

CASES = {  # case, its analysis's label -> what its judge's verdict starts with
    ("pwm-arm-s11", ""): "right",
    ("pwm-clean-s13", ""): "ok",
    ("rezeroed-coulomb-s42", "1+1"): "right + offsets named",
    ("gravity-pump-s61", ""): "right",
    ("impedance-clean-s51", ""): "ok",
}


@pytest.mark.parametrize(("name", "label"), list(CASES))
def test_a_stand_in_for_a_real_record_is_named_right(name, label, tmp_path):
    case = next(c for c in realistic.cases() if c.name == name)
    realistic.write_case(case, tmp_path)
    row = realistic.analyse_case(tmp_path / name, label)
    assert row["verdict"].startswith(CASES[(name, label)]), (row["verdict"], row["found"], row["analysis"])
