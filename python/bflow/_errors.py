"""Exceptions of the package that do not come from the C++ library."""


class ModelError(ValueError):
    """A model that cannot be compiled: the message names the problem and the values."""
