"""Ending a run on SIGTERM or Ctrl-C without blaming an FMU for it.

pythonfmu slaves run their Python in the master's own interpreter, so an exception a signal handler raises
lands in whatever Python frame is running at that instant. When that is a slave's `do_step`, pythonfmu
catches it and reports fmi2Fatal, and the run ends "failed: instance 'car' failed in doStep ... Interrupted()"
instead of "interrupted" (CI saw exactly that). So a signal that arrives while FMU code runs is held, and
the loop raises it once the FMU call has returned (`SignalGuard.check`, after every step); anywhere else it
raises at once, so a blocking wait (the pacer's sleep, a lockstep tick) still ends promptly.

`Interrupted` is a BaseException, as KeyboardInterrupt is, for the same reason: the loop's `except Exception`
turns whatever a doStep raises into that FMU's failure, and a signal handled in the Python around an FMU call
(fmpy's wrapper, the loop between two FMUs) raised there too: "instance 'car' failed in doStep at t = 0.29 s: "
with an empty reason, seen once in a full suite.
"""
from __future__ import annotations

import os
import signal
from pathlib import Path
from typing import Callable, Iterable


class Interrupted(BaseException):
    """SIGTERM/SIGINT during a run: stop, keep what was recorded. Not an Exception: no handler of errors
    (an FMU's, a hook's) may take it for its own."""


def _prefix(folder) -> str:
    return os.path.join(os.path.realpath(folder), "")


class SignalGuard:
    """SIGTERM (and SIGINT where Python's own Ctrl-C handler is in place) raise Interrupted, except inside
    FMU code: code under one of `fmu_dirs()` (the unzipped FMUs: a pythonfmu slave's module is in its
    resources) or in the pythonfmu package, anywhere up the interrupted frame's stack."""

    def __init__(self, fmu_dirs: Callable[[], Iterable[str]]):
        self.fmu_dirs = fmu_dirs
        self.pending: int | None = None  # the signal held until the FMU call returns
        self._previous: dict[int, object] = {}
        try:
            import pythonfmu

            self._package = _prefix(Path(pythonfmu.__file__).parent)
        except ImportError:  # no Python FMU can run without it
            self._package = None

    def install(self) -> None:
        """Take SIGTERM, and SIGINT unless it is ignored or someone else's; a no-op outside the main thread."""
        for signum in (signal.SIGTERM, signal.SIGINT):
            current = signal.getsignal(signum)
            if signum == signal.SIGINT and current is not signal.default_int_handler:
                continue  # ignored (a background job) or handled by the embedding program: leave it so
            try:
                self._previous[signum] = signal.signal(signum, self._handler)
            except ValueError:  # not the main thread: signals are not ours to take
                return

    def restore(self) -> None:
        for signum, previous in self._previous.items():
            signal.signal(signum, previous)
        self._previous = {}

    def check(self) -> None:
        """Raise the signal held while FMU code ran (call it where no FMU call is in progress)."""
        if self.pending is not None:
            self.pending = None
            raise Interrupted()

    def in_fmu_code(self, frame) -> bool:
        prefixes = tuple(_prefix(d) for d in self.fmu_dirs() if d)
        if self._package:
            prefixes += (self._package,)
        while frame is not None and prefixes:
            if os.path.realpath(frame.f_code.co_filename).startswith(prefixes):
                return True
            frame = frame.f_back
        return False

    def _handler(self, signum, frame) -> None:
        if self.in_fmu_code(frame):
            self.pending = signum
            return
        raise Interrupted()
