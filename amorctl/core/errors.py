"""The one error type that user-facing failures raise.

Library code raises :class:`AmorError` for anything the user can fix (a bad file, an unknown
plugin name, invalid weights). The CLI prints its message on one line and exits with
``exit_code``; ``AMORCTL_DEBUG=1`` shows the traceback instead.
"""

from __future__ import annotations


class AmorError(Exception):
    """A failure the user can fix; ``str(err)`` is the whole message, without the 'error:' prefix."""

    def __init__(self, message: str, *, exit_code: int = 2) -> None:
        super().__init__(message)
        self.exit_code = exit_code
