"""torquebed: a MuJoCo testbed for torque-controlled robot joints.

Importing this package registers the Gymnasium environments (:data:`ENV_IDS`), as Gymnasium 1.x third-party
packages do::

    import gymnasium
    import torquebed

    gymnasium.register_envs(torquebed)  # a no-op that keeps the import used
    env = gymnasium.make("torquebed/TorqueTracking-v0")

``gymnasium.make("torquebed:torquebed/TorqueTracking-v0")`` imports the package itself. The simulation
(:mod:`sim`), the sensor, the controllers and the experiments are the packages beside this one; importing them
registers nothing.
"""

from envs import ENV_ID, register_envs

register_envs()

ENV_IDS = (ENV_ID,)

__all__ = ["ENV_IDS"]
