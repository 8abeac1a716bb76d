"""What makes a case-study point sweepable: its own ports and bus prefix, app settings through a participant's
`args` and `{table.key}` values in its command, the AV app's `--set`, and the channel's `loss_prob` knob."""
from __future__ import annotations

import json
import socket
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from master.errors import ScenarioError
from master.scenario.overrides import apply_overrides, parse_override
from master.scenario.loader import load_scenario, read_raw
from master.sweep.point import free_port, per_point_overrides, point_ports

ROOT = Path(__file__).resolve().parent.parent
CASE_STUDY = ROOT / "scenarios" / "ima_case_study.toml"


def test_every_fixed_port_of_the_case_study_is_replaced_per_point():
    raw = read_raw(CASE_STUDY)
    first = {o.key: o.value for o in per_point_overrides(CASE_STUDY, [], "s", "aaa")}
    second = {o.key: o.value for o in per_point_overrides(CASE_STUDY, [], "s", "bbb")}
    assert set(first) == {"bridge.listen", "can.port", "bridge.prefix"}
    for ports in (first, second):
        (endpoint,) = ports["bridge.listen"]
        assert endpoint.startswith("tcp/127.0.0.1:") and endpoint != raw["bridge"]["listen"][0]
        assert ports["can.port"] != raw["can"]["port"]
    assert first["bridge.listen"] != second["bridge.listen"] and first["can.port"] != second["can.port"]
    assert (first["bridge.prefix"], second["bridge.prefix"]) == ("v2i/sweep/s/aaa", "v2i/sweep/s/bbb")
    # ... and the AV app is told the point's CAN port through {can.port} in its command
    sc = load_scenario(CASE_STUDY, [o.text for o in per_point_overrides(CASE_STUDY, [], "s", "ccc")])
    command = sc.participants.participants["cav"].command
    assert command[command.index("--can-port") + 1] == str(sc.resolved()["can"]["port"])
    assert sc.resolved()["can"]["port"] != raw["can"]["port"]


def test_port_zero_and_absent_tables_are_left_alone():
    raw = {"bridge": {"listen": ["tcp/127.0.0.1:0"]}, "serial": {"tlc": {"listen": "socket://127.0.0.1:0"}}}
    assert point_ports(raw) == []
    raw = {"bridge": {"transport": "udp", "port": 47000}, "can": {"interface": "virtual"},
           "serial": {"tlc": {"listen": "socket://127.0.0.1:41000"}}}
    keys = {o.key: o.value for o in point_ports(raw)}
    assert set(keys) == {"bridge.port", "serial.tlc.listen"}
    assert keys["serial.tlc.listen"].startswith("socket://127.0.0.1:") and keys["bridge.port"] != 47000


def test_free_ports_are_free_and_never_handed_out_twice():
    ports = [free_port(socket.SOCK_STREAM) for _ in range(20)]
    assert len(set(ports)) == 20
    with socket.socket() as s:
        s.bind(("127.0.0.1", ports[0]))  # it was free


def test_participant_args_and_scenario_values_in_the_command(fmu_dir):
    sc = load_scenario(CASE_STUDY, ["can.port=40123", 'participants.rsu.args=["--hardware", "cpu-i7"]'])
    rsu, cav = sc.participants.participants["rsu"], sc.participants.participants["cav"]
    assert rsu.args == ["--hardware", "cpu-i7"]
    assert cav.command[-2:] == ["--can-port", "40123"]
    resolved = sc.resolved()["participants"]
    assert resolved["rsu"]["args"] == ["--hardware", "cpu-i7"]
    assert resolved["cav"]["command"][-1] == "40123"  # the resolved scenario runs as it is
    with pytest.raises(ScenarioError) as info:
        load_scenario(CASE_STUDY, ['participants.cav.args=["--can-port", "{can.prot}"]',
                                   'participants.rsu.args=["{bridge}"]', "participants.rsu.args=3"])
    problems = "\n".join(info.value.problems)
    assert "participants.rsu.args: expected a list of strings" in problems
    with pytest.raises(ScenarioError) as info:
        load_scenario(CASE_STUDY, ['participants.cav.args=["--can-port", "{can.prot}"]',
                                   'participants.rsu.args=["{bridge}", "{time.stop}"]'])
    problems = "\n".join(info.value.problems)
    assert "participants.cav.args[1]: {can.prot} names no value of the scenario; did you mean 'port'?" in problems
    assert "participants.rsu.args[0]" not in problems  # {bridge} has no dot: not a scenario value, left as is
    sc = load_scenario(CASE_STUDY, ['participants.rsu.args=["{time.stop}"]'])
    assert sc.participants.participants["rsu"].args == ["12.0"]
    with pytest.raises(ScenarioError, match=r"args\[0\]: \{world.intersection\} is a table, not a single value"):
        load_scenario(CASE_STUDY, ['participants.rsu.args=["{world.intersection}"]'])


def test_args_need_a_command(fmu_dir):
    from master.links.participants import parse_participants

    problems = []
    parse_participants({}, {"box": {"args": ["-v"]}}, ROOT, lambda k, r: problems.append(f"{k}: {r}"))
    assert problems == ["participants.box.args: appended to command: this participant has no command"]


def test_the_av_app_takes_set(tmp_path):
    cmd = [sys.executable, "-m", "av_app", "--config", str(ROOT / "scenarios" / "apps" / "av.toml"),
           "--set", "route.cruise_speed=5.556", "--set", "planner.margin_m=0.6", "--can-port", "40001",
           "--print-config"]
    r = subprocess.run(cmd, capture_output=True, text=True, timeout=60, cwd=ROOT)
    assert r.returncode == 0, r.stderr
    cfg = json.loads(r.stdout)
    assert cfg["route"]["cruise_speed"] == 5.556 and cfg["planner"]["margin_m"] == 0.6
    assert cfg["can"]["port"] == 40001
    bad = subprocess.run(cmd[:-1] + ["--set", "route.cruise_sped=5", "--print-config"], capture_output=True,
                         text=True, timeout=60, cwd=ROOT)
    assert bad.returncode == 2 and "route.cruise_sped: unknown key (did you mean 'cruise_speed'?)" in bad.stderr
    bad = subprocess.run(cmd[:-1] + ["--set", "cruise_speed=5", "--print-config"], capture_output=True,
                         text=True, timeout=60, cwd=ROOT)
    assert bad.returncode == 2 and "--set cruise_speed=5: expected TABLE.KEY=VALUE" in bad.stderr


def test_channel_loss_prob_only_removes_deliveries():
    from fmus.channel.model import ChannelModel, ChannelParams

    tx = np.zeros((4000, 3))
    rx = np.column_stack([np.full(4000, 80.0), np.zeros(4000), np.zeros(4000)])
    seq = np.arange(4000)
    base = ChannelModel(ChannelParams()).evaluate(tx, rx, seq=seq)
    lossy = ChannelModel(ChannelParams(loss_prob=0.3)).evaluate(tx, rx, seq=seq)
    assert not np.any(lossy.delivered & ~base.delivered)  # a subset of the same frames
    kept = lossy.delivered.sum() / base.delivered.sum()
    assert kept == pytest.approx(0.7, abs=0.03)
    assert lossy.pdr == pytest.approx(base.pdr * 0.7)
    one = ChannelModel(ChannelParams(loss_prob=0.3)).evaluate_one((0, 0, 0), (80, 0, 0), seq=7)
    assert one["delivered"] == bool(lossy.delivered[7]) and one["pdr"] == pytest.approx(lossy.pdr[7])
    for bad in (-0.1, 1.0):
        with pytest.raises(ValueError, match="loss_prob must be in \\[0, 1\\)"):
            ChannelParams(loss_prob=bad).validate()


def test_the_scenario_refuses_a_bad_loss(fmu_dir):
    sc = load_scenario(CASE_STUDY, ["v2x.channel.loss_prob=0.25", "v2x.channel.technology=cv2x"])
    assert sc.v2x.channel == {"loss_prob": 0.25, "technology": "cv2x"}
    with pytest.raises(ScenarioError, match="v2x.channel: parameter loss_prob must be in"):
        load_scenario(CASE_STUDY, ["v2x.channel.loss_prob=1.5"])
    raw, _ = apply_overrides(read_raw(CASE_STUDY), [parse_override("v2x.channel.loss_prob=0.1")])
    assert raw["v2x"]["channel"] == {"loss_prob": 0.1} and raw["v2x"]["max_range_m"] == 500.0
