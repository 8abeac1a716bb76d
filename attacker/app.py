"""The attacker as a process: joins the run, hears the air, transmits its attacks. The thin shell.

1. check the configuration and make the keys the configured attacks need (a
   problem is a ConfigError, exit 2);
2. open the bus (V2I_* from the master, or flags), subscribe to
   `v2x/rx/<station>` (what its radio hears), join as a participant;
3. lockstep: at each tick of time t, hand what was heard up to t to the core,
   publish the frames due in [t, t + the tick period) on `v2x/tx/<station>`,
   each at its own simulation time (the air puts it on the channel then), and
   acknowledge; realtime: the same on the simulation time read off the
   master's clock, each frame stamped when it goes out;
4. at the end: one JSON summary line on stdout (what was sent, per attack).

Replays carry only the bytes heard: the trace stamps that rode with the
genuine frame on the bus are the simulator's bookkeeping, not on the air.
"""
from __future__ import annotations

import json
import logging
import signal
import sys
import threading
import time
import traceback
from pathlib import Path
from typing import Any

from bridges.geo import GeoOrigin
from bridges.timesync.errors import TimeSyncError
from bridges.timesync.exits import EXIT_CONFIG, EXIT_ERROR, EXIT_OK, SESSION_ERRORS, session_end
from bridges.timesync.participant import Participant, bus_from_env
from bridges.v2x import EPOCH, rx_key, tx_key

from attacker.attacks import Context
from attacker.config import AttackerConfig, ConfigError
from attacker.core import AttackerCore
from attacker.credentials import CredentialError, rogue_station, signed_by, stolen_expired, unsigned

log = logging.getLogger("attacker")



class Terminated(Exception):
    """SIGTERM: finish with the summary."""


def make_envelopes(cfg: AttackerConfig, notes: list[str]) -> dict[str, Any]:
    """The envelopes the configured attacks use; ConfigError naming keys.* when the keys cannot be had."""
    needed = cfg.envelopes_needed()
    out: dict[str, Any] = {"unsigned": unsigned}
    if "untrusted" in needed:
        out["untrusted"] = signed_by(rogue_station())
    if "expired" in needed:
        try:
            stolen = stolen_expired(Path(cfg.keys.stolen_dir), Path(cfg.keys.pki_dir) if cfg.keys.pki_dir else None)
        except CredentialError as exc:
            raise ConfigError([(exc.key, exc.reason)]) from None
        if stolen.made:
            notes.append(f"issued the expired certificate {str(cfg.keys.stolen_dir)!r} from the scenario CA's past")
        out["expired"] = signed_by(stolen.credentials)
    return out


class AttackerApp:
    def __init__(self, cfg: AttackerConfig):
        self.cfg = cfg
        self.name, self.station = cfg.app.name, cfg.app.station
        self.notes: list[str] = []
        self.envelopes = make_envelopes(cfg, self.notes)
        self.bus = self.part = self.core = None
        self._sub = None
        self._inbox: list[tuple[float, int, bytes]] = []
        self._lock = threading.Lock()
        self._order = 0
        self.ticks = 0
        self.published = self.publish_errors = 0
        self.t_sim = float("nan")
        self.ended = None
        self.exit_reason = ""
        self._frame_log = None

    # -- running ----------------------------------------------------------------------------------------
    def run(self) -> int:
        c = self.cfg
        try:
            self.bus = bus_from_env(self.name, transport=c.bus.transport or None, prefix=c.bus.prefix or None,
                                    connect=",".join(c.bus.connect) or None)
        except (TimeSyncError, ValueError, OSError) as exc:
            print(f"attacker: bus: {exc}", file=sys.stderr)
            return EXIT_CONFIG
        except Exception as exc:  # TransportError (unknown option, port taken...)
            print(f"attacker: bus: cannot open it: {exc}", file=sys.stderr)
            return EXIT_CONFIG
        code = EXIT_OK
        previous = signal.signal(signal.SIGTERM, self._on_sigterm)
        try:
            if c.app.frame_log:
                self._frame_log = open(c.app.frame_log, "w", buffering=1)
            self._sub = self.bus.subscribe(rx_key(self.station), self._heard)
            self.part = Participant(self.bus, self.name, c.app.role, publishes=[tx_key(self.station)])
            welcome = self.part.join(timeout=c.app.join_timeout_s)
            world = self.part.world
            epoch = world.get(EPOCH)
            if epoch is None:
                epoch = time.time()
                self.notes.append("the master sent no epoch_unix_s: simulation time 0 = this app's join")
            origin = self.part.origin or GeoOrigin()
            ctx = Context(origin, float(epoch), c.app.seed, self.envelopes)
            self.core = AttackerCore.build([(a.label, a.kind, a.params) for a in c.attacks], ctx)
            if welcome.mode == "lockstep":
                self._lockstep()
            else:
                self._realtime()
            self.ended = self.part.ended.status if self.part.ended else None
            self.exit_reason = f"the run ended ({self.ended})"
        except SESSION_ERRORS as exc:
            print(f"attacker: {exc}", file=sys.stderr)
            code, self.exit_reason = session_end(exc)
        except (Terminated, KeyboardInterrupt):
            self.exit_reason = "terminated by signal"
            if self.part is not None and self.part.welcome is not None and self.part.ended is None:
                try:
                    self.part.leave("terminated by signal")
                except Exception as exc:  # the bus may be gone
                    log.debug("leave: %s", exc)
        except OSError as exc:  # the frame log cannot be written
            print(f"attacker: {exc}", file=sys.stderr)
            code, self.exit_reason = EXIT_CONFIG, str(exc)
        except Exception as exc:  # a bug of ours: say so with the traceback, still summarise
            traceback.print_exc()
            code, self.exit_reason = EXIT_ERROR, f"internal error: {type(exc).__name__}: {exc}"
        finally:
            signal.signal(signal.SIGTERM, previous)
            summary = self.summary()
            self._close()
            print(json.dumps(summary), flush=True)
        return code

    def _on_sigterm(self, signum, frame):
        raise Terminated()

    def _heard(self, msg) -> None:
        with self._lock:
            self._order += 1
            self._inbox.append((msg.t_sim, self._order, bytes(msg.payload)))

    def _take(self, t: float) -> list[tuple[float, int, bytes]]:
        """What was heard up to t (everything when t is infinite), in arrival order."""
        with self._lock:
            items = [i for i in self._inbox if i[0] <= t + 1e-9]
            self._inbox = [i for i in self._inbox if i[0] > t + 1e-9]
        return sorted(items)

    def _lockstep(self) -> None:
        period_steps = max(1, int(self.part.welcome.sync_every or 1))
        for tick in self.part.ticks():
            c0 = time.perf_counter()
            self.t_sim = tick.t
            for t_arrival, _, payload in self._take(tick.t):
                self.core.hear(payload, t_arrival)
            step = float(tick.step or 0.0)
            t1 = tick.t + step * period_steps if step > 0 else tick.t + 1e-3
            self._publish(self.core.step(tick.t, t1))
            self.part.ack(tick, time.perf_counter() - c0)
            self.ticks += 1

    def _realtime(self) -> None:
        t_done = None
        while True:
            tick = self.part.next_tick(timeout=0.005)
            if tick is None and self.part.ended is not None:
                return
            try:
                now = self.part.sim_time_now()
            except TimeSyncError:
                continue  # no time mapping from the master yet
            self.t_sim = now
            for t_arrival, _, payload in self._take(now):
                self.core.hear(payload, t_arrival)
            t0 = now if t_done is None else t_done
            frames = self.core.step(t0, now + 1e-6)
            for f in frames:
                f.t = max(f.t, now)  # realtime: it goes out now
            self._publish(frames)
            t_done = now + 1e-6
            self.ticks += tick is not None

    def _publish(self, frames) -> None:
        key = tx_key(self.station)
        for f in frames:
            try:
                seq = self.bus.publish(key, f.payload, f.t)
                self.published += 1
            except Exception as exc:  # a closed or broken bus: count, keep the run going
                self.publish_errors += 1
                log.warning("could not publish on %s: %s", key, exc)
                continue
            if self._frame_log is not None:
                self._frame_log.write(json.dumps({"seq": seq, "t": f.t, "attack": f.attack,
                                                  "bytes": len(f.payload)}) + "\n")

    def _close(self) -> None:
        for thing in (self._sub, self.part):
            if thing is not None:
                try:
                    thing.close()
                except Exception as exc:
                    log.debug("closing %r: %s", thing, exc)
        if self._frame_log is not None:
            self._frame_log.close()
        if self.bus is not None:
            try:
                self.bus.close()
            except Exception as exc:
                log.debug("closing the bus: %s", exc)

    def summary(self) -> dict[str, Any]:
        out: dict[str, Any] = {"app": "attacker", "name": self.name, "station": self.station,
                               "exit": self.exit_reason, "end": self.ended, "ticks": self.ticks,
                               "published": self.published, "publish_errors": self.publish_errors,
                               "notes": self.notes}
        if self.part is not None and self.part.welcome is not None:
            out["mode"] = self.part.welcome.mode
        if self.core is not None:
            out["sent"] = dict(self.core.sent)
            out["heard"] = self.core.heard
            out["attacks"] = self.core.summary()
        return out
