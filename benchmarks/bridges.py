"""Benchmark: the bridge transports between two processes on this machine, beside a bare socket floor.

    python benchmarks/bridges.py [--repeats 3] [--json PATH] [--quick]

Cases (each an echo process and this process, over loopback):
* `floor`: a bare socket, no envelope: UDP datagram ping-pong for 200-byte messages; for a raw
  640x480x3 frame (921,600 bytes, more than one datagram) a TCP connection with a length prefix.
* `zenoh`: open_bus("zenoh"), peer mode, tcp/127.0.0.1 listen/connect, no scouting.
* `udp`: open_bus("udp"), multicast 239.255.42.99 on 127.0.0.1, 1400-byte datagrams (default).
* `udp-64k`: the same with 65000-byte datagrams (what a loopback or jumbo-frame link allows).

Per case and size:
* one-way latency = RTT/2 of an echo (publish -> the peer's subscription callback republishes ->
  our subscription receives): p50, p99, max over the pings of a repeat;
* throughput: the sender publishes back-to-back, the peer counts; messages/s and MB/s from the
  first send to the last arrival, and the fraction delivered (UDP may drop under a flood).
Figures are medians over repeats (max: the largest), with ratios to the floor of the same size.

Lockstep ticks per second with 1, 2 and 8 participants is the time protocol's part:
`bench_lockstep` below measures it with bridges.timesync.bench. Results: benchmarks/results/bridges.json.
"""
from __future__ import annotations

import argparse
import multiprocessing as mp
import socket
import statistics
import struct
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
# the repository first, and not this folder: its bridges.py would shadow the bridges package
# (with an editable install ROOT is already on the path, behind this folder)
sys.path[:] = [str(ROOT)] + [p for p in sys.path if Path(p or ".").resolve() != ROOT / "benchmarks"]

from benchmarks.common import RESULTS, machine_info, write_report  # noqa: E402

FRAME = 640 * 480 * 3
SIZES = {"200 B": 200, "frame": FRAME}
CASES = ("floor", "zenoh", "udp", "udp-64k")


def free_port(kind=socket.SOCK_STREAM) -> int:
    with socket.socket(socket.AF_INET, kind) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def bus_options(case: str, port: int, server: bool) -> tuple[str, dict]:
    if case == "zenoh":
        side = "listen" if server else "connect"
        return "zenoh", {side: [f"tcp/127.0.0.1:{port}"], "multicast_scouting": False}
    opts = {"port": port, "iface": "127.0.0.1", "ttl": 0}
    if case == "udp-64k":
        opts["datagram_size"] = 65000
    return "udp", opts


# -- the echo process -------------------------------------------------------------------------
def _bus_server(case: str, port: int, ready) -> None:
    from bridges.transport import open_bus

    backend, opts = bus_options(case, port, server=True)
    bus = open_bus(backend, prefix="v2i/bench", sender="echo", **opts)
    flood = {"n": 0, "last": 0}

    def on_ping(m):
        bus.publish("bench/pong", m.payload, m.t_sim, m.stamps)

    def on_flood(m):
        flood["n"] += 1
        flood["last"] = m.received_ns

    def on_end(m):
        bus.publish("bench/flood_result", struct.pack("<qq", flood["n"], flood["last"]), 0.0)
        flood.update(n=0, last=0)

    bus.subscribe("bench/ping", on_ping)
    bus.subscribe("bench/flood", on_flood)
    bus.subscribe("bench/flood_end", on_end)
    stop = bus.subscribe("bench/stop")
    ready.set()
    stop.recv()
    bus.close()


def _floor_server(port: int, tcp_port: int, ready) -> None:
    udp = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    udp.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4 * 1024 * 1024)  # as the udp bus does
    udp.bind(("127.0.0.1", port))
    lst = socket.socket()
    lst.bind(("127.0.0.1", tcp_port))
    lst.listen(1)
    ready.set()
    import threading

    def udp_loop():
        n = last = 0
        while True:
            data, addr = udp.recvfrom(65535)
            if data[:1] == b"P":
                udp.sendto(data, addr)
            elif data[:1] == b"F":
                n += 1
                last = time.time_ns()
            elif data[:1] == b"E":
                udp.sendto(struct.pack("<qq", n, last), addr)
                n = last = 0
            elif data[:1] == b"S":
                return

    threading.Thread(target=udp_loop, daemon=True).start()
    conn, _ = lst.accept()
    conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
    n = last = 0
    while True:
        head = _read_exact(conn, 5)
        if head is None:
            return
        kind, size = head[:1], struct.unpack("<I", head[1:])[0]
        body = _read_exact(conn, size)
        if kind == b"P":
            conn.sendall(head + body)
        elif kind == b"F":
            n += 1
            last = time.time_ns()
        elif kind == b"E":
            conn.sendall(struct.pack("<qq", n, last))
            n = last = 0


def _read_exact(conn, n: int) -> bytes | None:
    buf = bytearray()
    while len(buf) < n:
        chunk = conn.recv(n - len(buf))
        if not chunk:
            return None
        buf += chunk
    return bytes(buf)


# -- measurements -----------------------------------------------------------------------------
def latency_stats(rtts_ns: list[int]) -> dict:
    one_way = sorted(r / 2 / 1000 for r in rtts_ns)  # microseconds
    return {"p50_us": statistics.median(one_way), "p99_us": one_way[min(len(one_way) - 1, int(0.99 * len(one_way)))],
            "max_us": one_way[-1], "n": len(one_way)}


def run_bus_case(case: str, pings: dict, floods: dict) -> dict:
    from bridges.transport import open_bus

    ctx = mp.get_context("spawn")
    port = free_port(socket.SOCK_DGRAM if case.startswith("udp") else socket.SOCK_STREAM)
    ready = ctx.Event()
    proc = ctx.Process(target=_bus_server, args=(case, port, ready), daemon=True)
    proc.start()
    if not ready.wait(30):
        raise RuntimeError(f"{case}: echo process did not start")
    backend, opts = bus_options(case, port, server=False)
    bus = open_bus(backend, prefix="v2i/bench", sender="client", **opts)
    out = {}
    try:
        pong = bus.subscribe("bench/pong")
        result = bus.subscribe("bench/flood_result")
        deadline = time.monotonic() + 10  # until the echo answers
        while True:
            bus.publish("bench/ping", b"sync", 0.0)
            if pong.recv(timeout=0.05) is not None:
                break
            if time.monotonic() > deadline:
                raise RuntimeError(f"{case}: no echo within 10 s")
        while pong.recv(timeout=0.1) is not None:
            pass
        for label, size in SIZES.items():
            payload = bytes(size)
            rtts, lost = [], 0
            for _ in range(pings[label]):
                t0 = time.perf_counter_ns()
                bus.publish("bench/ping", payload, 0.0)
                m = pong.recv(timeout=1.0)
                if m is None:
                    lost += 1
                    continue
                rtts.append(time.perf_counter_ns() - t0)
            while pong.recv(timeout=0.02) is not None:  # late answers of lost pings
                pass
            entry = latency_stats(rtts) if rtts else {}
            entry["ping_lost"] = lost
            n = floods[label]
            t0 = time.time_ns()
            for i in range(n):
                bus.publish("bench/flood", payload, 0.0)
            got = None
            for _ in range(20):  # the end marker may itself be lost on UDP
                time.sleep(0.05)
                bus.publish("bench/flood_end", b"", 0.0)
                m = result.recv(timeout=1.0)
                if m is not None:
                    got = struct.unpack("<qq", m.payload)
                    break
            if got and got[0]:
                elapsed = (got[1] - t0) / 1e9
                entry.update(msgs_per_s=got[0] / elapsed, mb_per_s=got[0] * size / elapsed / 1e6,
                             delivered=got[0] / n)
            else:
                entry.update(msgs_per_s=0.0, mb_per_s=0.0, delivered=0.0)
            out[label] = entry
        out["stats"] = bus.stats()
    finally:
        bus.publish("bench/stop", b"", 0.0)
        bus.close()
        proc.join(5)
        if proc.is_alive():
            proc.kill()
    return out


def run_floor(pings: dict, floods: dict) -> dict:
    ctx = mp.get_context("spawn")
    port, tcp_port = free_port(socket.SOCK_DGRAM), free_port()
    ready = ctx.Event()
    proc = ctx.Process(target=_floor_server, args=(port, tcp_port, ready), daemon=True)
    proc.start()
    ready.wait(30)
    udp = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    udp.settimeout(1.0)
    tcp = socket.create_connection(("127.0.0.1", tcp_port))
    tcp.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
    out = {}
    try:
        # 200 B over UDP
        msg = b"P" + bytes(199)
        rtts, lost = [], 0
        for _ in range(pings["200 B"]):
            t0 = time.perf_counter_ns()
            udp.sendto(msg, ("127.0.0.1", port))
            try:
                udp.recvfrom(65535)
                rtts.append(time.perf_counter_ns() - t0)
            except socket.timeout:
                lost += 1
        entry = {**latency_stats(rtts), "ping_lost": lost, "transport": "UDP datagram"}
        n = floods["200 B"]
        flood = b"F" + bytes(199)
        t0 = time.time_ns()
        for _ in range(n):
            udp.sendto(flood, ("127.0.0.1", port))
        time.sleep(0.05)
        udp.sendto(b"E", ("127.0.0.1", port))
        count, last = struct.unpack("<qq", udp.recvfrom(64)[0])
        elapsed = (last - t0) / 1e9
        entry.update(msgs_per_s=count / elapsed, mb_per_s=count * 200 / elapsed / 1e6, delivered=count / n)
        out["200 B"] = entry
        # frame over TCP
        body = bytes(FRAME)
        ping = b"P" + struct.pack("<I", FRAME) + body
        rtts = []
        for _ in range(pings["frame"]):
            t0 = time.perf_counter_ns()
            tcp.sendall(ping)
            _read_exact(tcp, len(ping))
            rtts.append(time.perf_counter_ns() - t0)
        entry = {**latency_stats(rtts), "ping_lost": 0, "transport": "TCP, length-prefixed"}
        n = floods["frame"]
        flood = b"F" + struct.pack("<I", FRAME) + body
        t0 = time.time_ns()
        for _ in range(n):
            tcp.sendall(flood)
        tcp.sendall(b"E" + struct.pack("<I", 0))
        count, last = struct.unpack("<qq", _read_exact(tcp, 16))
        elapsed = (last - t0) / 1e9
        entry.update(msgs_per_s=count / elapsed, mb_per_s=count * FRAME / elapsed / 1e6, delivered=count / n)
        out["frame"] = entry
    finally:
        udp.sendto(b"S", ("127.0.0.1", port))
        tcp.close()
        udp.close()
        proc.join(5)
        if proc.is_alive():
            proc.kill()
    return out


def bench_lockstep(backends: tuple[str, ...], participants: tuple[int, ...] = (1, 2, 8), quick: bool = False) -> dict:
    """Lockstep ticks per second with 1, 2 and 8 echo participants (separate processes; memory: threads)."""
    from bridges.timesync.bench import bench_lockstep as one

    seconds = 0.5 if quick else 2.0
    out: dict = {}
    for backend in ("memory", *backends):
        out[backend] = {}
        for n in participants:
            r = one(n, backend, seconds=seconds)
            out[backend][n] = {"ticks_per_s": r["ticks_per_s"], "tick_resends": r["tick_resends"]}
    return out


def print_lockstep(lockstep: dict) -> None:
    ns = sorted({n for per in lockstep.values() for n in per})
    print("\nlockstep ticks per second (master tick -> every participant's ack)")
    print("backend   " + "".join(f"{n:>10d} p" for n in ns))
    for backend, per in lockstep.items():
        print(f"{backend:8s}  " + "".join(f"{per[n]['ticks_per_s']:>12.0f}" for n in ns))


# -- report ------------------------------------------------------------------------------------
def aggregate(runs: list[dict]) -> dict:
    out = {}
    for label in SIZES:
        rows = [r[label] for r in runs if label in r]
        if not rows:
            continue
        agg = {}
        for k in ("p50_us", "p99_us", "msgs_per_s", "mb_per_s", "delivered"):
            vals = [row[k] for row in rows if k in row]
            if vals:
                agg[k] = statistics.median(vals)
        agg["max_us"] = max((row.get("max_us", 0.0) for row in rows), default=0.0)
        agg["ping_lost"] = sum(row.get("ping_lost", 0) for row in rows)
        agg["all"] = rows
        out[label] = agg
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--json", type=Path, default=RESULTS / "bridges.json")
    ap.add_argument("--quick", action="store_true", help="a smoke test of a few seconds")
    ap.add_argument("--cases", default=",".join(CASES), help=f"comma-separated subset of {','.join(CASES)}")
    args = ap.parse_args(argv)
    if args.quick:
        args.repeats = 1
    pings = {"200 B": 200 if args.quick else 2000, "frame": 10 if args.quick else 100}
    floods = {"200 B": 500 if args.quick else 5000, "frame": 5 if args.quick else 50}
    cases = [c for c in args.cases.split(",") if c]
    import importlib.metadata as md

    info = machine_info(zenoh=md.version("eclipse-zenoh"))
    print(f"bridge transports: {args.repeats} repeat(s); pings {pings}, floods {floods}")
    print(f"machine: {info['platform']}, {info['cpu_count']} CPUs, Python {info['python']}, zenoh {info['zenoh']}")
    t_start = time.perf_counter()
    runs: dict[str, list[dict]] = {c: [] for c in cases}
    for r in range(args.repeats):
        for case in cases:  # interleaved, so a noisy neighbour hurts every case alike
            runs[case].append(run_floor(pings, floods) if case == "floor" else run_bus_case(case, pings, floods))
        print(f"  repeat {r + 1}/{args.repeats} done ({time.perf_counter() - t_start:.0f} s)", flush=True)
    results = {case: aggregate(rs) for case, rs in runs.items()}
    print()
    print("one-way latency = RTT/2 of an echo between two processes (µs); throughput publisher -> subscriber;")
    print("medians over repeats (max: largest); ratio = p50 / floor p50 of the same size")
    head = (f"{'size':<6} {'case':<8} {'p50 µs':>9} {'p99 µs':>9} {'max µs':>9} {'ratio':>6} "
            f"{'msg/s':>10} {'MB/s':>8} {'deliv':>6}")
    print(head)
    print("-" * len(head))
    for label in SIZES:
        floor = results.get("floor", {}).get(label, {}).get("p50_us")
        for case in cases:
            row = results[case].get(label)
            if not row or "p50_us" not in row:
                continue
            ratio = f"{row['p50_us'] / floor:6.1f}" if floor else "     -"
            print(f"{label:<6} {case:<8} {row['p50_us']:9.1f} {row['p99_us']:9.1f} {row['max_us']:9.1f} {ratio} "
                  f"{row.get('msgs_per_s', 0):10.0f} {row.get('mb_per_s', 0):8.1f} {row.get('delivered', 0):6.2f}")
    lockstep = bench_lockstep(tuple(c for c in cases if c in ("zenoh", "udp")), quick=args.quick)
    print_lockstep(lockstep)
    report = {"benchmark": "bridges", "machine": info, "repeats": args.repeats, "pings": pings, "floods": floods,
              "floor": {"200 B": "UDP datagram ping-pong", "frame": "TCP with a 5-byte length prefix"},
              "results": results, "lockstep": lockstep, "runtime_s": time.perf_counter() - t_start}
    write_report(args.json, report)
    return 0


if __name__ == "__main__":
    sys.exit(main())
