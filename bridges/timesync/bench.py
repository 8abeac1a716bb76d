"""How fast lockstep can go: ticks per second with N echo participants on a transport.

Each tick is a full round: the master publishes tick k, every participant
receives it and acknowledges, the master receives all N acks. On `memory`
the participants are threads of this process (it measures the protocol and
the GIL); on `udp` and `zenoh` they are separate `echo_participant`
processes, as a real deployment would have them. benchmarks/bridges.py
calls `lockstep_ticks_per_second` and prints the table.
"""
from __future__ import annotations

import os
import socket
import subprocess
import sys
import threading
import time
import uuid
from typing import Any

from bridges.timesync.coordinator import Coordinator, Expected
from bridges.timesync.participant import Participant


def free_tcp_port(host: str = "127.0.0.1") -> int:
    with socket.socket() as s:
        s.bind((host, 0))
        return s.getsockname()[1]


def default_options(backend: str) -> dict[str, Any]:
    """Bus options that keep a benchmark on loopback and apart from other runs."""
    if backend == "zenoh":
        return {"listen": [f"tcp/127.0.0.1:{free_tcp_port()}"]}
    return {}


def lockstep_ticks_per_second(n_participants: int, backend: str, *, seconds: float = 2.0,
                              options: dict[str, Any] | None = None) -> float:
    """Completed lockstep ticks per wall second with `n_participants` echo participants."""
    return bench_lockstep(n_participants, backend, seconds=seconds, options=options)["ticks_per_s"]


def bench_lockstep(n_participants: int, backend: str, *, seconds: float = 2.0,
                   options: dict[str, Any] | None = None) -> dict[str, Any]:
    from bridges.transport import open_bus

    prefix = f"v2i/bench-{uuid.uuid4().hex[:8]}"
    options = dict(default_options(backend) if options is None else options)
    names = [f"p{i}" for i in range(n_participants)]
    bus = open_bus(backend, prefix=prefix, sender="master", **options)
    coord = Coordinator(bus, [Expected(n, timeout_s=10.0) for n in names])
    coord.start()
    stop = []
    try:
        if backend == "memory":
            stop = [_thread_participant(backend, prefix, options, n) for n in names]
        else:
            stop = [_process_participant(backend, prefix, options, n) for n in names]
        coord.wait_for_participants(30.0)
        for k in range(20):  # warm-up
            coord.tick(k, k * 0.01, 0.01)
        k, t0 = 20, time.perf_counter()
        while (elapsed := time.perf_counter() - t0) < seconds:
            coord.tick(k, k * 0.01, 0.01)
            k += 1
        ticks = k - 20
        return {"backend": backend, "participants": n_participants, "ticks": ticks, "seconds": elapsed,
                "ticks_per_s": ticks / elapsed, "tick_resends": coord.resends}
    finally:
        coord.end("completed")
        for s in stop:
            s()
        coord.close()
        bus.close()


def _thread_participant(backend, prefix, options, name):
    from bridges.transport import open_bus

    bus = open_bus(backend, prefix=prefix, sender=name, **options)
    p = Participant(bus, name, "echo")

    def run():
        p.join(10)
        for tick in p.ticks():
            p.ack(tick)

    th = threading.Thread(target=run, daemon=True)
    th.start()

    def stop():
        th.join(5)
        p.close()
        bus.close()
    return stop


def _process_participant(backend, prefix, options, name):
    import json

    opts = dict(options)
    listen = opts.pop("listen", [])
    connect = opts.pop("connect", []) or [e.replace("0.0.0.0", "127.0.0.1") for e in listen]
    env = dict(os.environ, V2I_BUS=backend, V2I_PREFIX=prefix, V2I_CONNECT=",".join(connect),
               V2I_BUS_OPTIONS=json.dumps(opts), V2I_NAME=name, V2I_ROLE="echo")
    proc = subprocess.Popen([sys.executable, "-m", "bridges.timesync.echo_participant"], env=env,
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)

    def stop():
        try:
            proc.wait(5)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
    return stop


if __name__ == "__main__":  # python -m bridges.timesync.bench [backend ...]
    for backend in sys.argv[1:] or ["memory", "udp", "zenoh"]:
        for n in (1, 2, 8):
            r = bench_lockstep(n, backend)
            print(f"{backend:7s} {n} participant(s): {r['ticks_per_s']:8.0f} ticks/s  (resends {r['tick_resends']})")
