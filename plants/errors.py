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


class DesignError(EvstabError, ValueError):
    """A controller design, a design folder or a design setting is invalid."""


class SettingsError(EvstabError, ValueError):
    """A setting of a tool (monitor, fault injection, executor, writer) is invalid."""


class DataError(EvstabError, ValueError):
    """The data cannot answer the question asked (too few samples, no excitation, not the test run)."""


class CompileError(EvstabError, RuntimeError):
    """Compiling or calling generated code failed."""
