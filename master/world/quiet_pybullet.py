"""pybullet, imported without its build-time banner: ``from master.world.quiet_pybullet import pybullet as pb``.

pybullet's C extension prints ``pybullet build time: <date>`` when it is first
imported (on stderr in the wheels we use, on stdout in older builds), in the
middle of `v2i snapshot` output or of a test session's progress. Every module of
the project imports pybullet from here, so that first import runs with file
descriptors 1 and 2 pointed at /dev/null. C's stdio buffers are flushed before
the switch (nothing printed earlier is lost) and again before the descriptors are
restored (a buffered banner goes to /dev/null, not to the terminal later).

The switch is process-wide for the few milliseconds of the import: another
thread writing at that instant would lose its line. Where it is impossible (no
C library through ctypes, closed descriptors) pybullet is imported plainly.
"""
from __future__ import annotations

import contextlib
import os
import sys

_FDS = (1, 2)


def _import_quietly():
    if "pybullet" in sys.modules:  # the banner comes once per process, at the first import
        return sys.modules["pybullet"]
    try:
        import ctypes

        libc = ctypes.CDLL(None)
        for stream in (sys.stdout, sys.stderr):
            if stream is not None:
                stream.flush()
        libc.fflush(None)
        saved = [os.dup(fd) for fd in _FDS]
    except (OSError, AttributeError, ValueError):
        import pybullet

        return pybullet
    devnull = os.open(os.devnull, os.O_WRONLY)
    try:
        for fd in _FDS:
            os.dup2(devnull, fd)
        import pybullet

        libc.fflush(None)  # a banner still in C's stdout buffer goes to /dev/null now
    finally:
        for fd, copy in zip(_FDS, saved):
            os.dup2(copy, fd)
            os.close(copy)
        os.close(devnull)
    return pybullet


pybullet = _import_quietly()


@contextlib.contextmanager
def stdout_to_stderr():
    """C-level writes to file descriptor 1 go to descriptor 2 while inside.

    pybullet's EGL plugin prints its GL strings ("GL_VENDOR=...", "ven = ...", "Destroy EGL OpenGL window.")
    with printf when it loads, on the first frames and when it closes: on stdout, in the middle of a
    command's `--json` output or a CSV piped on. They go to stderr instead, where logs belong; nothing is
    thrown away. Python's and C's buffers are flushed at both ends, so earlier and later lines stay in
    order. The switch is process-wide while inside (a thread printing to stdout then writes to stderr).
    Where descriptors cannot be duplicated it does nothing."""
    try:
        import ctypes

        libc = ctypes.CDLL(None)
        if sys.stdout is not None:
            sys.stdout.flush()
        libc.fflush(None)
        saved = os.dup(1)
    except (OSError, AttributeError, ValueError):
        yield
        return
    try:
        os.dup2(2, 1)
        yield
    finally:
        libc.fflush(None)
        os.dup2(saved, 1)
        os.close(saved)


def gl_to_stderr(renderer: int):
    """`stdout_to_stderr()` around a pybullet call that draws with `renderer`, if it is EGL's OpenGL (whose
    plugin prints); a no-op context for TinyRenderer."""
    return stdout_to_stderr() if renderer == pybullet.ER_BULLET_HARDWARE_OPENGL else contextlib.nullcontext()


__all__ = ["gl_to_stderr", "pybullet", "stdout_to_stderr"]
