"""The case study under attack, as a user runs it: `v2i run scenarios/ima_attack.toml`, the attacker started by the
master (python -m attacker) beside the RSU and AV apps, all in lockstep on zenoh (loopback).

Two runs (about a minute each): the shipped case study and the same under attack, from copies of the shipped
files in a temporary folder with free ports (the first run makes the keys, the attacker its stolen certificate).
Under attack there is no collision and no needless stop: the cav brakes when and as hard as it does without the
attacker. Every frame the attacker got through to the cav was refused, each class with its reason (joined
frame by frame: the attacker's frame log gives each sequence number's attack, the air's events each delivery),
the refusals are in metrics.json (`v2x_rejected`), and the RSU's frames still reached the cav and were accepted.
"""
from __future__ import annotations

import json
import shutil
from collections import Counter
from pathlib import Path

import pytest

from test_case_study import run_case
from test_rsu_app_support import run_pairwise

ROOT = Path(__file__).resolve().parent.parent
pytest.importorskip("zenoh")
pytest.importorskip("pybullet")

FIRST_BRAKE_MARGIN_S = 0.1  # the attacked cav's first brake vs. the case study's
MIN_SPEED_MARGIN_MPS = 0.3  # its lowest speed vs. the case study's
RSU_PDR_MIN = 0.95  # the RSU's frames reach the cav under attack
FORMAT_REASONS = {"malformed", "trailing-bytes", "nonzero-padding", "non-canonical-encoding",
                  "non-canonical-signature"}  # what random bytes are refused as (nearly always malformed)


@pytest.fixture(scope="module")
def runs(tmp_path_factory, fmu_dir):
    study = tmp_path_factory.mktemp("attack-study") / "scenarios"
    (study / "apps").mkdir(parents=True)
    for name in ("ima_world.toml", "ima_case_study.toml", "ima_attack.toml"):
        shutil.copy(ROOT / "scenarios" / name, study / name)
    for name in ("rsu.toml", "av.toml", "attacker.toml"):
        shutil.copy(ROOT / "scenarios" / "apps" / name, study / "apps" / name)
    out = tmp_path_factory.mktemp("attack-runs")
    jobs = {"plain": ("ima_case_study.toml", "fixed", out / "plain"),
            "attack": ("ima_attack.toml", "fixed", out / "attack")}
    return run_pairwise(lambda job: run_case(study, *job), jobs)


def last_json(path: Path) -> dict:
    return json.loads(path.read_text().strip().splitlines()[-1])


def series(run, column: str) -> list[float]:
    lines = run["series"].decode().splitlines()
    i = lines[0].split(",").index(column)
    return [float(line.split(",")[i]) for line in lines[1:]]


def delivered_to_cav_by_attack(run_dir: Path) -> Counter:
    """The attacker's frames the air delivered to the cav, per attack (frame log seq -> attack)."""
    attack_of = {}
    for line in (run_dir / "attacker-frames.jsonl").read_text().splitlines():
        item = json.loads(line)
        attack_of[item["seq"]] = item["attack"]
    out: Counter = Counter()
    for line in (run_dir / "events.jsonl").read_text().splitlines():
        e = json.loads(line)
        if e.get("event") == "v2x_delivered" and e["from"] == "attacker" and e["to"] == "cav":
            out[attack_of[e["seq"]]] += 1
    return out


def test_under_attack_there_is_no_collision_and_no_needless_stop(runs):
    plain, attack = runs["plain"], runs["attack"]
    m = attack["metrics"]
    assert attack["meta"]["status"] == "completed" and m["collision"] is False and m["min_gap_m"] > 0.5
    assert "collision: false" in attack["stdout"]
    av_plain = last_json(plain["dir"] / "participant-cav.log")
    av_attack = last_json(attack["dir"] / "participant-cav.log")
    brake_plain, brake_attack = av_plain["first_s"]["first_brake"], av_attack["first_s"]["first_brake"]
    assert abs(brake_attack - brake_plain) <= FIRST_BRAKE_MARGIN_S, (brake_plain, brake_attack)
    v_plain, v_attack = min(series(plain, "cav.v")), min(series(attack, "cav.v"))
    assert abs(v_attack - v_plain) <= MIN_SPEED_MARGIN_MPS, (v_plain, v_attack)
    # what made it brake was the real emergency vehicle, as without the attacker
    assert av_attack["decisions"].keys() == av_plain["decisions"].keys()


def test_every_attack_class_reached_the_cav_and_each_frame_was_refused_with_its_reason(runs):
    run = runs["attack"]
    attacker = last_json(run["dir"] / "participant-attacker.log")
    assert attacker["exit"] == "the run ended (completed)" and attacker["publish_errors"] == 0
    sent = attacker["sent"]
    assert set(sent) == {"ghost-unsigned", "ghost-untrusted", "ghost-expired", "replay", "replay-short", "flood"}
    assert sent["ghost-unsigned"] == sent["ghost-untrusted"] == sent["ghost-expired"] == 90  # 10 Hz, 1 s to 10 s
    assert sent["flood"] == 500 and sent["replay"] > 100 and sent["replay-short"] > 100
    got = delivered_to_cav_by_attack(run["dir"])
    assert sum(got.values()) == run["metrics"]["pdr"]["attacker->cav"]["delivered"]
    assert all(got[a] > 0 for a in sent), got
    rejected = run["metrics"]["v2x_rejected"]["cav"]
    assert rejected["unsecured-not-allowed"] == got["ghost-unsigned"]
    assert rejected["untrusted-signer"] == got["ghost-untrusted"] + got["ghost-expired"]  # own CA; expired
    assert rejected["outside-time-window"] == got["replay"]  # 1 s later: older than the 0.5 s window
    assert rejected["replayed"] == got["replay-short"]  # 0.2 s later: a duplicate of an accepted frame
    flood = {r: n for r, n in rejected.items()
             if r not in ("unsecured-not-allowed", "untrusted-signer", "outside-time-window", "replayed")}
    assert set(flood) <= FORMAT_REASONS and sum(flood.values()) == got["flood"], flood
    # nothing else was refused, and nothing of the attacker's was accepted
    av = last_json(run["dir"] / "participant-cav.log")
    assert sum(rejected.values()) == sum(got.values()) == sum(av["obu"]["rejected"].values())
    assert av["obu"]["received"] == sum(av["obu"]["accepted"].values()) + sum(rejected.values())


def test_the_rsus_genuine_frames_still_got_through_and_were_accepted(runs):
    plain, attack = runs["plain"], runs["attack"]
    link = attack["metrics"]["pdr"]["rsu->cav"]
    assert link["pdr"] >= RSU_PDR_MIN
    assert link["delivered"] >= RSU_PDR_MIN * plain["metrics"]["pdr"]["rsu->cav"]["delivered"]
    av = last_json(attack["dir"] / "participant-cav.log")
    assert sum(av["obu"]["accepted"].values()) == link["delivered"]  # every RSU frame that arrived, and only those
    assert attack["metrics"]["latency_ms"]["e2e"]["n"] >= RSU_PDR_MIN * plain["metrics"]["latency_ms"]["e2e"]["n"]
    assert plain["metrics"]["v2x_rejected"] == {"cav": {}}  # without the attacker the cav refuses nothing
