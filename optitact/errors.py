"""Exceptions raised by optitact.

Every package exception subclasses the matching built-in, so callers that
catch ``ValueError`` or ``TypeError`` keep working.
"""

from __future__ import annotations

__all__ = ["OptitactError", "ShapeError", "InputError", "RenderError", "MissingExtraError", "KindError",
           "RegistrationError", "GainsError", "OptitactWarning"]


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


class KindError(OptitactError, TypeError):
    """Data of the wrong kind (e.g. a frame whose dtype is not a number) where a user's data came in.

    A ``TypeError``, so callers catching it keep working; a subclass so that
    the command line can tell the user's bad data from a programming error.
    """


class RegistrationError(InputError):
    """Registration: the frames cannot pin the model down; the message says what to add.

    Too few spots or elements, an ambiguous association, a degenerate pose.
    """


class GainsError(RegistrationError):
    """Registration's ``fit_gains``: no pressed element's gain could be measured (the pose fit was fine)."""


class OptitactWarning(UserWarning):
    """Data that can be read but may give wrong or less certain forces (lossy frames, a noisy baseline).

    The command line prints each as one ``optitact: warning: ...`` line on
    stderr; in Python, ``warnings.simplefilter("error", OptitactWarning)``
    turns them into errors.
    """
