"""The attacker's pieces in-process: each attack's frames go through the AV app's own receive path (av_app.obu,
the scenario CA as trust anchor, signatures required) and are refused with the reason each class must get; the
same ghost frames genuinely signed are accepted and make the AV's planner brake (the positive control: only the
envelope keeps the ghost out). Also the schedule, the flood's bounds, the stolen certificate's provisioning, the
configuration's errors, the CLI, and metrics.json's `v2x_rejected` from a run folder's participant logs.
"""
from __future__ import annotations

import json
import math
import subprocess
import sys
import time
from datetime import datetime, timedelta, timezone
from pathlib import Path

import pytest

from bridges.geo import GeoOrigin
from bridges.security import (PSID_SPAT_MAP, PSID_SURROGATE_BSM, ScenarioCA, Signer, Verifier, load_credentials,
                              time64_us)
from bridges.sensor_stream import GnssFix
from bridges.v2x import unix_time
from av_app.config import load as load_av_config
from av_app.core import AvCore
from av_app.obu import Obu, Rejected
from av_app.timing import StageClock

from attacker.attacks import (ATTACKS, MAX_FLOOD_FRAMES, MAX_FLOOD_RATE_HZ, Context, Flood, FloodParams, GhostParams,
                              Replay, ReplayParams, slots)
from attacker.config import ConfigError, build, parse_attack_flag
from attacker.core import AttackerCore
from attacker.ghost import GhostPath, ghost_bsm
from attacker.credentials import (CredentialError, EXPIRED_AGO_DAYS, rogue_station, signed_by, stolen_expired,
                                  unsigned)

ROOT = Path(__file__).resolve().parent.parent
ORIGIN = GeoOrigin()
EPOCH = time.time()  # the certificates below are valid from an hour before now
GHOST_PATH = [[-50.0, -1.75], [120.0, -1.75]]


@pytest.fixture(scope="module")
def pki(tmp_path_factory):
    """A scenario CA (valid from an hour ago) with the RSU's station, as `[pki]` leaves it; the stolen,
    expired certificate issued from it by the attacker's provisioning."""
    d = tmp_path_factory.mktemp("attacker-pki")
    start = datetime.now(timezone.utc) - timedelta(hours=1)
    ca = ScenarioCA.create(start=start)
    ca.credentials.save(d)
    rsu = ca.issue("rsu", [PSID_SURROGATE_BSM, PSID_SPAT_MAP], start=start)
    rsu.save(d)
    stolen = stolen_expired(d / "stolen", d)
    return {"dir": d, "ca": ca, "rsu": rsu, "stolen": stolen}


def context(pki, genuine: bool = False) -> Context:
    """The attacks' context; `genuine`: every envelope signs with the RSU's real credentials (positive control)."""
    if genuine:
        real = signed_by(pki["rsu"])
        return Context(ORIGIN, EPOCH, 1, {"unsigned": real, "untrusted": real, "expired": real})
    return Context(ORIGIN, EPOCH, 1, {"unsigned": unsigned, "untrusted": signed_by(rogue_station()),
                                      "expired": signed_by(pki["stolen"].credentials)})


def av_obu(pki) -> Obu:
    """The AV app's OBU as the case study configures it: the scenario CA, signatures required, 0.5 s window."""
    cfg = load_av_config(ROOT / "scenarios" / "apps" / "av.toml",
                         {"security": {"trust_anchor": str(pki["dir"] / "v2i-scenario-ca.cert")}})
    assert cfg.security.allow_unsecured is False and cfg.security.max_age_s == 0.5
    return Obu(cfg.obu, ORIGIN, EPOCH, Verifier([pki["ca"].certificate], max_age_s=cfg.security.max_age_s,
                                                max_future_s=cfg.security.max_future_s))


def ghost(kind: str, ctx: Context, **params):
    p = GhostParams(start_s=1.0, stop_s=6.0, path=GHOST_PATH, **params)
    return ATTACKS[kind](kind, p, ctx)


# -- each attack class through the AV's receive path ----------------------------------------------------------------
@pytest.mark.parametrize("kind, reason, detail", [
    ("ghost-unsigned", "unsecured-not-allowed", "policy requires signatures"),
    ("ghost-untrusted", "untrusted-signer", "not issued by a trusted CA"),
    ("ghost-expired", "untrusted-signer", "'rsu' is not valid at this time"),  # the verifier's expiry refusal
])
def test_every_ghost_frame_is_refused_by_the_av_receive_path_with_its_reason(pki, kind, reason, detail):
    obu = av_obu(pki)
    frames = ghost(kind, context(pki)).frames(0.0, 3.0)
    assert [f.t for f in frames] == pytest.approx([1.0 + 0.1 * n for n in range(20)])
    for f in frames:
        with pytest.raises(Rejected) as exc:
            obu.receive(f.payload, f.t + 0.002)  # 2 ms on the air
        assert exc.value.reason == reason and detail in exc.value.detail, exc.value
    assert obu.rejected == {reason: 20} and not obu.accepted


def test_the_same_ghost_frames_genuinely_signed_are_accepted_where_the_path_puts_the_ghost(pki):
    """Only the envelope differs: signed by the RSU, the ghost's BSMs verify and decode to an emergency vehicle
    on its path, heading east at its speed, one temporary id per attack."""
    obu = av_obu(pki)
    for kind in ("ghost-unsigned", "ghost-untrusted", "ghost-expired"):
        g = ghost(kind, context(pki, genuine=True))
        for f in g.frames(2.0, 2.25):
            acc = obu.receive(f.payload, f.t + 0.002)
            o = acc.object
            x = -50.0 + 16.667 * (f.t - 1.0)
            assert acc.station == "rsu" and o.emergency and o.surrogate
            assert (o.x, o.y) == pytest.approx((x, -1.75), abs=0.05) and o.yaw == pytest.approx(0.0, abs=1e-3)
            assert o.speed == pytest.approx(16.667, abs=0.02) and o.t == pytest.approx(f.t, abs=1e-3)
            assert o.id == f"v2x:{g.tid.hex()}"
    assert obu.accepted["bsm"] == 9 and not obu.rejected
    assert len({ghost(k, context(pki)).tid for k in ("ghost-unsigned", "ghost-untrusted", "ghost-expired")}) == 3


def drive(pki, ctx: Context, until: float = 4.0) -> AvCore:
    """The AV core of the case study (lidar off) driving north toward the junction at 30 km/h from y = -45,
    its speed following its own commands, fed every ghost frame 2 ms after it is sent."""
    cfg = load_av_config(ROOT / "scenarios" / "apps" / "av.toml",
                         {"security": {"trust_anchor": str(pki["dir"] / "v2i-scenario-ca.cert")},
                          "perception": {"enabled": False}})
    obu = Obu(cfg.obu, ORIGIN, EPOCH, Verifier([pki["ca"].certificate], max_age_s=0.5))
    core = AvCore(cfg, obu, StageClock("fixed", None, cfg.latency), {"intersection": {"road_width": 7.0}})
    attacker = AttackerCore([ghost(k, ctx) for k in ("ghost-unsigned", "ghost-untrusted", "ghost-expired")])
    y, v, dt = -45.0, 8.333, 0.02
    inbox = []
    for k in range(int(until / dt)):
        t = round(k * dt, 6)
        inbox.extend(attacker.step(t, t + dt))
        if k % 5 == 0:
            core.on_gnss(GnssFix(t, 1.75, y, 0.0, math.pi / 2, v))
        core.on_status(t, v, 0.0)
        for f in [f for f in inbox if f.t + 0.002 <= t]:
            core.on_v2x(f.payload, f.t + 0.002)
        inbox = [f for f in inbox if f.t + 0.002 > t]
        accel = []
        core.command(t, lambda a, s, m: accel.append(a) or k)
        v = max(0.0, v + accel[0] * dt)
        y += v * dt
    return core


def test_believed_the_ghost_would_stop_the_cav_refused_it_changes_nothing(pki):
    """Positive control for the attack run: the ghost ambulance of scenarios/apps/attacker.toml, had its frames
    verified, makes the AV brake for it within 3 s, with no real vehicle anywhere."""
    believed = drive(pki, context(pki, genuine=True))
    assert believed.health.first["first_brake"] < 3.0
    assert {"yield", "slow", "brake_hard"} & set(believed.health.decisions)
    refused = drive(pki, context(pki))
    assert set(refused.health.decisions) == {"cruise"} and "first_brake" not in refused.health.first
    assert refused.obu.rejected == {"unsecured-not-allowed": 30, "untrusted-signer": 60} and not refused.obu.accepted


# -- replay ------------------------------------------------------------------------------------------------------------
def genuine_frames(pki, times):
    """Signed surrogate BSMs of a real vehicle as the RSU sends them."""
    signer = Signer(pki["rsu"], 0.0)
    path = GhostPath(GHOST_PATH, 16.667, 0.0)  # any vehicle will do: one on the same lane
    return [signer.sign(ghost_bsm(path.pose(t), t, EPOCH, ORIGIN, b"real", n, 4.5, 1.8, False), PSID_SURROGATE_BSM,
                        time64_us(unix_time(t, EPOCH))) for n, t in enumerate(times)]


@pytest.mark.parametrize("delay_s, reason", [(0.2, "replayed"), (1.0, "outside-time-window")])
def test_a_replay_heard_and_sent_again_later_is_refused_as_a_duplicate_or_as_too_old(pki, delay_s, reason):
    """Ticks of 10 ms: the RSU's frames reach the AV and the attacker 2 ms after they are sent, the replays
    reach the AV 2 ms after the attacker sends them; the AV takes everything in arrival order."""
    obu = av_obu(pki)
    replay = Replay("replay", ReplayParams(delay_s=delay_s), Context(ORIGIN, EPOCH))
    times = [round(0.5 + 0.1 * n, 3) for n in range(10)]
    originals = list(zip([t + 0.002 for t in times], genuine_frames(pki, times)))
    in_flight, replayed_at, reasons = [], [], []
    for k in range(300):  # 3 s
        t0, t1 = k * 0.01, (k + 1) * 0.01
        for arrival, frame in originals:
            if t0 <= arrival < t1:
                in_flight.append((arrival, "original", frame))
                replay.hear(frame, arrival)
        for f in replay.frames(t0, t1):
            replayed_at.append(f.t)
            in_flight.append((f.t + 0.002, "replay", f.payload))
        for arrival, what, frame in sorted(i for i in in_flight if i[0] < t1):
            if what == "original":
                assert obu.receive(frame, arrival).kind == "bsm"
            else:
                with pytest.raises(Rejected) as exc:
                    obu.receive(frame, arrival)
                reasons.append(exc.value.reason)
        in_flight = [i for i in in_flight if i[0] >= t1]
    assert replayed_at == pytest.approx([t + 0.002 + delay_s for t in times])
    assert reasons == [reason] * 10 and obu.rejected == {reason: 10} and obu.accepted == {"bsm": 10}
    assert replay.summary() == {"attack": "replay", "kind": "replay", "sent": 10, "captured": 10, "late": 0,
                                "ignored": 0, "pending_at_end": 0}


def test_a_replay_keeps_to_its_window_and_its_cap_and_sends_a_late_capture_at_once():
    replay = Replay("r", ReplayParams(start_s=1.0, stop_s=3.0, delay_s=0.5, max_frames=3), Context(ORIGIN, EPOCH))
    for t in (0.9, 1.0, 1.2, 2.6, 1.5, 1.6):  # before start; in; in; its replay would fall after stop; in; over cap
        replay.hear(b"x%.1f" % t, t)
    assert (replay.captured, replay.ignored) == (3, 3)
    assert [f.payload for f in replay.frames(0.0, 1.8)] == [b"x1.0", b"x1.2"]
    late = replay.frames(2.5, 2.6)  # 1.5 + 0.5 = 2.0 is past: sent at 2.5, counted late
    assert [(f.t, f.payload) for f in late] == [(2.5, b"x1.5")] and replay.late == 1


# -- flood and the schedule --------------------------------------------------------------------------------------------
def test_fixed_rate_frames_fall_on_their_slots_whatever_the_tick():
    one_window = slots(0.3, 2.0, 10.0, 0.0, 5.0)
    ticked = [s for k in range(500) for s in slots(0.3, 2.0, 10.0, k * 0.01, (k + 1) * 0.01)]
    assert ticked == one_window and [n for n, _ in one_window] == list(range(17))
    assert one_window[-1][1] == pytest.approx(1.9)  # none at or after stop_s
    coarse = [s for k in range(50) for s in slots(0.3, 2.0, 10.0, k * 0.1, (k + 1) * 0.1)]
    assert coarse == one_window


def test_the_flood_is_bounded_by_rate_and_count_repeats_its_bytes_and_is_refused_as_malformed(pki):
    ctx = Context(ORIGIN, EPOCH, seed=3)
    flood = Flood("flood", FloodParams(start_s=1.0, rate_hz=MAX_FLOOD_RATE_HZ, max_frames=1500, bytes=120), ctx)
    frames = [f for k in range(300) for f in flood.frames(k * 0.01, (k + 1) * 0.01)]
    assert len(frames) == 1500 == flood.sent  # 2000/s from 1.0 s would be 4000 by 3 s: the cap holds
    assert frames[0].t == 1.0 and frames[1].t == pytest.approx(1.0005) and frames[-1].t == pytest.approx(1.7495)
    assert {len(f.payload) for f in frames} == {120}
    again = Flood("flood", FloodParams(start_s=1.0, rate_hz=MAX_FLOOD_RATE_HZ, max_frames=1500, bytes=120), ctx)
    assert [f.payload for f in again.frames(0.0, 3.0)] == [f.payload for f in frames]
    other = Flood("flood", FloodParams(start_s=1.0, max_frames=10, bytes=120), Context(ORIGIN, EPOCH, seed=4))
    assert other.frames(0.0, 3.0)[0].payload != frames[0].payload
    obu = av_obu(pki)
    for f in frames[:300]:
        with pytest.raises(Rejected):
            obu.receive(f.payload, f.t + 0.002)
    assert obu.rejected == {"malformed": 300} and not obu.accepted


def test_the_core_merges_attacks_in_time_order_and_counts_per_attack(pki):
    ctx = context(pki)
    core = AttackerCore.build([("g", "ghost-unsigned", GhostParams(start_s=0.05, rate_hz=10.0, path=GHOST_PATH)),
                               ("f", "flood", FloodParams(rate_hz=40.0, max_frames=100, bytes=10))], ctx)
    out = core.step(0.0, 0.3)
    assert [(f.attack, round(f.t, 3)) for f in out] == [
        ("f", 0.0), ("f", 0.025), ("g", 0.05), ("f", 0.05), ("f", 0.075), ("f", 0.1), ("f", 0.125), ("g", 0.15),
        ("f", 0.15), ("f", 0.175), ("f", 0.2), ("f", 0.225), ("g", 0.25), ("f", 0.25), ("f", 0.275)]
    assert core.sent == {"f": 12, "g": 3}


# -- the stolen certificate ----------------------------------------------------------------------------------------
def test_the_stolen_certificate_is_genuine_expired_made_once_and_remade_for_a_new_ca(pki, tmp_path):
    cert = pki["stolen"].credentials.certificate
    start_us, end_us = cert.validity_us()
    now_us = time64_us(time.time())
    assert cert.issuer_digest == pki["ca"].certificate.digest and cert.signed_by(pki["ca"].certificate)
    assert end_us < now_us - 20 * 86400 * 10**6 and start_us < now_us - (EXPIRED_AGO_DAYS - 1) * 86400 * 10**6
    assert pki["stolen"].made and cert.psids == {PSID_SURROGATE_BSM} and cert.name == "rsu"
    kept = stolen_expired(pki["dir"] / "stolen", pki["dir"])
    assert not kept.made and kept.credentials.certificate.encoded == cert.encoded
    # the scenario's keys made anew (a fresh checkout, another CA): the old theft is of no use, issue again
    fresh = tmp_path / "keys"
    ScenarioCA.create().credentials.save(fresh)
    (fresh / "stolen").mkdir()
    for suffix in (".cert", ".key"):
        (fresh / "stolen" / f"rsu{suffix}").write_bytes((pki["dir"] / "stolen" / f"rsu{suffix}").read_bytes())
    remade = stolen_expired(fresh / "stolen", fresh)
    assert remade.made and remade.credentials.certificate.issuer_digest != cert.issuer_digest
    assert load_credentials(fresh / "stolen", "rsu").certificate.encoded == remade.credentials.certificate.encoded
    with pytest.raises(CredentialError) as exc:  # nothing stolen and no CA to play the past with
        stolen_expired(tmp_path / "none", None)
    assert exc.value.key == "keys.stolen_dir"
    with pytest.raises(CredentialError) as exc:
        stolen_expired(tmp_path / "none", tmp_path / "no-ca")
    assert exc.value.key == "keys.pki_dir" and "v2i-scenario-ca" in exc.value.reason


# -- configuration and CLI -------------------------------------------------------------------------------------------
def test_the_shipped_attacker_config_has_every_attack_class():
    from attacker.config import read_toml

    cfg = build(read_toml(ROOT / "scenarios" / "apps" / "attacker.toml"), environ={})
    assert {a.kind for a in cfg.attacks} == set(ATTACKS)
    assert [a.label for a in cfg.attacks if a.kind == "replay"] == ["replay", "replay-short"]
    assert cfg.keys.stolen_dir.endswith("keys/stolen") and Path(cfg.keys.stolen_dir).is_absolute()


def test_every_config_problem_is_named_by_key_with_a_did_you_mean():
    with pytest.raises(ConfigError) as exc:
        build({"ap": {}, "app": {"sed": 1}, "attacks": [
            {"kind": "ghost-expird"},
            {"kind": "flood", "rate_hz": MAX_FLOOD_RATE_HZ * 2, "max_frames": MAX_FLOOD_FRAMES + 1, "byts": 3},
            {"kind": "ghost-unsigned", "path": [[0, 0]], "start_s": 5.0, "stop_s": 2.0},
            {"kind": "replay", "delay_s": 0},
            {"kind": "ghost-expired"}]}, environ={})
    problems = dict(exc.value.problems)
    assert "did you mean 'app'" in problems["ap"] and "did you mean 'seed'" in problems["app.sed"]
    assert "did you mean 'ghost-expired'" in problems["attacks[0].kind"]
    assert "at most 2000" in problems["attacks[1].rate_hz"] and "at most 100000" in problems["attacks[1].max_frames"]
    assert "did you mean 'bytes'" in problems["attacks[1].byts"]
    assert "two points" in problems["attacks[2].path"]
    assert "> 0" in problems["attacks[3].delay_s"]
    assert "stolen certificate" in problems["keys.stolen_dir"]
    with pytest.raises(ConfigError) as exc:
        build({"attacks": [{"kind": "ghost-unsigned", "start_s": 5.0, "stop_s": 2.0}]}, environ={})
    assert exc.value.problems == [("attacks[0].stop_s", "must be after start_s (5), got 2")]
    with pytest.raises(ConfigError) as exc:
        build({}, environ={})
    assert exc.value.problems[0][0] == "attacks"


def test_attacks_from_flags_are_toml_inline_tables():
    assert parse_attack_flag("flood: rate_hz = 500, max_frames = 300") == {"kind": "flood", "rate_hz": 500,
                                                                           "max_frames": 300}
    assert parse_attack_flag("ghost-unsigned: path = [[0, 0], [5, 0]]")["path"] == [[0, 0], [5, 0]]
    cfg = build({"attacks": [parse_attack_flag("flood"), parse_attack_flag("flood")]}, environ={"V2I_NAME": "eve"})
    assert [a.label for a in cfg.attacks] == ["flood", "flood#2"] and cfg.app.station == "eve"
    with pytest.raises(ConfigError) as exc:
        parse_attack_flag("flood: rate_hz = ")
    assert exc.value.problems[0][0] == "--attack"


def test_the_cli_lists_the_attacks_and_exits_2_naming_a_bad_key():
    listing = subprocess.run([sys.executable, "-m", "attacker", "--list"], capture_output=True, text=True, timeout=60)
    assert listing.returncode == 0 and all(f"{name}:" in listing.stdout for name in ATTACKS)
    bad = subprocess.run([sys.executable, "-m", "attacker", "--attack", "flood: rate_hz = 5000"], capture_output=True,
                         text=True, timeout=60)
    assert bad.returncode == 2 and bad.stdout == ""
    assert bad.stderr.strip() == "attacker: config: attacks[0].rate_hz: expected at most 2000, got 5000"


# -- metrics.json: v2x_rejected --------------------------------------------------------------------------------------
def test_metrics_count_the_refused_frames_by_reason_per_receiver(tmp_path):
    from master.run.metrics import rejected_by_receiver

    cav = {"name": "cav", "station": "cav", "obu": {"received": 9, "accepted": {"bsm": 2},
                                                    "rejected": {"untrusted-signer": 4, "malformed": 3}}}
    (tmp_path / "participant-cav.log").write_text(
        "cav: t=1.1 v2x rx=9 ok=2 rejected[malformed=3,untrusted-signer=4]\n" + json.dumps(cav) + "\n")
    quiet = {"name": "obu2", "obu": {"received": 3, "accepted": {"bsm": 3}, "rejected": {}}}
    (tmp_path / "participant-obu2.log").write_text(json.dumps(quiet) + "\n{\"torn\": \n")
    (tmp_path / "participant-rsu.log").write_text(json.dumps({"app": "rsu_app", "published": 5}) + "\n")
    (tmp_path / "participant-attacker.log").write_text("Traceback (most recent call last):\n")
    assert rejected_by_receiver(tmp_path) == {"cav": {"malformed": 3, "untrusted-signer": 4}, "obu2": {}}
