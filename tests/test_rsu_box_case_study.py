"""The case study with real-radio interfaces, through the emulated RSU box in a second network namespace.

`v2i run` on scenarios/ima_rsu_box.toml (the case study with `[v2x] mode = "rsu"`) runs in one namespace
(10.77.0.1) with its apps; `python -m bridges.rsu_box` runs in the other (10.77.0.2), joined by a veth
pair (tests/test_hil_netns.py's fixture, with 2 ms of netem delay each way where the kernel has netem).
Every surrogate BSM and MAP crosses the link as an Immediate Forward record, waits the box's delay, and
comes back as an OBU forward. Only the two addresses of the shipped scenario change, as they would for real
devices. The verdict is the simulated air's (no collision), and the air stage of the latency chain, and so
every end-to-end record, includes the box's delay. Needs root and `ip netns` (skipped otherwise, with why).
"""
from __future__ import annotations

import json
import select
import shutil
import signal
import subprocess
import sys
from pathlib import Path

import pytest

from bridges.v2x import AIR_ARRIVAL, CAN_APPLIED, FRAME, SEND
from master.run.metrics import applied_times, read_csv, read_jsonl, with_can_applied
import test_hil_netns
from test_hil_netns import BOX_IP, MASTER_IP

ROOT = Path(__file__).resolve().parent.parent
V2I = Path(sys.executable).with_name("v2i")
pytest.importorskip("zenoh")
pytest.importorskip("pybullet")

netns_pair = test_hil_netns.netns_pair  # the two namespaces and their veth pair, as the HIL test makes them
DELAY_MS = 20.0
RSU_PORT, OBU_PORT = 1516, 47900


@pytest.mark.timeout(900)
def test_case_study_through_the_emulated_box_in_another_namespace(netns_pair, tmp_path, fmu_dir):
    master_ns, box_ns, delayed = netns_pair
    study = tmp_path / "scenarios"
    (study / "apps").mkdir(parents=True)
    for name in ("ima_world.toml", "ima_case_study.toml", "ima_rsu_box.toml"):
        shutil.copy(ROOT / "scenarios" / name, study / name)
    for name in ("rsu.toml", "av.toml"):
        shutil.copy(ROOT / "scenarios" / "apps" / name, study / "apps" / name)
    variant = study / "through-netns.toml"
    variant.write_text(f"""
[scenario]
extends = "ima_rsu_box.toml"
[v2x]
rsu = "{BOX_IP}:{RSU_PORT}"
obu_listen = "{MASTER_IP}:{OBU_PORT}"
""")  # the two addresses a user changes for real devices; nothing else
    box_log, out = tmp_path / "box.jsonl", tmp_path / "run"
    box = subprocess.Popen(["ip", "netns", "exec", box_ns, sys.executable, "-m", "bridges.rsu_box",
                            "--listen", f"{BOX_IP}:{RSU_PORT}", "--forward", f"{MASTER_IP}:{OBU_PORT}",
                            "--delay-ms", str(DELAY_MS), "--seed", "1", "--log", str(box_log)],
                           stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        ready, _, _ = select.select([box.stdout], [], [], 60)
        assert ready, "the box did not start"
        assert json.loads(box.stdout.readline())["address"] == f"{BOX_IP}:{RSU_PORT}"
        run = subprocess.run(["ip", "netns", "exec", master_ns, str(V2I), "run", str(variant), "--out", str(out),
                              "--quiet", "--no-report"], capture_output=True, text=True, timeout=800)
        box.send_signal(signal.SIGTERM)
        box_out, box_err = box.communicate(timeout=20)
    finally:
        if box.poll() is None:
            box.kill()
            box.wait()
    assert run.returncode == 0, run.stdout + run.stderr
    assert box.returncode == 0, box_err
    metrics = json.loads((out / "metrics.json").read_text())
    meta = json.loads((out / "metadata.json").read_text())

    # the verdict of the simulated air: the cav yields to the ev
    assert metrics["collision"] is False, run.stdout
    assert meta["status"] == "completed"

    # every frame went out as a record, through the box, and came back
    link, summary = meta["v2x"]["rsu"], json.loads(box_out.strip().splitlines()[-1])
    assert link["rsu"] == f"{BOX_IP}:{RSU_PORT}" and link["kernel_timestamps"] is True
    assert link["records_sent"] > 100 and link["not_sent"] == 0 and link["obu_refused"] == 0, link
    assert summary["received"] == link["records_sent"] and summary["refused"] == 0, summary
    assert summary["forwarded"] == summary["received"] == link["forwards_received"]
    assert link["delivered"] == link["records_sent"] and link["lost"] == 0 and link["foreign"] == 0, link
    assert set(summary["types"]) == {"BSM", "MAP"}
    assert metrics["pdr"]["rsu->cav"] == {"pdr": 1.0, "delivered": link["delivered"], "dropped": 0}

    # the air stage is the box's delay (and the veth's), and every end-to-end record carries it
    floor_ms = DELAY_MS + (4.0 if delayed else 0.0)  # netem: 2 ms out to the box, 2 ms back
    assert link["wall_delay_ms"]["min"] >= floor_ms, link["wall_delay_ms"]
    assert metrics["latency_ms"]["air"]["n"] > 100
    assert floor_ms <= metrics["latency_ms"]["air"]["p50"] < floor_ms + 15, metrics["latency_ms"]["air"]
    events = read_jsonl(out / "events.jsonl")
    delivered = [e for e in events if e.get("event") == "v2x_delivered" and e.get("via") == "rsu"]
    assert len(delivered) == link["delivered"] and min(e["latency_s"] for e in delivered) * 1e3 >= floor_ms
    applied = applied_times(read_csv(out / "can-applied.csv"))
    chains = [with_can_applied(r, applied) for r in read_jsonl(out / "trace.jsonl")]
    chains = [s for s in chains if {FRAME, SEND, AIR_ARRIVAL, CAN_APPLIED} <= set(s)]
    assert len(chains) > 50
    for s in chains:
        air_ms = (s[AIR_ARRIVAL] - s[SEND]) / 1e6
        assert air_ms >= floor_ms and (s[CAN_APPLIED] - s[FRAME]) / 1e6 >= air_ms + 50.0  # + the 50 ms detect stage
    assert metrics["latency_ms"]["e2e"]["p50"] >= 50.0 + floor_ms
