"""Flags and output helpers shared by the experiment command lines."""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path
from typing import Any

import numpy as np

from sim.params import ParameterError, TestbedParams, load_params


def add_params_arg(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--params", type=Path, metavar="TOML",
                        help="TOML file overriding parameters, e.g. [friction] breakaway_torque_nm = 0.2")


def load_params_arg(parser: argparse.ArgumentParser, args: argparse.Namespace) -> TestbedParams:
    """Load --params, turning a bad file into a command-line error that names the field."""
    try:
        return load_params(args.params)
    except ParameterError as exc:
        parser.error(str(exc))


def _jsonable(x: Any) -> Any:
    if isinstance(x, dict):
        return {k: _jsonable(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_jsonable(v) for v in x]
    if isinstance(x, np.ndarray):
        return _jsonable(x.tolist())
    if isinstance(x, (np.floating, float)):
        return float(x) if math.isfinite(x) else None
    if isinstance(x, np.integer):
        return int(x)
    return x


def write_json(path: Path, data: dict[str, Any]) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(_jsonable(data), indent=2, ensure_ascii=False) + "\n")
