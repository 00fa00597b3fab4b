"""Gymnasium environments on the simulated testbed.

``register_envs()`` registers :data:`ENV_ID` with Gymnasium; ``import sim`` calls it, so after that
``gymnasium.make("torquebed/TorqueTracking-v0")`` works. Without importing anything first, use Gymnasium's
module prefix: ``gymnasium.make("sim:torquebed/TorqueTracking-v0")``. (The ``gymnasium.envs`` entry point in
pyproject.toml serves Gymnasium 0.26-0.29, which load plugins from it; Gymnasium >= 1.0 no longer does.)

This module imports nothing heavy: the environment itself is :mod:`envs.torque_tracking`.
"""

from __future__ import annotations

ENV_ID = "torquebed/TorqueTracking-v0"
ENTRY_POINT = "envs.torque_tracking:TorqueTrackingEnv"


def register_envs() -> None:
    """Register :data:`ENV_ID` with Gymnasium once (a second call is a no-op)."""
    from gymnasium.envs.registration import register, registry

    if ENV_ID not in registry:
        register(id=ENV_ID, entry_point=ENTRY_POINT)
