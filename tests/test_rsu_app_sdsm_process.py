"""The RSU app as a real process sending SDSMs (issue 40): `v2i run` of the case-study world, one RSU app with
`[v2x] messages = surrogate_bsm, sdsm` and a certificate for PSID 0x90, a probe recording what it transmits.

Every SDSM must verify with the scenario CA under 0x90, come at 10 Hz, and place its objects where the run's
ground truth (timeseries.csv) has the vehicles at each object's measurement time; each slot's SDSM carries
as many objects as that slot's BSMs.
"""
from __future__ import annotations

import math
import uuid
from collections import defaultdict

import numpy as np
import pytest

from bridges.j2735 import Sdsm, default_codec
from bridges.security import PSID_SURROGATE_BSM, Verifier, load_certificate, time64_us

from test_rsu_app_process import case_study_scenario
from test_rsu_app_support import ROOT, Truth, app_summary, free_port, make_pki, rsu_table, run_with_probe

PSID_SDSM = 0x90


@pytest.fixture(scope="module")
def sdsm_run(tmp_path_factory, fmu_dir):
    folder = tmp_path_factory.mktemp("rsu-sdsm")
    keys = make_pki(folder / "keys", {"rsu": "0x7f,0x82,0x90"})
    prefix, port = f"test/rsu-sdsm-{uuid.uuid4().hex[:8]}", free_port()
    config = str(ROOT / "scenarios" / "apps" / "rsu.toml")
    tables = rsu_table("rsu", "--config", config, "--pki-dir", "keys", "--set", "v2x.messages=surrogate_bsm,sdsm",
                       "--set", f"v2x.sdsm_psid={PSID_SDSM}")
    result, probe, out = run_with_probe(case_study_scenario(prefix, port, tables), folder, prefix, port)
    assert result.returncode == 0, result.stdout + result.stderr
    assert probe.error is None, probe.error
    ca = load_certificate(keys / "v2i-scenario-ca.cert")
    return {"probe": probe, "verifier": lambda: Verifier([ca]), "truth": Truth(out, folder / "run.toml"),
            "summary": app_summary(out, "rsu")}


def test_sdsms_verify_under_their_psid_at_ten_hertz_beside_the_bsms(sdsm_run):
    probe, verifier = sdsm_run["probe"], sdsm_run["verifier"]()  # a fresh receiver: no replay memory
    epoch = probe.world["epoch_unix_s"]
    sdsms, pending, checked = [], 0, 0
    for s in sorted(probe.sent, key=lambda s: s.t_sim):
        verified = verifier.verify(s.payload, time64_us(epoch + s.t_sim))
        message_id = default_codec().decode(verified.payload).message_id
        if message_id == 20:
            assert verified.psid == PSID_SURROGATE_BSM
            pending += 1
        elif message_id == 41:
            assert verified.psid == PSID_SDSM
            sdsm = Sdsm.decode(verified.payload)
            sdsms.append((s.t_sim, sdsm))
            assert len(sdsm.objects) == pending  # the slot's BSMs, then its SDSM with the same tracks
            pending, checked = 0, checked + 1
    assert checked > 40
    slots = np.array([sdsm.timestamp.to_unix() - epoch for _, sdsm in sdsms])
    rate = (len(slots) - 1) / (slots[-1] - slots[0])
    assert 9.0 <= rate <= 11.0
    summary = sdsm_run["summary"]["sdsm"]
    assert summary["sent"] == len(sdsms) and summary["psid"] == PSID_SDSM and summary["objects_dropped"] == 0


def test_sdsm_objects_are_where_the_vehicles_were_when_seen(sdsm_run):
    probe, verifier, truth = sdsm_run["probe"], sdsm_run["verifier"](), sdsm_run["truth"]
    epoch = probe.world["epoch_unix_s"]
    errors, ids = defaultdict(list), defaultdict(set)
    for s in sorted(probe.sent, key=lambda s: s.t_sim):
        payload = verifier.verify(s.payload, time64_us(epoch + s.t_sim)).payload
        if default_codec().decode(payload).message_id != 41:
            continue
        sdsm = Sdsm.decode(payload)
        for o in sdsm.objects:
            t_seen = sdsm.timestamp.to_unix() - epoch + o.measurement_time
            assert -0.5 <= o.measurement_time <= 0.0
            vehicle, err = truth.nearest(o.offset_x, o.offset_y, t_seen)
            errors[vehicle].append(err)
            ids[vehicle].add(o.object_id)
            assert o.object_type == "vehicle"
            if o.type_confidence == 0:  # no camera box yet: a track the mast radar started (it names no class),
                tx, ty = truth.at(vehicle, t_seen)[:2]  # the ev far out on the west arm
                assert vehicle == "ev" and math.hypot(tx - 6.5, ty - 6.5) > 50.0, (vehicle, tx, ty)
            else:
                assert 40 <= o.type_confidence <= 100
    assert set(errors) == {"cav", "ev"}
    medians = {v: float(np.median(e)) for v, e in errors.items()}
    print(f"SDSM objects: median position error at their measurement time {medians}, ids {dict(ids)}")
    # measured: cav 0.168 m, ev 0.395 m (medians). The surrogate BSMs of the same tracks are held to 0.27 and
    # 0.65 m (test_rsu_app_process.py, measured 0.170 and 0.552): an SDSM object is the track at its frame's
    # time, not predicted to the slot, so the ev's fast motion adds less error
    assert medians["cav"] <= 0.27 and medians["ev"] <= 0.5, medians
