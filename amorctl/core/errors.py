"""The one error type that user-facing failures raise, and the one warning type.

Library code raises :class:`AmorError` for anything the user can fix (a bad file, an unknown
plugin name, invalid weights). The CLI prints its message on one line and exits with
``exit_code``; ``AMORCTL_DEBUG=1`` shows the traceback instead. Library code issues an
:class:`AmorWarning` (``warnings.warn``) for what the user should know but that does not stop the
command (input that cannot be verified); the CLI prints it as one ``warning:`` line on stderr.
"""

from __future__ import annotations


class AmorError(Exception):
    """A failure the user can fix; ``str(err)`` is the whole message, without the 'error:' prefix."""

    def __init__(self, message: str, *, exit_code: int = 2) -> None:
        super().__init__(message)
        self.exit_code = exit_code


class AmorWarning(UserWarning):
    """A notice the user should see that does not stop the command; ``str(warning)`` is the whole
    message, without the 'warning:' prefix."""


class AmorNote(AmorWarning):
    """Something amorctl did on its own that the user should know of (a stale lock recovered, a
    damaged cache rebuilt); the CLI prints it as one ``note:`` line on stderr."""
