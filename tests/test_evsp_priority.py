"""EVSP at the RSU, without bus or controller: signed SRMs are verified (PSID, trust), arbitrated (one request
per approach, emergency first) into a preemption call and SSM statuses (requested -> processing -> granted);
bad SRMs get the right SSM status or a counted rejection, never an exception (issue 39)."""
from __future__ import annotations

from datetime import datetime, timezone

import pytest

from bridges.j2735.signal_request import AccessPoint, Requestor, RequestorType, SignalRequest, Srm, Ssm
from bridges.security import PSID_SPAT_MAP, PSID_SRM, PSID_SSM, ScenarioCA, Signer, Verifier, time64_us
from bridges.security import oer
from bridges.security.oer import PROTOCOL_VERSION
from rsu_app.envelope import Envelope
from rsu_app.priority import IngressLane, PriorityCore
from rsu_app.priority_stage import PriorityStage
from rsu_app.timing import LatencyModel

EPOCH = datetime(2026, 3, 1, tzinfo=timezone.utc).timestamp()
# the case-study MAP: approach 1 south arm (northbound, group 2), 2 west arm (eastbound, group 8), 3 north (6), 4 east (4)
LANES = {11: IngressLane(11, 1, 2), 21: IngressLane(21, 2, 8), 31: IngressLane(31, 3, 6), 41: IngressLane(41, 4, 4)}
IX = 1201


def srm(lane=21, *, vehicle=0xE1, role="emergency", kind="priorityRequest", intersection=IX, request_id=1, seq=1,
        point="lane"):
    return Srm(Requestor(vehicle_id=vehicle, type=RequestorType(role)),
               [SignalRequest(intersection_id=intersection, request_id=request_id, inbound=AccessPoint(point, lane),
                              request_type=kind, eta_minute=1000, eta_second=12.0, duration=8.0)],
               second=1.0, moy=1000, sequence_number=seq)


def core():
    return PriorityCore(IX, LANES, {4, 8})


def status(c: PriorityCore) -> list[str]:
    ssm = c.ssm()
    return [] if ssm is None else [s.status for s in Ssm.decode(ssm.encode()).status[0].requests]


def test_an_emergency_request_is_requested_processing_granted_and_released_when_cancelled():
    c = core()
    c.on_srm(srm(), 1.0)
    ev = c.step(1.0)
    assert ev.preempt is True and status(c) == ["requested"]
    c.on_preempt_sent(True, 1.1)
    assert status(c) == ["processing"]
    c.on_controller(greens=(1 << 1) | (1 << 5), preempt_active=True, t=3.0)   # 2 + 6 still green
    assert status(c) == ["processing"]
    c.on_controller(greens=(1 << 3) | (1 << 7), preempt_active=True, t=8.0)   # 4 + 8: the ev's group
    assert status(c) == ["granted"] and c.requests[(0xE1, 1)].t_granted == 8.0
    c.on_srm(srm(seq=2), 9.0)
    assert c.step(9.0).preempt is None          # a renewal changes nothing
    c.on_srm(srm(kind="priorityCancellation", seq=3), 10.0)
    assert c.step(10.0).preempt is False and status(c) == [] and c.cancellations == 1


def test_a_request_not_renewed_expires_and_releases_the_call():
    c = core()
    c.on_srm(srm(), 1.0)
    assert c.step(1.0).preempt is True
    assert c.step(1.0 + c.expire_s - 0.01).preempt is None
    assert c.step(1.0 + c.expire_s + 0.01).preempt is False and c.expired == 1


@pytest.mark.parametrize("kwargs, reason", [
    (dict(lane=99), "unknown-lane"),
    (dict(lane=9, point="approach"), "unknown-lane"),
    (dict(role="basicVehicle"), "not-emergency"),
    (dict(lane=11), "not-served"),             # group 2: the preemption dwells on 4 + 8
])
def test_a_request_that_cannot_be_served_is_answered_rejected(kwargs, reason):
    c = core()
    c.on_srm(srm(**kwargs), 1.0)
    assert c.step(1.0).preempt is None and status(c) == ["rejected"]
    assert c.answered_rejected == {reason: 1} and not c.call


def test_an_unknown_intersection_is_not_answered_but_counted():
    c = core()
    c.on_srm(srm(intersection=77), 1.0)
    assert status(c) == [] and c.rejections == {"unknown-intersection": 1}


def test_a_second_vehicle_on_another_approach_is_rejected_while_the_first_is_active():
    c = core()
    c.on_srm(srm(lane=21, vehicle=1), 1.0)
    c.on_srm(srm(lane=41, vehicle=2), 1.5)
    c.on_srm(srm(lane=21, vehicle=3), 1.6)
    assert status(c) == ["requested", "rejected", "rejected"]
    assert c.answered_rejected == {"other-approach-active": 1, "approach-busy": 1}
    # once the first is cancelled, the second vehicle's next SRM is accepted
    c.on_srm(srm(lane=21, vehicle=1, kind="priorityCancellation"), 2.0)
    c.on_srm(srm(lane=41, vehicle=2, seq=2), 2.1)
    assert (2, 1) in c.requests and c.requests[(2, 1)].status == "requested"


# -- the stage: 1609.2 checks and the PSID ---------------------------------------------------------------------
@pytest.fixture(scope="module")
def pki():
    start = datetime(2026, 1, 1, tzinfo=timezone.utc)
    ca = ScenarioCA.create(start=start)
    return ca, ca.issue("ev", [PSID_SRM], start, 24 * 365), ca.issue("rsu", [PSID_SPAT_MAP, PSID_SSM, PSID_SRM], start,
                                                                   24 * 365)


def stage(pki):
    ca, _, rsu = pki
    latency = LatencyModel("lockstep", "fixed", {})
    return PriorityStage(core(), Verifier([ca.certificate]), "rsu", EPOCH, Envelope(Signer(rsu)), latency)


def signed(credentials, message: Srm, t: float, psid=PSID_SRM) -> bytes:
    return Signer(credentials).sign(message.encode(), psid, time64_us(EPOCH + t))


def test_a_signed_srm_is_accepted_and_the_ssm_is_signed_under_the_ssm_psid(pki):
    s = stage(pki)
    assert s.receive(signed(pki[1], srm(), 1.0), 1.0) is not None
    s.core.step(1.0)
    tx = s.send(1.0)
    v = Verifier([pki[0].certificate]).verify(tx.payload, time64_us(EPOCH + 1.0))
    assert v.psid == PSID_SSM and Ssm.decode(v.payload).status[0].requests[0].status == "requested"


def test_bad_frames_are_counted_by_reason_never_raised(pki):
    ca, ev, rsu = pki
    s = stage(pki)
    unsigned = oer.encode("Ieee1609Dot2Data", {"protocolVersion": PROTOCOL_VERSION,
                                               "content": ("unsecuredData", srm().encode())})
    other_ca = ScenarioCA.create(start=datetime(2026, 1, 1, tzinfo=timezone.utc))
    rogue = other_ca.issue("ev", [PSID_SRM], datetime(2026, 1, 1, tzinfo=timezone.utc), 24 * 365)
    assert s.receive(unsigned, 1.0) is None
    assert s.receive(signed(rsu, srm(), 1.0, psid=PSID_SPAT_MAP), 1.0) is None   # an SRM under the SPaT PSID
    assert s.receive(signed(rogue, srm(), 1.0), 1.0) is None                    # untrusted CA
    assert s.receive(b"\x03\x81\x00garbage", 1.0) is None
    assert s.receive(signed(rsu, srm(), 1.0, psid=PSID_SSM), 1.0) is None       # an SRM under the SSM PSID
    assert s.srms == 0 and s.core.step(1.0).preempt is None and s.send(1.0) is None
    r = s.core.rejections
    assert dict(r) == {"unsecured-not-allowed": 1, "psid-mismatch": 2, "untrusted-signer": 1, "malformed": 1}
    assert sum(r.values()) == 5
    good = signed(ev, srm(), 1.0)
    assert s.receive(good, 1.0) is not None and s.receive(good, 1.01) is None   # a replay is refused
    assert r["replayed"] == 1 and s.srms == 1


# -- inside the RSU's discrete-event core: SRM -> call -> ack -> controller status -> SSM ----------------------
def test_the_rsu_core_turns_an_srm_into_a_preemption_call_and_ssms_that_follow_the_controller(pki):
    from bridges import ab3418
    from rsu_app.controller_link import PreemptAck
    from rsu_app.core import RsuCore
    from rsu_app.spat_stage import SpatStage

    ca, ev, rsu = pki
    latency = LatencyModel("lockstep", "fixed", {})
    envelope = Envelope(Signer(rsu, 0.0))   # the full certificate in every frame: each check below stands alone
    spat = SpatStage("rsu", EPOCH, envelope, latency, intersection_id=IX, signal_groups=[2, 4, 6, 8], baud=9600,
                     max_age_s=0.5)
    prio = PriorityStage(core(), Verifier([ca.certificate]), "rsu", EPOCH, envelope, latency)
    rsu_core = RsuCore(latency, spat=spat, priority=prio, spat_rate_hz=10.0, ssm_rate_hz=10.0)
    verifier = Verifier([ca.certificate])

    def ssm_states(txs, t):
        return [Ssm.decode(verifier.verify(x.payload, time64_us(EPOCH + t)).payload).status[0].requests[0].status
                for x in txs if x.kind == "ssm"]

    assert ssm_states(rsu_core.step(0.0), 0.0) == []
    rsu_core.step(0.5, srms=[(signed(ev, srm(), 0.45), 0.45)])
    assert rsu_core.take_preempt_calls() == [(0.45, True)]
    assert ssm_states(rsu_core.step(0.6), 0.6) == ["requested"]
    ack = PreemptAck(True, 9, 8, True, 0.0)
    rsu_core.step(0.65, acks=[ack])
    assert ssm_states(rsu_core.step(0.7), 0.7) == ["processing"]
    for seq, t in ((2, 2.0), (3, 4.0)):   # renewals keep the request (and the call) standing
        rsu_core.step(t, srms=[(signed(ev, srm(kind="priorityRequestUpdate", seq=seq), t), t)])
    assert rsu_core.take_preempt_calls() == []
    green_8 = ab3418.ShortStatus(greens=(1 << 3) | (1 << 7), status=ab3418.STATUS_PREEMPT, pattern=1)
    rsu_core.step(5.0, statuses=[(green_8, 10)])
    assert ssm_states(rsu_core.step(5.1), 5.1) == ["granted"]
    kinds = [(r["kind"], r.get("status")) for r in rsu_core.take_priority_records()]
    assert kinds[:2] == [("srm", None), ("preempt_call", None)]
    assert ("preempt_ack", None) in kinds and ("status", "granted") in kinds
    # no renewal: the request expires and the call is released
    rsu_core.step(4.0 + prio.core.expire_s + 0.2)
    assert rsu_core.take_preempt_calls() == [(pytest.approx(4.0 + prio.core.expire_s + 0.1), False)]
