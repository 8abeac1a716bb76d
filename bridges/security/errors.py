"""The security package's error types: one base, so a caller can catch everything this package refuses.

All derive from ValueError (what the package raised before it had types), so
existing `except ValueError` handlers keep working.
"""
from __future__ import annotations


class SecurityError(ValueError):
    """Something the security package refuses; `reason` is the human-readable why."""

    def __init__(self, reason: str):
        super().__init__(reason)
        self.reason = reason


class PsidNotPermitted(SecurityError):
    """A signer asked to sign under a PSID its certificate does not list in appPermissions."""

    def __init__(self, certificate: str, psid: int, permitted: set[int]):
        self.certificate, self.psid, self.permitted = certificate, psid, frozenset(permitted)
        super().__init__(f"{certificate!r} may not sign PSID {psid:#x} (permitted: "
                         f"{', '.join(hex(p) for p in sorted(permitted)) or 'none'})")
