"""Every command line runs in a short mode and writes what it promises."""

import json
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def run(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", *args], cwd=ROOT, capture_output=True, text=True, timeout=300)


def test_plant_card_prints_the_tables_and_writes_the_json(tmp_path):
    """experiments.plant: parameter table, derived quantities, the card's JSON keys, and its figure."""
    out = tmp_path / "card.json"
    result = run("experiments.plant", "--json", str(out), "--plot", str(tmp_path))
    assert result.returncode == 0, result.stderr
    assert (tmp_path / "plant.png").stat().st_size > 0 and f"figure: {tmp_path / 'plant.png'}" in result.stdout
    assert "flexure_stiffness" in result.stdout and "paper: 5975 Hz estimate, 3407 Hz FEA" in result.stdout
    card = json.loads(out.read_text())
    bounded = {"value", "unit", "source", "bound", "bound_source"}
    assert set(card["parameters"]["friction.breakaway_torque_nm"]) == bounded
    assert set(card["parameters"]["simulation.control_period_s"]) == bounded - {"bound", "bound_source"}
    assert card["parameters"]["friction.breakaway_torque_nm"]["bound"] == [0.117, 0.143]
    assert "[0.02, 0.04]" in result.stdout and "] !" not in result.stdout  # every default inside its bound
    printed = result.stdout.splitlines()
    assert max(len(line) for line in printed) <= 160  # sources wrap
    longest = max(card["parameters"].values(), key=lambda row: len(row["source"]))["source"]
    assert len(longest) > 160 - 70 and longest in " ".join(line.strip() for line in printed)  # wrapped, not cut
    for key, unit in [("flexure_stiffness", "N·m/rad"), ("flexure_youngs_modulus", "Pa"),
                      ("flexure_shear_modulus", "Pa"), ("breakaway_torque_measured", "N·m"),
                      ("backlash_width_measured", "rad")]:
        assert card["derived"][key]["unit"] == unit
        assert card["derived"][key]["value"] > 0
    motor = {k.split(".", 1)[1]: v["value"] for k, v in card["parameters"].items() if k.startswith("motor.")}
    # the command that delivers the peak through τ = c/(1 + α|c|), solved by hand: 18/(1 - 18α) = 26.3 N·m
    limit = motor["peak_torque_nm"] / (1.0 - motor["torque_saturation_per_nm"] * motor["peak_torque_nm"])
    assert card["derived"]["driver_command_limit"] == {"value": pytest.approx(limit, rel=1e-12), "unit": "N·m"}
    for fixture in ("locked", "free"):  # the substeps are what the stricter of the rule's two parts asks for
        rules = [card["derived"][f"substeps_{fixture}_{rule}_rule"]["value"] for rule in ("modes", "presliding")]
        assert card["derived"][f"substeps_{fixture}"]["value"] == max(rules)


def test_plant_card_rejects_a_bad_parameter_file_naming_the_field(tmp_path):
    """--params with an out-of-range value exits with status 2 and names the field and the range."""
    bad = tmp_path / "bad.toml"
    bad.write_text("[flexure]\nyoungs_modulus_pa = -1.0\n")
    result = run("experiments.plant", "--params", str(bad))
    assert result.returncode == 2
    assert "flexure.youngs_modulus_pa = -1.0 Pa is out of its valid range" in result.stderr


def test_open_loop_step_short_run_prints_paper_beside_simulation(tmp_path):
    """experiments.open_loop_step in a short mode: table with the paper's fractions, JSON and a figure."""
    result = run("experiments.open_loop_step", "--duration", "0.2", "--json", str(tmp_path / "r.json"),
                 "--plot", str(tmp_path))
    assert result.returncode == 0, result.stderr
    assert "paper" in result.stdout and "30%" in result.stdout
    data = json.loads((tmp_path / "r.json").read_text())
    assert [s["command_nm"] for s in data["steps"]] == pytest.approx([0.05, 0.1, 0.2])
    assert (tmp_path / "open_loop_step.png").stat().st_size > 10_000


def test_open_loop_step_refuses_a_non_positive_duration():
    """--duration 0 is a usage error naming the flag."""
    result = run("experiments.open_loop_step", "--duration", "0")
    assert result.returncode == 2 and "--duration" in result.stderr


def test_discrepancy_demo_writes_a_log_whose_hidden_effect_the_analysis_names(tmp_path):
    """experiments.discrepancy_demo: a log and its baseline rig; the analysis of the pair names the hidden effect
    first and recovers its value within the sweep's 5 %; a second demo into the same place is refused."""
    demo = run("experiments.discrepancy_demo", "--effect", "coulomb_friction", "--duration", "6", "--out",
               str(tmp_path))
    assert demo.returncode == 0, demo.stderr
    hidden = float(demo.stdout.split("coulomb = ")[1].split()[0])
    result = run("experiments.discrepancy", str(tmp_path / "demo_log.csv"), "--rig", str(tmp_path / "demo_rig.toml"),
                 "--no-replay", "--plot", str(tmp_path))
    assert result.returncode == 0, result.stderr
    line = next(line for line in result.stdout.splitlines() if line.strip().startswith("1. coulomb_friction"))
    found = line.split("coulomb = ")[1].split()[0]
    assert float(found) == pytest.approx(hidden, rel=0.05)
    again = run("experiments.discrepancy_demo", "--out", str(tmp_path))
    assert again.returncode == 2 and "exists" in again.stderr


@pytest.mark.parametrize("step", ["0", "100", "nan"])
def test_open_loop_step_refuses_a_step_of_zero_or_beyond_the_driver_limit(step):
    """A zero step, one the driver would clip (±26.3 N·m) or a non-number is a usage error with the valid range."""
    result = run("experiments.open_loop_step", "--steps", step)
    assert result.returncode == 2 and "valid steps are non-zero, within the driver's command limit" in result.stderr


def test_the_plant_card_marks_a_value_outside_its_source_bound():
    from experiments.plant import _bound_text

    assert _bound_text({"value": 0.05, "bound": [0.02, 0.04]}) == "[0.02, 0.04] !"
    assert _bound_text({"value": 0.03, "bound": [0.02, 0.04]}) == "[0.02, 0.04]"
    assert _bound_text({"value": 0.03}) == ""
