"""A trust store on disk: the folder `v2i pki init` writes, read as what a receiver trusts.

Every `*.cert` in the folder is read. Self-signed ones are the trust anchors
(the scenario CA); the others are station certificates, each of which must be
issued by one of those anchors. Knowing the stations up front lets a tool
verify a digest-signed message (nine of ten BSMs) without first seeing the
sender's full-certificate message. Private keys (`*.key`) are never read.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from bridges.security.certificates import Certificate, load_certificate
from bridges.security.envelope import Verifier
from bridges.security.errors import SecurityError
from bridges.security.oer import SecurityFormatError


@dataclass
class TrustStore:
    directory: Path
    anchors: list[Certificate] = field(default_factory=list)
    stations: list[Certificate] = field(default_factory=list)

    def verifier(self, **policy: Any) -> Verifier:
        """A Verifier trusting the anchors and knowing the stations; `policy` as Verifier's keywords."""
        return Verifier(self.anchors, stations=self.stations, **policy)


def load_trust_store(directory: str | Path) -> TrustStore:
    """The certificates in `directory`; SecurityError listing every problem (unreadable files, orphans)."""
    directory = Path(directory)
    if not directory.is_dir():
        raise SecurityError(f"trust store {str(directory)!r} is not a folder (write one with "
                            f"`v2i pki init {directory}`)")
    store, problems, others = TrustStore(directory), [], []
    for path in sorted(directory.glob("*.cert")):
        try:
            certificate = load_certificate(path)
        except SecurityFormatError as exc:
            problems.append(exc.reason)
            continue
        if certificate.self_signed:
            if certificate.signed_by(None):
                store.anchors.append(certificate)
            else:
                problems.append(f"{path}: self-signed certificate {certificate.name!r} does not verify")
        else:
            others.append((path, certificate))
    anchors = {a.digest for a in store.anchors}
    for path, certificate in others:
        if certificate.issuer_digest in anchors:
            store.stations.append(certificate)
        else:
            problems.append(f"{path}: station certificate {certificate.name!r} is not issued by a CA in this folder")
    if not store.anchors and not problems:
        problems.append(f"no CA certificate (*.cert, self-signed) in {str(directory)!r} (write one with "
                        f"`v2i pki init {directory}`)")
    if problems:
        raise SecurityError("trust store: " + "; ".join(problems))
    return store
