"""The discrepancy analysis on records of a real drive: the EMPS benchmark (Janot, Gautier, Brunot, 2019).

The records are read from ``../shared/data/emps`` beside the project (never copied into it); the test is skipped
where they are absent. From a baseline that knows only the carriage's mass and viscous friction, one run of the
command line with the pulses record for validation must name Coulomb friction first, within 5 % of the published
IDIM-LS value (20.39 N), then a constant force within 20 % of the published offset (-3.16 N), and its saved rig
must predict the validation record's force better than the published model does (5.98 %; at most 5.0 %).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from experiments import discrepancy as cli
from sim.discrepancy.rig import load_rig
from sim.logio import SlideRunLog, write_log
from sim.logmap import log_map_from_dict, read_mapped

EMPS = Path(__file__).resolve().parents[2] / "shared" / "data" / "emps"
PUBLISHED = {"coulomb": 20.3935, "offset": -3.1648, "validation_error": 0.0598}  # the benchmark's IDIM-LS model
RIG = """model = "rigid-joint"
joint = "slide"
mass_kg = 95.1
effort_gain = 1.0
free = []
[friction]
coulomb = 0.0
viscous = 203.5
"""

pytestmark = pytest.mark.skipif(not (EMPS / "DATA_EMPS.mat").exists(), reason=f"the EMPS records are not at {EMPS}")


def emps_log(name: str) -> SlideRunLog:
    """An EMPS record as a run log: time t [s], the force gtau·vir [N], the motor-side position qm [m]."""
    import scipy.io

    m = scipy.io.loadmat(EMPS / name)
    force = float(np.ravel(m["gtau"])[0]) * np.ravel(m["vir"]).astype(float)
    columns = {"time": np.ravel(m["t"]).astype(float), "tau_cmd": force, "q": np.ravel(m["qm"]).astype(float)}
    return SlideRunLog(columns, {"time": "s", "tau_cmd": "N", "q": "m"})


def run_cli(folder: Path, records: dict[str, Path], rig_text: str) -> tuple[dict, Path]:
    """One run of the command line on the estimation and validation records; its JSON result and saved rig."""
    rig = folder / "rig.toml"
    rig.write_text(rig_text, encoding="utf-8")
    out, saved = folder / "out.json", folder / "saved.toml"
    cli.main([str(records["estimation"]), "--rig", str(rig), "--validate", str(records["validation"]), "--json",
              str(out), "--save-rig", str(saved), "--no-plot", "--no-replay"])
    return json.loads(out.read_text(encoding="utf-8")), saved


@pytest.fixture(scope="module")
def converted(tmp_path_factory) -> tuple[dict, Path]:
    """The analysis of the EMPS records converted to run logs (CSV)."""
    folder = tmp_path_factory.mktemp("converted")
    records = {}
    for role, name in (("estimation", "DATA_EMPS.mat"), ("validation", "DATA_EMPS_PULSES.mat")):
        records[role] = folder / f"{role}.csv"
        write_log(emps_log(name), records[role])
    return run_cli(folder, records, RIG)


def test_emps_names_coulomb_then_a_constant_force_and_its_saved_rig_beats_the_published_model(converted):
    result, saved = converted
    names = [f["effect"] for f in result["findings"]]
    assert names[0] == "coulomb_friction"
    coulomb = result["findings"][0]["parameters"]["coulomb"]["value"]
    assert coulomb == pytest.approx(PUBLISHED["coulomb"], rel=0.05)
    assert "constant_effort" in names
    constant = result["findings"][names.index("constant_effort")]["parameters"]["constant_effort"]["value"]
    assert constant == pytest.approx(PUBLISHED["offset"], rel=0.20)
    validation = next(e for e in result["logs"] if e["role"] == "validation")
    assert validation["relative_effort_error"]["final"] <= 0.050 < PUBLISHED["validation_error"]
    carried = load_rig(saved).rigid
    assert carried["coulomb"] == coulomb and carried["constant_effort"] == constant


def test_emps_read_straight_from_its_mat_files_is_the_log_a_converter_writes():
    """The rig's [log] table maps the .mat variables (the force gtau * vir, a 1 x 1 variable times a column) onto
    the very run log a converter script writes, so the analysis of the .mat is the analysis of the converted logs
    (deterministic); docs/own_logs.md runs the command on the .mat files themselves (tests/test_doc_examples.py)."""
    log_map = log_map_from_dict({"columns": {"time": "t", "tau_cmd": "vir * gtau", "q": "qm"}})
    for name in ("DATA_EMPS.mat", "DATA_EMPS_PULSES.mat"):
        record = read_mapped(EMPS / name, log_map, joint="slide")
        converted = emps_log(name)
        (log,) = record.logs
        assert log.units == converted.units and list(log.columns) == list(converted.columns)
        assert all(np.array_equal(log[c], converted[c]) for c in converted.columns)
        assert record.notes == ("time [s] = t", "tau_cmd [N] = vir * gtau, gtau = 35.1507", "q [m] = qm")
