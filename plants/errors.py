"""Typed errors raised by evstab.

Every error names what was wrong (file, field, key, column, row) and what was
expected, so that the message alone tells a user what to fix.
"""

from __future__ import annotations


class EvstabError(Exception):
    """Base class of every error evstab raises on purpose."""


class ParameterError(EvstabError, ValueError):
    """A vehicle parameter (or parameter file) is missing, unknown or out of range."""


class ModelError(EvstabError, ValueError):
    """A model was asked for something it cannot do (wrong signal, wrong time base, ...)."""


class ManeuverError(EvstabError, ValueError):
    """A manoeuvre definition is inconsistent (negative speed, unknown name, ...)."""
