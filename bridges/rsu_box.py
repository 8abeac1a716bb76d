"""An emulated roadside unit: Immediate Forward in, "radio" out to on-board units, everything logged.

    python -m bridges.rsu_box --listen 127.0.0.1:1516 --forward 127.0.0.1:47900 \\
        --delay-ms 20 --loss 0.0 --seed 1 --log box.jsonl [--obu-format ieee1609dot2]

It stands in for a real RSU and the OBUs that hear it, so a scenario that
speaks to real devices (`[v2x] mode = "rsu"`) runs with no hardware, across
network namespaces or on loopback, and runs unchanged with the devices by
changing two addresses. It listens for Immediate Forward records
(bridges.immediate_forward) like an RSU on port 1516, checks each (the record's
format, PSID against the type's table, that the payload's J2735 message is of
the record's Type and that a signed payload's PSID is the record's) and
"broadcasts" it: to each `--forward` address, after `--delay-ms` (plus a
uniform 0..`--jitter-ms`), unless lost with probability `--loss` (independently
per receiver, from `--seed`), it sends what an OBU of format `--obu-format`
forwards (bridges.obu_forward). It sends nowhere else: the forward addresses
have no default.

What goes on the emulated air: a payload that is 1609.2 data goes as it is
(signed or not); a bare MessageFrame is wrapped as unsecured 1609.2 data. A
real RSU signs a bare frame when the record says ``Signature=True``; the
emulation has no certificate, so it only logs the flag.

The log (`--log`, JSON lines) has one line per record received, refused (with
the reason), forwarded or lost, and a summary with the counts by reason; the
same summary is printed on stdout at exit. SIGTERM or SIGINT ends it cleanly
(exit 0); forwards still pending then are counted, not sent. Garbage never
ends it. The first stdout line says where it listens (``{"event": "listening",
"address": ...}``), so a caller can give port 0 and read the port.
"""
from __future__ import annotations

import argparse
import heapq
import itertools
import json
import random
import select
import signal
import statistics
import sys
import time
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, TextIO

from bridges import immediate_forward as imf
from bridges import obu_forward
from bridges.security import oer
from bridges.udp_endpoint import Endpoint, enable_rx_timestamps, parse_endpoint, recv_stamped, udp_socket

EXIT_OK, EXIT_USAGE = 0, 2


class BoxRefusal(ValueError):
    def __init__(self, reason: str, detail: str):
        super().__init__(f"{reason}: {detail}")
        self.reason = reason
        self.detail = detail


def on_the_air(record: imf.Record, routes: imf.RouteTable) -> obu_forward.OverTheAir:
    """What the emulated RSU radiates for a record; BoxRefusal when a real one should not send it."""
    if record.encryption:
        raise BoxRefusal("encryption-not-emulated", "Encryption=True: the emulated RSU cannot encrypt")
    try:
        frame, psid, signed = obu_forward.open_envelope(record.payload)
        envelope = record.payload
    except obu_forward.ForwardError:
        frame, psid, signed = record.payload, None, False
        envelope = oer.unsecured(record.payload)
    try:
        msg_id = imf.message_id(frame)
    except ValueError as exc:
        raise BoxRefusal("payload-not-j2735", str(exc)) from None
    types = {r.type for r in routes.routes if r.message_id == msg_id}
    if record.type not in types:
        raise BoxRefusal("type-mismatch", f"Type={record.type} but the payload is J2735 message {msg_id}"
                                          + (f" ({', '.join(sorted(types))})" if types else ""))
    if psid is not None and psid != record.psid_value:
        raise BoxRefusal("psid-mismatch", f"the 1609.2 header says PSID {psid:#x}, the record "
                                          f"{imf.format_psid(record.psid)} (PSID {record.psid_value:#x})")
    return obu_forward.OverTheAir(envelope, frame, record.type, record.psid, record.tx_channel, signed)


@dataclass
class BoxSettings:
    forwards: list[Endpoint]
    delay_s: float = 0.0
    jitter_s: float = 0.0
    loss: float = 0.0
    seed: int = 0
    obu_format: str = "ieee1609dot2"
    routes: imf.RouteTable = field(default_factory=imf.default_routes)


class BoxCore:
    """The box without sockets: a datagram in -> the forwards to send and when. Counts everything."""

    def __init__(self, settings: BoxSettings, log: Callable[[dict], None] | None = None):
        self.settings = settings
        self.fmt = obu_forward.get_format(settings.obu_format)
        self.rng = random.Random(settings.seed)
        self.log = log or (lambda event: None)
        self.counts: Counter = Counter()
        self.refused: Counter = Counter()
        self.types: Counter = Counter()
        self._n = itertools.count()

    def receive(self, data: bytes, source: str, now: float) -> list[tuple[float, Endpoint, bytes, int]]:
        """[(due time, forward address, datagram, record number)] for one datagram received at `now`."""
        n = next(self._n)
        self.counts["received"] += 1
        s = self.settings
        try:
            record = imf.parse(data, s.routes)
            air = on_the_air(record, s.routes)
            out = self.fmt.write(air)
        except imf.RecordError as exc:
            return self._refuse(n, source, now, exc.reason.value, exc.detail, len(data))
        except BoxRefusal as exc:
            return self._refuse(n, source, now, exc.reason, exc.detail, len(data))
        except (obu_forward.ForwardError, ValueError) as exc:  # the forward format cannot carry it
            return self._refuse(n, source, now, "forward-format", str(exc), len(data))
        self.counts["accepted"] += 1
        self.types[record.type] += 1
        self.log({"event": "received", "t": now, "n": n, "from": source, "bytes": len(data),
                  "type": record.type, "psid": imf.format_psid(record.psid), "channel": record.tx_channel,
                  "signature": record.signature, "signed": air.signed, "payload_bytes": len(record.payload)})
        sends = []
        for target in s.forwards:
            if s.loss > 0 and self.rng.random() < s.loss:
                self.counts["lost"] += 1
                self.log({"event": "lost", "t": now, "n": n, "to": str(target)})
                continue
            delay = s.delay_s + (self.rng.uniform(0.0, s.jitter_s) if s.jitter_s > 0 else 0.0)
            sends.append((now + delay, target, out, n))
        return sends

    def _refuse(self, n: int, source: str, now: float, reason: str, detail: str, size: int) -> list:
        self.counts["refused"] += 1
        self.refused[reason] += 1
        self.log({"event": "refused", "t": now, "n": n, "from": source, "bytes": size, "reason": reason,
                  "detail": detail[:300]})
        return []

    def summary(self, delays_ms: list[float], pending: int) -> dict[str, Any]:
        return {"event": "summary", **{k: self.counts.get(k, 0) for k in
                                      ("received", "accepted", "refused", "forwarded", "lost", "send_errors")},
                "refused_by_reason": dict(sorted(self.refused.items())), "types": dict(sorted(self.types.items())),
                "pending_at_exit": pending,
                "delay_ms": {"p50": statistics.median(delays_ms) if delays_ms else None,
                             "min": min(delays_ms, default=None), "max": max(delays_ms, default=None),
                             "n": len(delays_ms)}}


class _Log:
    def __init__(self, path: Path | None):
        self.file: TextIO | None = open(path, "w", buffering=1) if path else None
        self.t0 = time.time()

    def __call__(self, event: dict) -> None:
        if self.file is not None:
            if "t" in event:
                event = {**event, "t": round(event["t"] - self.t0, 6)}
            self.file.write(json.dumps(event, separators=(",", ":")) + "\n")

    def close(self) -> None:
        if self.file is not None:
            self.file.close()


def serve(listen: Endpoint, settings: BoxSettings, log: Callable[[dict], None],
          should_stop: Callable[[], bool], announce: Callable[[str], None] = lambda address: None) -> dict:
    """Receive, refuse or schedule, and send on time until `should_stop()`; returns the summary."""
    core = BoxCore(settings, log)
    oer.spec()  # compile the 1609.2 module now, not while the first record waits for its delay
    sock, _ = udp_socket(listen, bind=True)
    enable_rx_timestamps(sock)  # a record's delay counts from the kernel's receive time
    targets = {t: udp_socket(t, bind=False)[1] for t in settings.forwards}
    host, port = sock.getsockname()[:2]
    announce(str(Endpoint(host, port)))
    pending: list = []
    order = itertools.count()
    delays: list[float] = []
    try:
        while not should_stop():
            now = time.time()
            while pending and pending[0][0] <= now:
                due, _, received, target, out, n = heapq.heappop(pending)
                try:
                    sock.sendto(out, targets[target])
                except OSError as exc:
                    core.counts["send_errors"] += 1
                    log({"event": "send_error", "t": now, "n": n, "to": str(target), "error": str(exc)})
                    continue
                sent = time.time()
                core.counts["forwarded"] += 1
                delays.append((sent - received) * 1e3)
                log({"event": "forwarded", "t": sent, "n": n, "to": str(target), "bytes": len(out),
                     "delay_ms": round((sent - received) * 1e3, 3)})
            timeout = 0.2 if not pending else max(0.0, min(0.2, pending[0][0] - time.time()))
            ready, _, _ = select.select([sock], [], [], timeout)
            if not ready:
                continue
            try:
                data, source, received = recv_stamped(sock)
            except OSError as exc:  # e.g. ICMP errors surfacing on the socket: counted, never fatal
                core.counts["receive_errors"] += 1
                log({"event": "receive_error", "t": time.time(), "error": str(exc)})
                continue
            for due, target, out, n in core.receive(data, str(Endpoint(*source[:2])), received):
                heapq.heappush(pending, (due, next(order), received, target, out, n))
    finally:
        sock.close()
    summary = core.summary(delays, len(pending))
    log(summary)
    return summary


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="python -m bridges.rsu_box", description=__doc__.split("\n\n")[0])
    p.add_argument("--listen", required=True, help="HOST:PORT for Immediate Forward records (RSU default "
                                                   f"port {imf.DEFAULT_PORT}; port 0: any free port)")
    p.add_argument("--forward", action="append", required=True, metavar="HOST:PORT",
                   help="where an OBU that hears the broadcast forwards it (repeat for several OBUs)")
    p.add_argument("--delay-ms", type=float, default=0.0, help="radio delay, ms (default 0)")
    p.add_argument("--jitter-ms", type=float, default=0.0, help="plus a uniform 0..this, ms (default 0)")
    p.add_argument("--loss", type=float, default=0.0, help="probability a receiver misses a record (default 0)")
    p.add_argument("--seed", type=int, default=0, help="seed of the loss and jitter draws (default 0)")
    p.add_argument("--obu-format", default="ieee1609dot2", choices=obu_forward.formats(),
                   help="what the OBU forwards (default ieee1609dot2)")
    p.add_argument("--psid", action="append", default=[], metavar="KIND=HEX",
                   help=f"override a kind's p-encoded PSID (kinds: {', '.join(imf.DEFAULT_ROUTES.kinds)})")
    p.add_argument("--channel", type=int, default=imf.DSRC_CHANNEL,
                   help=f"the default channel of every kind (default {imf.DSRC_CHANNEL}; C-V2X {imf.CV2X_CHANNEL})")
    p.add_argument("--log", type=Path, help="JSON-lines log of every record (default: none)")
    return p


def settings_from_args(args: argparse.Namespace) -> tuple[Endpoint, BoxSettings]:
    """The listen address and settings; ValueError listing every bad argument."""
    problems = []
    listen = None
    try:
        listen = parse_endpoint(args.listen, allow_any_port=True)
    except ValueError as exc:
        problems.append(f"--listen: {exc}")
    forwards = []
    for text in args.forward:
        try:
            forwards.append(parse_endpoint(text))
        except ValueError as exc:
            problems.append(f"--forward: {exc}")
    for name, value, low, high in (("--delay-ms", args.delay_ms, 0, 60000), ("--jitter-ms", args.jitter_ms, 0, 60000),
                                   ("--loss", args.loss, 0, 1)):
        if not low <= value <= high:
            problems.append(f"{name}: expected {low}..{high}, got {value}")
    overrides: dict[str, dict] = {}
    for item in args.psid:
        kind, sep, psid = item.partition("=")
        if not sep:
            problems.append(f"--psid: expected KIND=HEX, got {item!r}")
            continue
        overrides[kind.strip()] = {"psid": psid.strip()}
    routes = imf.default_routes(args.channel) if 1 <= args.channel <= 255 else imf.default_routes()
    if not 1 <= args.channel <= 255:
        problems.append(f"--channel: expected 1..255, got {args.channel}")
    routes = routes.with_overrides(overrides, lambda key, reason: problems.append(f"--psid {key}: {reason}"))
    if problems:
        raise ValueError("\n".join(problems))
    return listen, BoxSettings(forwards, args.delay_ms / 1e3, args.jitter_ms / 1e3, args.loss, args.seed,
                               args.obu_format, routes)


def main(argv: list[str] | None = None) -> int:
    args = _parser().parse_args(argv)
    try:
        listen, settings = settings_from_args(args)
    except ValueError as exc:
        print(f"rsu_box: {exc}", file=sys.stderr)
        return EXIT_USAGE
    stop = []
    for sig in (signal.SIGTERM, signal.SIGINT):
        signal.signal(sig, lambda signum, frame: stop.append(signum))
    log = _Log(args.log)

    def announce(address: str) -> None:
        print(json.dumps({"event": "listening", "address": address,
                          "forward": [str(t) for t in settings.forwards]}), flush=True)

    try:
        summary = serve(listen, settings, log, lambda: bool(stop), announce)
    except OSError as exc:
        print(f"rsu_box: cannot listen on {listen} or reach a forward address: {exc}", file=sys.stderr)
        return EXIT_USAGE
    finally:
        log.close()
    print(json.dumps(summary), flush=True)
    return EXIT_OK


if __name__ == "__main__":
    sys.exit(main())
