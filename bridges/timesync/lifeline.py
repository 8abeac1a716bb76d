"""An app the master started dies with it: no orphans when the master is killed (`kill -9`, OOM, a crash).

A participant the master launches gets `V2I_MASTER_PID` in its environment.
When the app's parent is still that process, the app asks Linux to send it
SIGTERM the moment its parent dies (prctl PR_SET_PDEATHSIG), and the app's
own SIGTERM handling ends it cleanly with its summary. Without that, an
orphan waits for the master's silence to pass `master_timeout_s` (tens of
seconds) or, if it never joined, for its join timeout.

Apps on other machines (a box over Ethernet) are not the master's children:
they keep relying on the master's heartbeats. Elsewhere than Linux, or if the
parent is not the master (a wrapper script in between), nothing is armed.
"""
from __future__ import annotations

import ctypes
import ctypes.util
import os
import signal
import sys

ENV = "V2I_MASTER_PID"
_PR_SET_PDEATHSIG = 1


def arm(environ=os.environ) -> bool:
    """Arm the parent-death signal if the master started this process; True when armed.

    If the master already died between starting us and this call, we are an orphan: SIGTERM ourselves now."""
    master = environ.get(ENV, "")
    if not master.isdigit() or not sys.platform.startswith("linux"):
        return False
    if os.getppid() != int(master):
        return False  # started through something else, or already orphaned and re-parented
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6", use_errno=True)
        if libc.prctl(_PR_SET_PDEATHSIG, int(signal.SIGTERM), 0, 0, 0) != 0:
            return False
    except (OSError, AttributeError):
        return False
    if os.getppid() != int(master):  # the master died before prctl took effect
        os.kill(os.getpid(), signal.SIGTERM)
    return True
