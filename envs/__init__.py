"""Gymnasium environments on the simulated testbed.

``register_envs()`` registers :data:`ENV_ID` with Gymnasium; ``import torquebed`` calls it, so after that
``gymnasium.make("torquebed/TorqueTracking-v0")`` works, and ``gymnasium.make_vec("torquebed/TorqueTracking-v0",
num_envs=N)`` gives N environments stepped together (:mod:`envs.torque_tracking_vector`). Without importing
anything first, use Gymnasium's module prefix: ``gymnasium.make("torquebed:torquebed/TorqueTracking-v0")``.

Importing this module is light; ``register_envs()`` imports Gymnasium (~0.2 s), and the environment itself is
:mod:`envs.torque_tracking`.
"""

from __future__ import annotations

ENV_ID = "torquebed/TorqueTracking-v0"
ENTRY_POINT = "envs.torque_tracking:TorqueTrackingEnv"
VECTOR_ENTRY_POINT = "envs.torque_tracking_vector:TorqueTrackingVectorEnv"


def register_envs() -> None:
    """Register :data:`ENV_ID` with Gymnasium once (a second call is a no-op)."""
    from gymnasium.envs.registration import register, registry

    if ENV_ID not in registry:
        register(id=ENV_ID, entry_point=ENTRY_POINT, vector_entry_point=VECTOR_ENTRY_POINT)
