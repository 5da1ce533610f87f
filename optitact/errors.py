"""Exceptions raised by optitact.

Every package exception subclasses the matching built-in, so callers that
catch ``ValueError`` or ``TypeError`` keep working.
"""

from __future__ import annotations

__all__ = ["OptitactError", "ShapeError", "InputError", "RenderError", "MissingExtraError"]


class OptitactError(Exception):
    """Base class of optitact's own exceptions (never raised directly)."""


class ShapeError(OptitactError, ValueError):
    """An array has the wrong shape or size."""


class InputError(OptitactError, ValueError):
    """A value is out of range, not finite, or otherwise unusable."""


class RenderError(OptitactError, RuntimeError):
    """Mitsuba could not be set up or failed while rendering."""


class MissingExtraError(OptitactError, ImportError):
    """An optional dependency is not installed; the message names the extra that brings it."""
