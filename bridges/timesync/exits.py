"""Exit codes every app of the project shares, and what ends a session with the master.

A launcher (the master, a test, a box's service manager) reads an app's exit
code the same way whichever app it is: 0 ok, 1 internal error, 2 bad
configuration, 3 refused by the master, 4 no master answered, 5 the master
went silent during the run.
"""
from __future__ import annotations

from bridges.timesync.errors import JoinTimeout, MasterLost, Refused

EXIT_OK, EXIT_ERROR, EXIT_CONFIG, EXIT_REFUSED, EXIT_NO_MASTER, EXIT_MASTER_LOST = 0, 1, 2, 3, 4, 5
SESSION_ERRORS = (Refused, JoinTimeout, MasterLost)  # the master refused, never answered, or went silent


def session_end(exc: BaseException) -> tuple[int, str]:
    """(exit code, reason) of an app whose session ended with one of SESSION_ERRORS."""
    if isinstance(exc, Refused):
        return EXIT_REFUSED, f"refused: {exc.reason}"
    if isinstance(exc, JoinTimeout):
        return EXIT_NO_MASTER, "no welcome from the master"
    if isinstance(exc, MasterLost):
        return EXIT_MASTER_LOST, str(exc)
    raise TypeError(f"not a session error: {type(exc).__name__}")
