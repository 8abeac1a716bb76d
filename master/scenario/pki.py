"""`[pki]`: the scenario's credentials, made when a run needs them and missing.

The apps sign and verify their V2X frames with certificates of a scenario CA
(`v2i pki init`, bridges.security). A scenario that names them here::

    [pki]
    dir = "keys"                                    # relative to the scenario file
    stations = { rsu = "0x7f,0x82", cav = "0x20" }  # station -> the PSIDs it may sign

runs as printed in a fresh checkout: before anything else opens, the master
makes the CA and every station's certificate that is missing from `dir`, and
re-issues a station certificate that has expired (or will within a day) or
lacks a PSID. What exists and is valid is never touched, so keys copied onto a
box stay the ones the run uses. The metadata section says what was made.

Two runs of scenarios that share a keys folder may start at once (a user's two
shells, a sweep's points, the tests two at a time): the check-and-make holds a
file lock in that folder, so the second finds what the first made instead of
making a second CA over it, which would leave the first run's apps with a
certificate the other CA never issued.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

from filelock import FileLock

from master.hooks import Hook, RunContext
from master.scenario.tables import Table

CA_NAME = "v2i-scenario-ca"
RENEW_BEFORE_S = 24 * 3600.0  # a station certificate expiring within this is re-issued


@dataclass
class PkiSpec:
    dir: Path
    stations: dict[str, list[int]] = field(default_factory=dict)

    def resolved(self) -> dict[str, Any]:
        return {"dir": str(self.dir),
                "stations": {n: ",".join(hex(p) for p in psids) for n, psids in self.stations.items()}}


def read_section(value: Any, context) -> PkiSpec | None:
    """The reader of `[pki]` (master.scenario.sections)."""
    t = Table(value, "pki", context.problem)
    if not t.ok:
        return None
    t.unknown_keys(("dir", "stations"))
    directory = t.string("dir", None, expected="a folder for the scenario CA and the stations' credentials",
                         required=True)
    stations = t.sub("stations", "a table of station = \"PSID[,PSID...]\"")
    spec = PkiSpec(Path(directory or "."))
    for name, psids in stations.raw.items():
        if not isinstance(psids, str):
            stations.problem(name, f"expected PSIDs as a string such as \"0x7f,0x82\", got {psids!r}")
            continue
        try:
            spec.stations[name] = [int(p, 0) for p in psids.split(",")]
        except ValueError:
            stations.problem(name, f"{psids!r}: PSIDs must be integers, comma-separated (\"0x7f,0x82\" or \"127\")")
    if not spec.stations and stations.ok:
        t.problem("stations", "expected at least one station = \"PSID[,PSID...]\"")
    if not t.ok or not stations.ok or directory is None:
        return None
    base = Path(directory).expanduser()
    spec.dir = base if base.is_absolute() else context.base_dir / base
    return spec


def ensure(spec: PkiSpec, now: datetime | None = None) -> dict[str, Any]:
    """Make what is missing in spec.dir (the CA, station credentials); returns what was made and kept."""
    now = now or datetime.now(timezone.utc)
    spec.dir.mkdir(parents=True, exist_ok=True)
    with FileLock(spec.dir / ".pki.lock"):
        return _ensure_locked(spec, now)


def _ensure_locked(spec: PkiSpec, now: datetime) -> dict[str, Any]:
    from bridges.security.certificates import ScenarioCA, load_credentials, time32

    made, kept = [], []
    if (spec.dir / f"{CA_NAME}.key").exists():
        ca = ScenarioCA(load_credentials(spec.dir, CA_NAME))
    else:
        ca = ScenarioCA.create(CA_NAME)
        ca.credentials.save(spec.dir)
        made.append(CA_NAME)
    for name, psids in spec.stations.items():
        if _usable(spec.dir, name, psids, ca, time32(now) + RENEW_BEFORE_S):
            kept.append(name)
            continue
        ca.issue(name, psids).save(spec.dir)
        made.append(name)
    return {"dir": str(spec.dir), "made": made, "kept": kept}


def _usable(directory: Path, name: str, psids: list[int], ca, valid_until: float) -> bool:
    from bridges.security.certificates import load_credentials
    from bridges.security.oer import SecurityFormatError

    try:
        cred = load_credentials(directory, name)
    except SecurityFormatError:
        return False
    cert = cred.certificate
    return (cert.issuer_digest == ca.certificate.digest and set(psids) <= cert.psids
            and cert.validity()[1] > valid_until)


class PkiHook(Hook):
    """Opens first: the credentials exist before any app starts and reads them."""

    name = "pki"

    def __init__(self, spec: PkiSpec):
        self.spec = spec

    def open(self, ctx: RunContext) -> dict[str, Any]:
        return ensure(self.spec)
