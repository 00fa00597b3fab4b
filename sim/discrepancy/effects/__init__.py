"""The library of named effects: one module per effect, each a subclass of :class:`base.Effect`.

Every module of this package except ``base`` defines ``EFFECT``, an instance of its effect; this package
collects them, so adding an effect is adding a module (and its tests; ``docs/extending.md`` shows how).

>>> from sim.discrepancy.effects import EFFECTS
>>> EFFECTS["viscous_friction"].params[0].key
'viscous'
"""

from __future__ import annotations

import importlib
import pkgutil

from sim.discrepancy.effects.base import (
    ALL_RIGS,
    HINGE,
    RIGID_RIGS,
    SLIDE,
    TESTBED,
    Effect,
    OwnFit,
    Param,
    Realisation,
    Scale,
    rig_kind,
)


def _discover() -> dict[str, Effect]:
    found = []
    for module in pkgutil.iter_modules(__path__):
        if module.name == "base" or module.name.startswith("_"):
            continue
        effect = importlib.import_module(f"{__name__}.{module.name}").EFFECT
        if effect.name != module.name:
            raise ImportError(f"sim.discrepancy.effects.{module.name} defines effect {effect.name!r}; an effect "
                              f"lives in the module of its name")
        found.append(effect)
    return {effect.name: effect for effect in sorted(found, key=lambda e: (e.order, e.name))}


EFFECTS: dict[str, Effect] = _discover()


def spec(name: str) -> Effect:
    """The effect called ``name``; an unknown name raises ``KeyError`` listing the library."""
    try:
        return EFFECTS[name]
    except KeyError:
        raise KeyError(f"unknown effect {name!r}; the library has: {', '.join(EFFECTS)}") from None


def effect_of_key(key: str) -> Effect:
    """The effect that owns theta entry ``key``."""
    for effect in EFFECTS.values():
        if key in effect.keys:
            return effect
    raise KeyError(f"no effect owns parameter {key!r}")


__all__ = ["ALL_RIGS", "EFFECTS", "HINGE", "RIGID_RIGS", "SLIDE", "TESTBED", "Effect", "OwnFit", "Param", "Realisation",
           "Scale", "effect_of_key", "rig_kind", "spec"]
