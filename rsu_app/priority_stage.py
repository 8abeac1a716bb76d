"""The RSU's signal-request stage: frames off the air -> verified, decoded SRMs -> `PriorityCore`; SSMs out.

The thin part beside the pure `rsu_app.priority.PriorityCore`: it runs the
1609.2 checks (bridges.security.Verifier) at the frame's simulated arrival
time, insists on the SRM's PSID, decodes the J2735 frame, and signs the SSM
under the SSM's PSID. Every refusal is a counted reason, never an exception:
a bad SRM must not take the RSU down.
"""
from __future__ import annotations

import time
from collections import Counter

from bridges.j2735 import J2735Error, default_codec
from bridges.j2735.signal_request import SRM_ID, Srm
from bridges.security import PSID_SRM, PSID_SSM, VerificationError, Verifier, time64_us
from bridges.v2x import tx_key, unix_time
from rsu_app.bsm_stage import Transmission, minute_of_year, sign_encoded
from rsu_app.priority import PriorityCore


class PriorityStage:
    def __init__(self, core: PriorityCore, verifier: Verifier | None, station: str, epoch_unix_s: float, envelope,
                 latency):
        self.core, self.verifier = core, verifier
        self.key = tx_key(station)
        self.epoch, self.envelope, self.latency = float(epoch_unix_s), envelope, latency
        self.codec = default_codec()
        self.srms = 0
        self.other_messages: Counter = Counter()   # frames of other kinds on the air, by message id
        self.first_srm_t: float | None = None
        self.verify_s: list[float] = []
        self.sent = 0

    def receive(self, payload: bytes, t_arrival: float) -> Srm | None:
        """One frame heard at t_arrival: the SRM it carried when it was accepted, else None (counted)."""
        if self.verifier is None:
            self.core.reject_frame("no-trust-anchor")
            return None
        c0 = time.perf_counter()
        try:
            verified = self.verifier.verify(bytes(payload), time64_us(unix_time(t_arrival, self.epoch)))
        except VerificationError as exc:
            self.core.reject_frame(exc.reason.value)
            return None
        except Exception:  # the verifier must never take the RSU down
            self.core.reject_frame("malformed")
            return None
        try:
            frame = self.codec.decode(verified.payload)
        except J2735Error:
            self.core.reject_frame("undecodable")
            return None
        if frame.message_id != SRM_ID:
            self.other_messages[frame.message_id] += 1
            return None
        if verified.secured and verified.psid != PSID_SRM:
            self.core.reject_frame("psid-mismatch")
            return None
        try:
            srm = Srm.from_asn1(frame.message)
        except (J2735Error, KeyError, TypeError, ValueError):
            self.core.reject_frame("undecodable")
            return None
        self.verify_s.append(time.perf_counter() - c0)
        self.srms += 1
        if self.first_srm_t is None:
            self.first_srm_t = t_arrival
        self.core.on_srm(srm, t_arrival)
        return srm

    def send(self, t: float) -> Transmission | None:
        """The signed SSM of slot t (None when no request is known)."""
        unix = unix_time(t, self.epoch)
        c0 = time.perf_counter()
        ssm = self.core.ssm(second=round(unix % 60.0, 3), moy=minute_of_year(unix))
        if ssm is None:
            return None
        signed = sign_encoded(ssm.encode(), c0, t, PSID_SSM, self.envelope, self.latency, self.epoch)
        self.sent += 1
        return Transmission(self.key, signed.frame, signed.t_sign, signed.marks(), "ssm",
                            compute_s=signed.compute_s())
