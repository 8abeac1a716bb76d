"""Hardware-in-the-loop rehearsal: master and a "box" in two network namespaces joined by a veth pair.

The master (`v2i run`) runs in one namespace at 10.77.0.1, an echo participant
in the other at 10.77.0.2, so every message crosses a real (virtual) Ethernet
link with its own IP stack, as with an RSU box on a cable. Where the kernel has
netem, 2 ms of delay each way makes the link slower than loopback. Needs root
and `ip netns`; skipped, with the reason, otherwise.
"""
from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import textwrap
import uuid

import pytest

MASTER_IP, BOX_IP = "10.77.0.1", "10.77.0.2"


def _ip(*args, ns: str | None = None, check: bool = True) -> subprocess.CompletedProcess:
    cmd = ["ip", *(["netns", "exec", ns, "ip"] if ns else []), *args]
    return subprocess.run(cmd, capture_output=True, text=True, check=check, timeout=20)


def _skip_reason() -> str | None:
    if shutil.which("ip") is None:
        return "the `ip` command (iproute2) is not installed"
    if os.geteuid() != 0:
        return "network namespaces need root (run the tests as root, e.g. in a container)"
    probe = f"v2i-probe-{uuid.uuid4().hex[:6]}"
    made = subprocess.run(["ip", "netns", "add", probe], capture_output=True, text=True)
    if made.returncode != 0:
        return f"`ip netns add` does not work here: {made.stderr.strip()}"
    subprocess.run(["ip", "netns", "del", probe], capture_output=True)
    return None


@pytest.fixture(scope="module")
def netns_pair():
    """(master_ns, box_ns, delayed): two namespaces, lo up, veth 10.77.0.1/24 <-> 10.77.0.2/24, netem delay
    where the kernel has it; always removed."""
    reason = _skip_reason()
    if reason:
        pytest.skip(reason)
    tag = uuid.uuid4().hex[:6]
    names = (f"v2i-m-{tag}", f"v2i-b-{tag}")
    veth = (f"v2im{tag}", f"v2ib{tag}")  # interface names: at most 15 characters
    delayed = bool(shutil.which("tc"))
    try:
        for ns in names:
            _ip("netns", "add", ns)
            _ip("link", "set", "lo", "up", ns=ns)
        _ip("link", "add", veth[0], "type", "veth", "peer", "name", veth[1])
        for ns, dev, addr in zip(names, veth, (MASTER_IP, BOX_IP)):
            _ip("link", "set", dev, "netns", ns)
            _ip("addr", "add", f"{addr}/24", "dev", dev, ns=ns)
            _ip("link", "set", dev, "up", ns=ns)
            if delayed:  # a link slower than loopback: 2 ms each way (needs the sch_netem module)
                delayed = subprocess.run(["ip", "netns", "exec", ns, "tc", "qdisc", "add", "dev", dev, "root",
                                          "netem", "delay", "2ms"], capture_output=True).returncode == 0
        ping = subprocess.run(["ip", "netns", "exec", names[1], "ping", "-c", "1", "-W", "2", MASTER_IP],
                              capture_output=True, text=True)
        if ping.returncode != 0 and shutil.which("ping"):
            pytest.fail(f"the veth link does not carry packets: {ping.stdout}{ping.stderr}")
        yield (*names, delayed)
    finally:
        for ns in names:
            pids = subprocess.run(["ip", "netns", "pids", ns], capture_output=True, text=True).stdout.split()
            for pid in pids:  # only processes this test started live in these namespaces
                try:
                    os.kill(int(pid), signal.SIGKILL)
                except (ProcessLookupError, ValueError):
                    pass
            subprocess.run(["ip", "netns", "del", ns], capture_output=True)
        subprocess.run(["ip", "link", "del", veth[0]], capture_output=True)  # only if it never moved


def _scenario(tmp_path, vehicle_fmu, mode: str, prefix: str, port: int) -> str:
    path = tmp_path / f"hil-{mode}.toml"
    path.write_text(textwrap.dedent(f"""
        [scenario]
        name = "hil-{mode}"
        [time]
        stop = {0.5 if mode == "lockstep" else 1.0}
        step = 0.01
        mode = "{mode}"
        [fmus.car]
        fmu = "{vehicle_fmu}"
        [bridge]
        transport = "zenoh"
        prefix = "{prefix}"
        listen = ["tcp/{MASTER_IP}:{port}"]
        join_timeout_s = 20.0
        [participants.box]
        role = "box"
        timeout_s = 5.0
        [participants.obu]
        role = "av_app"
        timeout_s = 5.0
    """))
    return str(path)


def _exchange(netns_pair, tmp_path, vehicle_fmu, mode: str, *box_args: str) -> tuple[dict, dict, dict]:
    """The master in one namespace; two participants ("box" with `box_args`, and "obu") in the other."""
    master_ns, box_ns, _ = netns_pair
    prefix, port = f"v2i/hil-{uuid.uuid4().hex[:8]}", 17447
    run_dir = tmp_path / f"run-{mode}"
    master = subprocess.Popen(
        ["ip", "netns", "exec", master_ns, sys.executable, "-m", "master.cli", "run",
         _scenario(tmp_path, vehicle_fmu, mode, prefix, port), "--out", str(run_dir), "--quiet"],
        stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    apps = {name: subprocess.Popen(
        ["ip", "netns", "exec", box_ns, sys.executable, "-m", "bridges.timesync.echo_participant",
         "--bus", "zenoh", "--prefix", prefix, "--connect", f"tcp/{MASTER_IP}:{port}", "--name", name,
         "--role", role, *args],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        for name, role, args in (("box", "box", box_args), ("obu", "av_app", ()))}
    outs = {}
    try:
        master_out, _ = master.communicate(timeout=60)
        for name, proc in apps.items():
            outs[name] = proc.communicate(timeout=20)
    finally:
        for proc in (master, *apps.values()):
            if proc.poll() is None:
                proc.kill()
                proc.wait()
    assert master.returncode == 0, master_out
    for name, proc in apps.items():
        assert proc.returncode == 0, outs[name][1]
    meta = json.loads((run_dir / "metadata.json").read_text())
    box, obu = (json.loads(outs[n][0].strip().splitlines()[-1]) for n in ("box", "obu"))
    return meta, box, obu


def test_lockstep_across_the_link(netns_pair, tmp_path, vehicle_fmu):
    meta, box, obu = _exchange(netns_pair, tmp_path, vehicle_fmu, "lockstep")
    assert meta["status"] == "completed"
    for name, app in (("box", box), ("obu", obu)):
        member = meta["participants"]["members"][name]
        assert member["acks"] == 50 and member["timeouts"] == 0, (name, member)
        assert member["host"] and app["ticks"] == 50 and app["end"] == "completed"


def test_realtime_offset_across_the_link(netns_pair, tmp_path, vehicle_fmu):
    """The box's clock runs 0.25 s ahead; across the link the estimate is within a few ms."""
    meta, box, obu = _exchange(netns_pair, tmp_path, vehicle_fmu, "realtime", "--clock-offset", "0.25")
    offset = meta["participants"]["members"]["box"]["clock_offset"]
    other = meta["participants"]["members"]["obu"]["clock_offset"]
    assert other is not None and abs(other["offset_ns"]) < 3_000_000, other  # same clock as the master
    assert offset is not None, meta["participants"]
    assert abs(offset["offset_ns"] + 250_000_000) < 3_000_000, offset
    if netns_pair[2]:
        assert offset["rtt_ns"] >= 3_000_000  # it did cross the delayed link
    assert box["mode"] == "realtime" and box["offset_ns"] == offset["offset_ns"]
