"""Every command of ``python -m experiments.<name>``, and the paper's experiments behind one interface.

A paper experiment is run as ``EXPERIMENTS[name].run(params, seed, duration_s, controller)`` and returns a
:class:`Result`: ``rows()`` (each figure beside the paper's: ``{table, quantity, unit, paper, sim, ratio}``, then
the alternative readings of the paper's definitions, which also carry ``reading`` and ``reason``:
:func:`experiments.common.paper_row`),
``to_dict()`` (JSON-ready) and ``plot(directory)`` (the figures written, as paths; a run draws nothing).
``experiments.paper`` runs them in this order; the README's command table and the command-line tests list
:data:`COMMANDS`.
"""

from __future__ import annotations

import sys
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol

from experiments.admittance import run_admittance
from experiments.calibration import run_calibration
from experiments.sinusoid import run_sinusoid
from experiments.step import run_step
from experiments.thermal import run_thermal
from sim.params import TestbedParams


class Result(Protocol):
    """What a paper experiment returns."""

    def rows(self) -> list[dict[str, Any]]: ...

    def to_dict(self) -> dict[str, Any]: ...

    def plot(self, directory: Path) -> list[Path]: ...


@dataclass(frozen=True)
class Experiment:
    """One of the paper's experiments.

    Attributes
    ----------
    name : str
        The command's name: ``python -m experiments.<name>``.
    paper : str
        The paper's sections and tables it reproduces.
    runner : callable
        ``runner(params, seed=..., [duration_s=...], [controller=...], [progress=...]) -> Result``.
    shortens : bool
        Takes ``duration_s`` (a shortened run, a check rather than the paper's protocol).
    controlled : bool
        Takes a controller (:class:`sim.run.Controller` or a factory ``(params, feedback) -> Controller``).
    """

    name: str
    paper: str
    runner: Callable[..., Result]
    shortens: bool = True
    controlled: bool = True

    @property
    def plot_files(self) -> tuple[str, ...]:
        """The files its ``plot(directory)`` writes: the ``PLOT_FILES`` of the runner's module."""
        return sys.modules[self.runner.__module__].PLOT_FILES

    def run(self, params: TestbedParams | None = None, seed: int = 0, duration_s: float | None = None,
            controller=None, progress: bool = False) -> Result:
        """Run the experiment (``duration_s`` and ``controller`` where it takes them; ValueError otherwise)."""
        kwargs: dict[str, Any] = {"seed": seed}
        if duration_s is not None:
            if not self.shortens:
                raise ValueError(f"experiment {self.name!r} has no shortened mode: duration_s must be None")
            kwargs["duration_s"] = duration_s
        if controller is not None:
            if not self.controlled:
                raise ValueError(f"experiment {self.name!r} runs no controller: controller must be None")
            kwargs["controller"] = controller
        if self.shortens:
            kwargs["progress"] = progress
        return self.runner(params, **kwargs)


EXPERIMENTS: dict[str, Experiment] = {e.name: e for e in (
    Experiment("calibration", "Sec. III-B, Tables III-IV", run_calibration, shortens=False, controlled=False),
    Experiment("thermal", "Sec. III-C, Table V", run_thermal, shortens=False, controlled=False),
    Experiment("step", "Sec. IV-A, Table VI", run_step),
    Experiment("sinusoid", "Sec. IV-B, Table VII", run_sinusoid),
    Experiment("admittance", "Sec. IV-C, Fig. 13", run_admittance),
)}

# Every command (python -m experiments.<name>) -> what it is for.
COMMANDS: dict[str, str] = {
    "plant": "the model card: every parameter with unit and source, derived quantities, simulated measurements",
    "step": "PI torque steps and the disturbance test, current vs sensor feedback (Table VI)",
    "sinusoid": "sine and square references, current vs sensor feedback (Table VII)",
    "admittance": "admittance control of the free lever pushed slowly and fast (Fig. 13)",
    "paper": "every paper experiment: one table of every figure beside the simulated one, and the behaviours",
    "identify_defaults": "joint identification of the uncertain defaults within their source bounds, resumable",
    "open_loop_step": "torque steps with the driver's current loop only",
    "calibration": "the calibration rig: LS against QP, Tables III-IV",
    "thermal": "the temperature chamber and the one-hour drift tests, Table V",
    "units": "the sensor's Tables III-V figures over manufactured units: their spread, the paper's percentile",
    "qp_gain": "the QP calibration's resolution gain over LS across random sensor parameter sets",
    "tune": "PI gains tuned on the Gymnasium environment, against the paper's",
    "discrepancy": "what the simulation gets wrong about a measured log, why, and how much a better model gains",
    "discrepancy_demo": "a synthetic log with one effect hidden, to try the discrepancy analysis on",
}
