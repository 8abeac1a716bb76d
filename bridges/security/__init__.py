"""IEEE 1609.2-style security: signed envelopes (ECDSA P-256) and a scenario CA."""
from bridges.security.certificates import (Certificate, Credentials, ScenarioCA, load_certificate,
                                           load_credentials, time64_us, to_time64)
from bridges.security.envelope import (PSID_BSM, PSID_SPAT_MAP, PSID_SRM, PSID_SSM, PSID_SURROGATE_BSM, SIGNER_IDENTIFIERS, Rejection,
                                       Signer, VerificationError, Verified, Verifier, open_unsecured)
from bridges.security.errors import PsidNotPermitted, SecurityError
from bridges.security.oer import NonCanonicalEncoding, SecurityFormatError

__all__ = ["Certificate", "Credentials", "ScenarioCA", "load_certificate", "load_credentials",
           "time64_us", "to_time64", "PSID_BSM", "PSID_SPAT_MAP", "PSID_SURROGATE_BSM", "PSID_SRM", "PSID_SSM",
           "SIGNER_IDENTIFIERS",
           "Rejection", "Signer", "VerificationError", "Verified", "Verifier", "open_unsecured",
           "SecurityError", "PsidNotPermitted", "NonCanonicalEncoding", "SecurityFormatError"]
