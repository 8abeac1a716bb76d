"""The 1609.2 envelope around every message the RSU sends: signed with its certificate, or unsecured.

Loading the station's credentials is part of checking the configuration: a
missing file, a key that does not match its certificate, or a certificate that
may not sign a PSID the app will use is a configuration error naming
`security.pki_dir` / `security.credential`, before the app joins a run.
"""
from __future__ import annotations

from pathlib import Path

from bridges.security import PSID_SPAT_MAP, PSID_SURROGATE_BSM, SecurityFormatError, Signer, load_credentials
from bridges.security import oer
from bridges.security.oer import PROTOCOL_VERSION
from rsu_app.config import ConfigError

PSID_NAMES = {PSID_SURROGATE_BSM: "surrogate BSM (J2945/8 test PSID 0x7f)", PSID_SPAT_MAP: "SPaT/MAP (0x82)"}


class Envelope:
    def __init__(self, signer: Signer | None):
        self.signer = signer

    @property
    def signed(self) -> bool:
        return self.signer is not None

    @classmethod
    def load(cls, mode: str, pki_dir: str | None, credential: str, psids: list[int],
             certificate_interval_s: float = 1.0) -> "Envelope":
        if mode == "unsecured":
            return cls(None)
        directory = Path(pki_dir or ".")
        try:
            credentials = load_credentials(directory, credential)
        except SecurityFormatError as exc:
            raise ConfigError([("security.pki_dir", f"cannot load the credentials {credential!r} from "
                                                    f"{str(directory)!r}: {exc.reason}")]) from None
        permitted = credentials.certificate.psids
        missing = [p for p in psids if p not in permitted]
        if missing:
            names = ", ".join(PSID_NAMES.get(p, hex(p)) for p in missing)
            raise ConfigError([("security.credential", f"certificate {credential!r} may not sign {names} (it "
                                                       f"permits {', '.join(hex(p) for p in sorted(permitted))}); "
                                                       f"issue it with `v2i pki init DIR --station "
                                                       f"{credential}:{','.join(hex(p) for p in psids)}`")])
        return cls(Signer(credentials, certificate_interval_s))

    def wrap(self, payload: bytes, psid: int, generation_time_us: int) -> bytes:
        if self.signer is not None:
            return self.signer.sign(payload, psid, generation_time_us)
        return oer.encode("Ieee1609Dot2Data", {"protocolVersion": PROTOCOL_VERSION,
                                               "content": ("unsecuredData", bytes(payload))})
