"""Exceptions raised by cooploc.

Every error a user can cause (bad arrays, bad configuration) is a `CooplocError`, and
its message names the field and the offending value, so that nobody has to read a
NumPy traceback from deep inside an estimator to learn what was wrong.
"""

from __future__ import annotations

__all__ = ["ConfigError", "CooplocError", "InvalidInputError"]


class CooplocError(Exception):
    """Base class of every error cooploc raises on purpose."""


class InvalidInputError(CooplocError, ValueError):
    """An array or value handed to cooploc is malformed (shape, NaN, covariance, ids)."""


class ConfigError(CooplocError, ValueError):
    """A scenario, estimator or experiment configuration is invalid (unknown key, bad value)."""
