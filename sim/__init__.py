"""The simulated testbed. Importing this package registers the Gymnasium environment
``torquebed/TorqueTracking-v0`` (see :mod:`envs`)."""

from envs import register_envs as _register_envs

_register_envs()
