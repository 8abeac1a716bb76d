"""The attacker's keys, and the envelopes its ghost frames travel in.

* unsigned: the BSM as 1609.2 unsecuredData (no signature at all);
* untrusted: signed with a station certificate of a CA the attacker made
  itself; it copies the scenario CA's name and the RSU's station name, so only
  the chain to a trust anchor tells it apart. Made in memory for each run,
  valid from an hour before now;
* expired: signed with a genuine station certificate of the scenario CA whose
  validity has ended, and its private key (a certificate stolen from a station
  that has since been re-keyed). Kept on disk in `stolen_dir`. When it is
  missing there (a fresh checkout), the simulator plays the CA's past: it
  loads the scenario CA from `pki_dir` and issues the certificate with a
  validity that ended `EXPIRED_AGO_DAYS` ago. The CA's key is used for that
  and nothing else; the attack itself signs only with the expired key.

Every signed ghost frame carries its full certificate ("certificate" signer
identifier): the strongest attempt, since a receiver that does not know the
signer must then check the chain and the validity instead of refusing an
unknown digest.
"""
from __future__ import annotations

from dataclasses import dataclass
from datetime import datetime, timedelta, timezone
from pathlib import Path
from typing import Callable

from bridges.security import (PSID_SURROGATE_BSM, Credentials, ScenarioCA, SecurityFormatError, Signer,
                              load_credentials, time64_us)
from bridges.security import oer
from bridges.security.oer import PROTOCOL_VERSION

CA_NAME = "v2i-scenario-ca"  # the scenario CA's name (master/scenario/pki.py): the rogue CA copies it
IMPERSONATED = "rsu"  # the station name the untrusted and the stolen certificates carry
EXPIRED_AGO_DAYS = 30  # the stolen certificate's validity ended this long before it is made
EXPIRED_HOURS = 24 * 7  # ... after a week of validity


class CredentialError(ValueError):
    """The attacker's keys cannot be made or read; `key` names the config key to fix."""

    def __init__(self, key: str, reason: str):
        super().__init__(f"{key}: {reason}")
        self.key, self.reason = key, reason


Wrap = Callable[[bytes, int], bytes]  # (J2735 payload, 1609.2 generation time in µs) -> envelope bytes


def unsigned(payload: bytes, generation_time_us: int) -> bytes:
    """1609.2 unsecuredData: what a receiver requiring signatures refuses first."""
    return oer.encode("Ieee1609Dot2Data", {"protocolVersion": PROTOCOL_VERSION,
                                           "content": ("unsecuredData", bytes(payload))})


def signed_by(credentials: Credentials, psid: int = PSID_SURROGATE_BSM) -> Wrap:
    """Signs under `psid` with `credentials`, the full certificate in every frame."""
    signer = Signer(credentials, signer_identifier="certificate")

    def wrap(payload: bytes, generation_time_us: int) -> bytes:
        return signer.sign(payload, psid, generation_time_us)
    return wrap


def rogue_station(now: datetime | None = None) -> Credentials:
    """A station certificate (PSID 0x7F, named like the RSU) from a fresh CA of the attacker's own."""
    start = (now or datetime.now(timezone.utc)) - timedelta(hours=1)
    return ScenarioCA.create(CA_NAME, start=start).issue(IMPERSONATED, [PSID_SURROGATE_BSM], start=start)


@dataclass
class Stolen:
    credentials: Credentials
    made: bool  # issued now (from the scenario CA's past) rather than read from stolen_dir


def stolen_expired(stolen_dir: Path, pki_dir: Path | None, now: datetime | None = None) -> Stolen:
    """The expired certificate and key in `stolen_dir`; issued there from the scenario CA in `pki_dir` when
    missing, issued by another CA (the scenario's keys were made anew) or, oddly, not expired."""
    now = now or datetime.now(timezone.utc)
    ca = None
    if pki_dir is not None:
        try:
            ca = ScenarioCA.load(pki_dir, CA_NAME)
        except SecurityFormatError as exc:
            raise CredentialError("keys.pki_dir", f"cannot load the scenario CA {CA_NAME!r}: {exc.reason} "
                                                  f"(`v2i pki init` or the scenario's [pki] makes it)") from None
    try:
        cred = load_credentials(stolen_dir, IMPERSONATED)
    except SecurityFormatError:
        cred = None
    if cred is not None and _expired_from(cred, ca, now):
        return Stolen(cred, made=False)
    if ca is None:
        why = "holds no usable expired certificate" if cred is None else "holds a certificate that is not expired"
        raise CredentialError("keys.stolen_dir", f"{str(stolen_dir)!r} {why} ({IMPERSONATED}.cert/.key); give "
                                                 f"keys.pki_dir (the scenario CA) to issue one")
    start = now - timedelta(days=EXPIRED_AGO_DAYS)
    cred = ca.issue(IMPERSONATED, [PSID_SURROGATE_BSM], start=start, hours=EXPIRED_HOURS)
    try:
        cred.save(stolen_dir)
    except OSError as exc:
        raise CredentialError("keys.stolen_dir", f"cannot write {str(stolen_dir)!r}: {exc.strerror}") from None
    return Stolen(cred, made=True)


def _expired_from(cred: Credentials, ca: ScenarioCA | None, now: datetime) -> bool:
    """Expired at `now`, and (when the CA is known) issued by it."""
    end_us = cred.certificate.validity_us()[1]
    if end_us >= time64_us(now.timestamp()):
        return False
    return ca is None or cred.certificate.issuer_digest == ca.certificate.digest
