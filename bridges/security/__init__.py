"""IEEE 1609.2-style security: signed envelopes (ECDSA P-256) and a scenario CA."""
from bridges.security.certificates import (Certificate, Credentials, ScenarioCA, load_certificate,
                                           load_credentials, time64_us)
from bridges.security.envelope import (PSID_BSM, PSID_SPAT_MAP, PSID_SURROGATE_BSM, Rejection, Signer,
                                       VerificationError, Verified, Verifier, open_unsecured)
from bridges.security.oer import SecurityFormatError

__all__ = ["Certificate", "Credentials", "ScenarioCA", "load_certificate", "load_credentials",
           "time64_us", "PSID_BSM", "PSID_SPAT_MAP", "PSID_SURROGATE_BSM", "Rejection", "Signer",
           "VerificationError", "Verified", "Verifier", "open_unsecured", "SecurityFormatError"]
