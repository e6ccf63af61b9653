"""The project's own exception types.

The command line turns :class:`BadInput` into one clear line and exit code 2. Anything else that
escapes a command is a bug in plm-highway and is shown as such (traceback, request to report it),
so a bug never looks like a user's mistake.
"""

from __future__ import annotations


class BadInput(ValueError):
    """Input the user can fix: a file, field, row, option or value outside what the tool accepts.

    The message names the culprit (file, field, row or value) and what would be accepted.
    A subclass of ValueError so that library callers may catch either.
    """


class OutputRefused(BadInput):
    """A command would have replaced or deleted something it did not write (or was not told to)."""
