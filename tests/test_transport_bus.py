"""Both network backends (udp, zenoh) between two real processes over loopback.

The other process is a small command server (spawned once per module) that opens buses, publishes,
subscribes and reports what it received, driven over a multiprocessing pipe.
"""
from __future__ import annotations

import hashlib
import logging
import multiprocessing as mp
import socket
import subprocess
import sys
import textwrap
import time
import uuid

import pytest

from bridges.transport import KeyExprError, TransportError, encode, open_bus
from bridges.transport.fragments import HEADER, split
from bridges.transport.keys import join

BACKENDS = ["udp", "zenoh"]
FRAME = 640 * 480 * 3


# -- the other process ------------------------------------------------------------------------
def _summary(msg) -> dict | None:
    if msg is None:
        return None
    return {"key": msg.key, "sender": msg.sender, "t_sim": msg.t_sim, "seq": msg.seq, "stamps": msg.stamps,
            "size": len(msg.payload), "sha": hashlib.sha1(msg.payload).hexdigest(),
            "payload": msg.payload if len(msg.payload) <= 64 else None, "version": msg.version}


def _peer_main(conn) -> None:
    """Command loop: ("op", args...) -> ("ok", result) | ("error", text)."""
    buses, subs = {}, {}
    while True:
        op, *args = conn.recv()
        try:
            result = None
            if op == "open":
                bid, backend, prefix, sender, options = args
                buses[bid] = open_bus(backend, prefix=prefix, sender=sender, **options)
            elif op == "subscribe":
                bid, sid, expr, kw = args
                subs[sid] = buses[bid].subscribe(expr, **kw)
            elif op == "echo":  # republish everything on ping/** as pong/** with the same payload and stamps
                bid, = args
                bus = buses[bid]
                subs[("echo", bid)] = bus.subscribe(
                    "ping/**", lambda m, bus=bus: bus.publish("pong/" + m.key[5:], m.payload, m.t_sim, m.stamps))
            elif op == "recv_all":
                sid, n, timeout = args
                got, deadline = [], time.monotonic() + timeout
                while len(got) < n and time.monotonic() < deadline:
                    m = subs[sid].recv(timeout=max(0.0, deadline - time.monotonic()))
                    if m is not None:
                        got.append(_summary(m))
                result = got
            elif op == "publish":
                bid, key, payload, t_sim, stamps = args
                result = buses[bid].publish(key, payload, t_sim, stamps)
            elif op == "publish_many":
                bid, key, n, size = args
                result = [buses[bid].publish(key, i.to_bytes(4, "little") * (size // 4), 0.01 * i) for i in range(n)]
            elif op == "publish_raw":  # bytes straight onto the wire: forged versions, truncations, repeats
                bid, key, data = args
                bus = buses[bid]
                bus._send(join(bus.prefix, key), data)
            elif op == "stats":
                result = buses[args[0]].stats()
            elif op == "close":
                buses.pop(args[0]).close()
            elif op == "exit":
                for bus in buses.values():
                    bus.close()
                conn.send(("ok", None))
                return
            conn.send(("ok", result))
        except Exception as exc:  # report to the test, keep serving
            conn.send(("error", f"{type(exc).__name__}: {exc}"))


class Peer:
    def __init__(self):
        ctx = mp.get_context("spawn")
        self.conn, child = ctx.Pipe()
        self.proc = ctx.Process(target=_peer_main, args=(child,), daemon=True)
        self.proc.start()

    def __call__(self, *cmd, timeout: float = 20.0):
        self.conn.send(cmd)
        if not self.conn.poll(timeout):
            raise AssertionError(f"peer did not answer {cmd[0]} within {timeout} s")
        status, result = self.conn.recv()
        if status != "ok":
            raise AssertionError(f"peer failed {cmd[0]}: {result}")
        return result

    def stop(self):
        try:
            self("exit", timeout=5)
        finally:
            self.proc.join(5)
            if self.proc.is_alive():
                self.proc.kill()


@pytest.fixture(scope="module")
def peer():
    p = Peer()
    yield p
    p.stop()


def free_port(kind=socket.SOCK_STREAM) -> int:
    with socket.socket(socket.AF_INET, kind) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class Link:
    """A bus here and a bus in the peer process, on one fresh prefix and a fresh port."""

    def __init__(self, peer, backend, here_opts=None, there_opts=None):
        self.peer, self.backend = peer, backend
        self.prefix = f"v2i/test-{uuid.uuid4().hex[:8]}"
        self.bid = uuid.uuid4().hex[:8]
        if backend == "udp":
            port = free_port(socket.SOCK_DGRAM)
            base = dict(port=port, iface="127.0.0.1", ttl=0)
            self.here_opts = {**base, **(here_opts or {})}
            there = {**base, **(there_opts or {})}
        else:
            port = free_port()
            self.here_opts = dict(listen=[f"tcp/127.0.0.1:{port}"], multicast_scouting=False, **(here_opts or {}))
            there = dict(connect=[f"tcp/127.0.0.1:{port}"], multicast_scouting=False, **(there_opts or {}))
        self.there_opts = there
        self.bus = open_bus(backend, prefix=self.prefix, sender="master", **self.here_opts)
        peer("open", self.bid, backend, self.prefix, "rsu1", there)
        peer("echo", self.bid)
        self._pong = self.bus.subscribe("pong/**")
        self.sync()

    def sync(self, timeout=10.0):
        """Round trip through the peer: once it returns, subscriptions declared before it are in place."""
        token = uuid.uuid4().hex.encode()
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            self.bus.publish("ping/sync", token, 0.0)
            while (m := self._pong.recv(timeout=0.05)) is not None:
                if m.payload == token:
                    return
        raise AssertionError(f"{self.backend}: no round trip through the peer within {timeout} s")

    def other_bus(self, prefix=None, **opts):
        """Another bus here, on the same wire (UDP: same port; zenoh: connected to our listener)."""
        if self.backend == "udp":
            options = {**self.here_opts, **opts}
        else:
            options = dict(connect=self.here_opts["listen"], multicast_scouting=False, **opts)
        return open_bus(self.backend, prefix=prefix or self.prefix, sender="other", **options)

    def remote_subscribe(self, expr, **kw):
        sid = uuid.uuid4().hex[:8]
        self.peer("subscribe", self.bid, sid, expr, kw)
        self.sync()
        return sid

    def close(self):
        self.bus.close()
        self.peer("close", self.bid)


@pytest.fixture(params=BACKENDS)
def link(request, peer):
    lk = Link(peer, request.param)
    yield lk
    lk.close()


def drain(sub, n, timeout=5.0):
    got, deadline = [], time.monotonic() + timeout
    while len(got) < n and time.monotonic() < deadline:
        m = sub.recv(timeout=max(0.0, deadline - time.monotonic()))
        if m is not None:
            got.append(m)
    return got


# -- tests ------------------------------------------------------------------------------------
def test_delivery_in_order_with_every_field(link, peer):
    sub = link.bus.subscribe("v2x/tx/rsu1")
    link.sync()
    seqs = peer("publish_many", link.bid, "v2x/tx/rsu1", 200, 200)
    assert seqs == list(range(200))
    got = drain(sub, 200)
    assert [m.seq for m in got] == list(range(200))
    m = got[17]
    assert (m.key, m.sender, m.version, m.t_sim) == ("v2x/tx/rsu1", "rsu1", (1, 0), 0.17)
    assert m.payload == (17).to_bytes(4, "little") * 50 and m.received_ns > 0
    stats = link.bus.stats()
    assert stats["duplicates"] == stats["reordered"] == stats["garbage"] == 0
    assert link.bus.stream_stats()[("rsu1", "v2x/tx/rsu1")]["last_seq"] == 199


def test_stamps_and_t_sim_travel_both_ways(link, peer):
    sid = link.remote_subscribe("clock/**")
    t0 = time.time_ns()
    assert link.bus.publish("clock/tick", b"", 3.25, {"master_sent": t0}) == 0
    (m,) = peer("recv_all", sid, 1, 5.0)
    assert (m["key"], m["sender"], m["t_sim"], m["stamps"], m["seq"]) == \
        ("clock/tick", "master", 3.25, {"master_sent": t0}, 0)


def test_prefix_isolation(link, peer):
    other_run = link.other_bus(prefix=link.prefix + "x")  # 'v2i/test-abcx' is not under 'v2i/test-abc'
    try:
        sub_other = other_run.subscribe("**")
        sub_mine = link.bus.subscribe("data/**")
        link.sync()
        peer("publish_many", link.bid, "data/a", 5, 8)
        assert len(drain(sub_mine, 5)) == 5
        assert sub_other.recv(timeout=0.3) is None
        if link.backend == "udp":  # same wire, so the other run heard and ignored it
            assert other_run.stats()["other_prefix"] >= 5
    finally:
        other_run.close()


def test_wildcard_subscriptions(link, peer):
    one = link.bus.subscribe("v2x/*/rsu1")
    many = link.bus.subscribe("camera/**")
    tx = link.bus.subscribe("v2x/tx/*")
    link.sync()
    keys = ["v2x/tx/rsu1", "v2x/rx/rsu1", "v2x/tx/obu7", "camera/rsu_cam", "camera/rsu_cam/info", "clock/tick"]
    for k in keys:
        peer("publish", link.bid, k, k.encode(), 1.0, None)
    link.sync()
    assert sorted(m.key for m in drain(one, 2)) == ["v2x/rx/rsu1", "v2x/tx/rsu1"]
    assert sorted(m.key for m in drain(many, 2)) == ["camera/rsu_cam", "camera/rsu_cam/info"]
    assert sorted(m.key for m in drain(tx, 2)) == ["v2x/tx/obu7", "v2x/tx/rsu1"]
    for s in (one, many, tx):
        assert s.recv(timeout=0.05) is None


def test_raw_camera_frame_both_directions(link, peer):
    frame = bytes(range(256)) * (FRAME // 256)
    assert len(frame) == FRAME
    sub = link.bus.subscribe("camera/rsu_cam")
    sid = link.remote_subscribe("camera/master_cam")
    link.sync()
    peer("publish", link.bid, "camera/rsu_cam", frame, 0.1, {"rendered": 1})
    (m,) = drain(sub, 1)
    assert m.payload == frame and m.stamps == {"rendered": 1}
    link.bus.publish("camera/master_cam", frame, 0.2)
    (r,) = peer("recv_all", sid, 1, 5.0)
    assert r["size"] == FRAME and r["sha"] == hashlib.sha1(frame).hexdigest()
    if link.backend == "udp":
        assert len(split(frame, 0, 0, 1400)) > 600  # it really was fragmented
        assert link.bus.stats()["incomplete"] == 0


def test_latest_only_keeps_the_newest(link, peer):
    sub = link.bus.subscribe("camera/rsu_cam", latest_only=True)
    link.sync()
    peer("publish_many", link.bid, "camera/rsu_cam", 30, 64 * 1024)
    link.sync()
    m = sub.recv(timeout=2)
    assert m.seq == 29 and sub.recv(timeout=0.05) is None
    assert link.bus.stats()["superseded"] == 29


def test_bounded_queue_counts_drops(link, peer):
    sub = link.bus.subscribe("data/x", maxlen=5)
    link.sync()
    peer("publish_many", link.bid, "data/x", 20, 8)
    link.sync()
    assert [m.seq for m in drain(sub, 5, timeout=2)] == [15, 16, 17, 18, 19]
    assert link.bus.stats()["dropped_queue_full"] == 15


def test_callback_subscription(link, peer):
    got = []
    sub = link.bus.subscribe("data/cb", got.append)
    link.sync()
    peer("publish_many", link.bid, "data/cb", 3, 8)
    link.sync()
    assert [m.seq for m in got] == [0, 1, 2]
    with pytest.raises(TransportError, match="callback"):
        sub.recv(0)


def test_other_major_version_is_dropped_counted_and_logged_once(link, peer, caplog):
    sub = link.bus.subscribe("v2x/**")
    link.sync()
    forged = encode("rsu9", join(link.prefix, "v2x/tx/rsu9"), 1.0, 0, b"future", version=(2, 0))
    with caplog.at_level(logging.WARNING, logger="bridges.transport"):
        for _ in range(3):
            peer("publish_raw", link.bid, "v2x/tx/rsu9", forged)
        peer("publish", link.bid, "v2x/tx/rsu1", b"current", 1.0, None)
        (m,) = drain(sub, 1)
    assert m.payload == b"current"
    assert link.bus.stats()["version_mismatch"] == 3
    lines = [r.getMessage() for r in caplog.records if "speaks bridge protocol" in r.getMessage()]
    assert len(lines) == 1 and "participant rsu9 speaks bridge protocol 2.0, this side 1.0" in lines[0]


def test_truncated_envelope_and_repeats(link, peer):
    sub = link.bus.subscribe("data/**")
    link.sync()
    full = join(link.prefix, "data/t")
    good = [encode("rsu1", full, 0.1 * s, s, b"x%d" % s, session=4242) for s in range(6)]
    peer("publish_raw", link.bid, "data/t", good[0][:-3])   # truncated: counted, dropped
    for s in (5, 5, 3):                                       # duplicate dropped, reordered delivered
        peer("publish_raw", link.bid, "data/t", good[s])
    got = drain(sub, 2)
    link.sync()
    assert [m.seq for m in got] == [5, 3] and sub.recv(timeout=0.05) is None
    stats = link.bus.stats()
    assert (stats["truncated"], stats["duplicates"], stats["reordered"]) == (1, 1, 1)
    assert link.bus.stream_stats()[("rsu1", "data/t")] == {"received": 2, "duplicates": 1, "reordered": 1,
                                                            "last_seq": 5}


def test_oversized_messages(link, peer):
    with pytest.raises(TransportError, match=r"would be \d+ bytes \(payload 5000000\), over .* 4194304"):
        link.bus.publish("camera/huge", bytes(5_000_000), 0.0)
    small = link.other_bus(max_size=10_000)
    try:
        sub = small.subscribe("data/**")
        deadline = time.monotonic() + 10
        while sub.recv(timeout=0.05) is None:  # until the peer's messages reach this third bus
            assert time.monotonic() < deadline, "the small bus never heard the peer"
            peer("publish", link.bid, "data/ready", b"", 0.0, None)
        while sub.recv(timeout=0.1) is not None:
            pass
        peer("publish", link.bid, "data/big", bytes(20_000), 0.0, None)
        peer("publish", link.bid, "data/ok", b"fine", 0.0, None)
        assert [m.key for m in drain(sub, 1)] == ["data/ok"]
        assert small.stats()["oversized"] == 1
    finally:
        small.close()


def test_key_validation_is_immediate(link):
    with pytest.raises(KeyExprError, match="empty"):
        link.bus.publish("v2x//tx", b"", 0.0)
    with pytest.raises(KeyExprError, match="whole chunks"):
        link.bus.subscribe("cam*")
    with pytest.raises(KeyExprError, match="reserved"):
        link.bus.publish("v2x/*", b"", 0.0)


# -- UDP only ---------------------------------------------------------------------------------
def test_udp_garbage_datagrams_are_counted_and_survived():
    # A unicast-mode bus owns its port; on a shared multicast port the kernel hands a unicast
    # datagram to only one of the sockets, so the injection would be a lottery.
    port = free_port(socket.SOCK_DGRAM)
    bus = open_bus("udp", prefix="v2i/garbage", sender="victim", port=port, peers=["127.0.0.1:9"])
    try:
        sub = bus.subscribe("data/**")
        full = join("v2i/garbage", "data/after")
        truncated = encode("rsu1", full, 0.0, 0, b"abc")[:-2]
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as raw:
            dest = ("127.0.0.1", port)
            raw.sendto(b"hello", dest)                                         # too short for a header
            raw.sendto(b"GET / HTTP/1.1\r\nHost: x\r\n\r\n", dest)              # bad fragment magic
            raw.sendto(HEADER.pack(b"V2IF", 1, 1, 0, 4) + b"junk", dest)        # fragment of a non-envelope
            raw.sendto(split(truncated, 7, 1, 1400)[0], dest)                  # truncated envelope
            raw.sendto(HEADER.pack(b"V2IF", 1, 2, 0, 3000) + bytes(1000), dest)  # never completed
            raw.sendto(HEADER.pack(b"V2IF", 1, 3, 0, 1 << 30) + bytes(100), dest)  # 1 GiB announced
            raw.sendto(split(encode("rsu1", full, 0.0, 1, b"ok"), 7, 3, 1400)[0], dest)
        (m,) = drain(sub, 1)
        assert m.payload == b"ok" and m.extra["source"].startswith("127.0.0.1:")
        stats = bus.stats()
        assert (stats["garbage"], stats["truncated"], stats["oversized"]) == (3, 1, 1)
        deadline = time.monotonic() + 3
        while bus.stats()["incomplete"] == 0 and time.monotonic() < deadline:
            time.sleep(0.05)
        assert bus.stats()["incomplete"] == 1
        assert bus._thread.is_alive()
    finally:
        bus.close()


def test_udp_unicast_peers(peer):
    here_port, there_port = free_port(socket.SOCK_DGRAM), free_port(socket.SOCK_DGRAM)
    lk = Link(peer, "udp", here_opts=dict(port=here_port, peers=[f"127.0.0.1:{there_port}"]),
              there_opts=dict(port=there_port, peers=[f"localhost:{here_port}"]))
    try:
        assert lk.bus.group is None
        sub = lk.bus.subscribe("camera/rsu_cam")
        peer("publish", lk.bid, "camera/rsu_cam", bytes(FRAME), 0.1, None)
        (m,) = drain(sub, 1)
        assert len(m.payload) == FRAME
        with pytest.raises(TransportError, match="cannot open"):
            open_bus("udp", prefix="v2i/x", sender="clash", port=here_port, peers=["127.0.0.1:9"])
    finally:
        lk.close()


def test_udp_bad_options():
    with pytest.raises(TransportError, match="host:port"):
        open_bus("udp", prefix="v2i/x", sender="a", port=0, peers=["nohost"])
    with pytest.raises(TransportError, match="datagram_size"):
        open_bus("udp", prefix="v2i/x", sender="a", port=0, datagram_size=10)


# -- zenoh only -------------------------------------------------------------------------------
def test_zenoh_process_exits_without_close():
    """An open zenoh session with callbacks in flight must not hang interpreter exit."""
    port = free_port()
    code = textwrap.dedent(f"""
        import time
        from bridges.transport import open_bus
        a = open_bus("zenoh", prefix="v2i/exit", sender="a", listen=["tcp/127.0.0.1:{port}"], multicast_scouting=False)
        b = open_bus("zenoh", prefix="v2i/exit", sender="b", connect=["tcp/127.0.0.1:{port}"], multicast_scouting=False)
        sub = a.subscribe("x", lambda m: None)
        time.sleep(0.2)
        for i in range(20):
            b.publish("x", b"y", 0.0)
        time.sleep(0.2)
        print("bye", a.stats()["received"])
    """)
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=30,
                         cwd=str(__import__("pathlib").Path(__file__).resolve().parent.parent))
    assert out.returncode == 0, out.stderr
    assert out.stdout.split()[0] == "bye" and int(out.stdout.split()[1]) > 0


def test_zenoh_bad_endpoint_is_a_transport_error():
    with pytest.raises(TransportError, match="zenoh could not open"):
        open_bus("zenoh", prefix="v2i/x", sender="a", listen=["nonsense/1.2.3.4"], multicast_scouting=False)
