"""The error a model raises for a parameter set it cannot be built from.

:mod:`sim.params` re-exports it as ``sim.params.ParameterError``, the name the validation of a parameter set
and every caller use.
"""


class ParameterError(ValueError):
    """A parameter set that is not physically valid; the message names the field and its valid range."""
