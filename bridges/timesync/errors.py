"""Errors of the time protocol: each names the participant (and tick) at fault."""
from __future__ import annotations


class TimeSyncError(RuntimeError):
    """Base of every time-protocol failure a user can act on."""


class ProtocolError(TimeSyncError, ValueError):
    """A payload that is not a valid time-protocol message; the text says why."""


class Refused(TimeSyncError):
    """The master refused a join (version, unknown name, name taken); `reason` says which."""

    def __init__(self, name: str, reason: str):
        self.name, self.reason = name, reason
        super().__init__(f"participant '{name}' refused by the master: {reason}")


class JoinTimeout(TimeSyncError):
    """Expected participants did not join in time (master side) or no welcome came (participant side)."""

    def __init__(self, missing: list[str], timeout_s: float, detail: str = ""):
        self.missing, self.timeout_s = list(missing), timeout_s
        who = ", ".join(f"'{m}'" for m in self.missing)
        super().__init__(f"participant(s) {who} did not join within {timeout_s:g} s{detail}")


class ParticipantTimeout(TimeSyncError):
    """A participant did not acknowledge a tick within its timeout."""

    def __init__(self, name: str, k: int, t: float, timeout_s: float):
        self.name, self.k, self.t, self.timeout_s = name, k, t, timeout_s
        super().__init__(f"participant '{name}' did not acknowledge tick {k} (t = {t:.6g} s) "
                         f"within {timeout_s:g} s")


class ParticipantLost(TimeSyncError):
    """A participant left, crashed or stopped sending heartbeats."""

    def __init__(self, name: str, reason: str):
        self.name, self.reason = name, reason
        super().__init__(f"participant '{name}' lost: {reason}")


class MasterLost(TimeSyncError):
    """Participant side: nothing heard from the master for too long."""
