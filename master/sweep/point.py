"""One point of a sweep: a full `v2i run` of the base scenario with the point's overrides, in its own folder.

`run_point(task)` is what every engine runs, on whichever machine it lands:
it gives the point its own ports and bus prefix there, starts `v2i run` as a
child process (a crashed or hung point cannot take the sweep with it), and returns a plain dict (the
table's row material: status, error, wall time, the run's metrics.json) that
pickles through a process pool or Ray alike.

Ports. Every port the scenario fixes is replaced, per point, by one that is free
on the machine running it, so points side by side never share a bus: the
master's zenoh endpoints (`[bridge] listen`), the UDP transport's `[bridge]
port`, the CAN bus's `[can] port` (udp_multicast; set even when the file leaves
it at the default) and serial ports with a fixed `listen` port. An app that
must know a port gets it from the scenario (`"--can-port", "{can.port}"` in its
command, master.links.participants), so it follows. Each point also gets its own
`[bridge] prefix`, v2i/sweep/<sweep>/<point id>.
"""
from __future__ import annotations

import json
import os
import platform
import re
import shutil
import socket
import subprocess
import sys
import threading
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

from master.scenario.overrides import Override, apply_overrides, override, parse_override

ERROR_LINES = 6  # of a failed point's output, kept as its error
TERM_GRACE_S = 15.0  # wall seconds a timed-out point gets to stop after SIGTERM
_ENDPOINT = re.compile(r"^(?P<proto>[a-z0-9]+)/(?P<host>.+):(?P<port>\d+)$")
_SOCKET_URL = re.compile(r"^(?P<scheme>socket://)(?P<host>.+):(?P<port>\d+)$")
_given_ports: set[tuple[int, int]] = set()  # (socket type, port) handed out by this process: never twice
_ports_lock = threading.Lock()


@dataclass
class PointTask:
    """Everything a worker needs to run a point (plain values: it crosses process and machine borders)."""

    point_id: str
    base: str  # absolute path of the base scenario
    overrides: list[str]  # KEY=VALUE texts, [sweep.set] first
    run_dir: str  # absolute
    sweep_name: str
    cwd: str  # where `v2i run` starts (relative FMU and output paths are read from there)
    timeout_s: float = 1800.0
    report: bool = False
    env: dict[str, str] = field(default_factory=dict)

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


def run_point(task: PointTask | dict[str, Any]) -> dict[str, Any]:
    """Run one point; never raises for the point's own failure (the dict says `status` failed and why)."""
    if isinstance(task, dict):
        task = PointTask(**task)
    started = time.time()
    out: dict[str, Any] = {"id": task.point_id, "run_dir": task.run_dir, "host": socket.gethostname(),
                           "cpu": cpu_model(), "started": started}
    try:
        extra = per_point_overrides(Path(task.base), task.overrides, task.sweep_name, task.point_id)
    except Exception as exc:  # noqa: BLE001 -- the base or an override is bad: this point fails, not the sweep
        return {**out, "status": "failed", "error": f"{type(exc).__name__}: {exc}", "wall_s": time.time() - started,
                "metrics": None}
    run_dir = Path(task.run_dir)
    if run_dir.exists():  # what an earlier, failed attempt left: a point is run from scratch
        shutil.rmtree(run_dir)
    run_dir.parent.mkdir(parents=True, exist_ok=True)
    argv = [sys.executable, "-m", "master.cli", "run", task.base]
    for item in [*task.overrides, *(o.text for o in extra)]:
        argv += ["--set", item]
    argv += ["--out", str(run_dir), "--quiet"]
    if not task.report:
        argv.append("--no-report")
    env = {**os.environ, **task.env}
    cwd = task.cwd if Path(task.cwd).is_dir() else None  # another machine may not have the driver's folder
    try:
        rc, output, timed_out = _run(argv, cwd, env, task.timeout_s)
    except OSError as exc:
        return {**out, "status": "failed", "error": f"cannot start v2i run: {exc}", "wall_s": time.time() - started,
                "metrics": None}
    wall = time.time() - started
    run_dir.mkdir(parents=True, exist_ok=True)
    (run_dir / "sweep-point.log").write_text(" ".join(argv) + "\n\n" + output)
    metrics = _read_json(run_dir / "metrics.json")
    meta = _read_json(run_dir / "metadata.json") or {}
    out.update(wall_s=wall, metrics=metrics, run_status=meta.get("status"), ports=[o.text for o in extra])
    if timed_out:
        return {**out, "status": "failed", "error": f"timed out after {task.timeout_s:g} s (killed)"}
    if rc != 0:
        return {**out, "status": "failed", "error": f"v2i run exited {rc}: {last_lines(output)}"}
    return {**out, "status": "ok", "error": None}


def _run(argv: list[str], cwd: str | None, env: dict[str, str], timeout_s: float) -> tuple[int | None, str, bool]:
    """(exit code, output, timed out). A point past its time gets SIGTERM, which `v2i run` answers like
    Ctrl-C (it records what it has and stops its apps), then SIGKILL. The child stays in our process
    group, so Ctrl-C on the sweep reaches every running point the same way."""
    proc = subprocess.Popen(argv, cwd=cwd, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                            stdin=subprocess.DEVNULL)
    try:
        output, _ = proc.communicate(timeout=timeout_s)
        return proc.returncode, output.decode(errors="replace"), False
    except subprocess.TimeoutExpired:
        proc.terminate()
        try:
            output, _ = proc.communicate(timeout=TERM_GRACE_S)
        except subprocess.TimeoutExpired:
            proc.kill()
            output, _ = proc.communicate()
        return proc.returncode, output.decode(errors="replace"), True


def last_lines(text: str, n: int = ERROR_LINES) -> str:
    """The last n non-empty lines of a failed point's output (its error message is among them)."""
    lines = [ln.rstrip() for ln in text.splitlines() if ln.strip()]
    return "\n".join(lines[-n:]) or "(no output)"


def _read_json(path: Path) -> Any:
    try:
        return json.loads(path.read_text())
    except (OSError, ValueError):
        return None


def cpu_model() -> str:
    """The processor's model name and this machine's core count (for the DSE table's 'this CPU')."""
    name = platform.processor() or platform.machine()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                name = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    return f"{name}, {os.cpu_count()} cores"


# -- ports and prefix -----------------------------------------------------------------------------------
def per_point_overrides(base: Path, overrides: list[str], sweep_name: str, point_id: str) -> list[Override]:
    """The overrides that give this point its own ports and bus prefix, from the merged scenario."""
    from master.scenario.loader import read_raw

    raw, _ = apply_overrides(read_raw(base), [parse_override(o) for o in overrides])
    return point_ports(raw) + point_prefix(raw, sweep_name, point_id)


def point_prefix(raw: dict[str, Any], sweep_name: str, point_id: str) -> list[Override]:
    if not isinstance(raw.get("bridge"), dict):
        return []
    safe = re.sub(r"[^A-Za-z0-9_.\-]", "_", sweep_name) or "sweep"
    return [override("bridge.prefix", f"v2i/sweep/{safe}/{point_id}")]


def point_ports(raw: dict[str, Any]) -> list[Override]:
    """A free port for every port the scenario fixes (see the module's docstring)."""
    out: list[Override] = []
    bridge = raw.get("bridge")
    if isinstance(bridge, dict):
        listen = bridge.get("listen")
        if isinstance(listen, (str, list)):
            endpoints = [listen] if isinstance(listen, str) else list(listen)
            moved = [_free_endpoint(e) if isinstance(e, str) else e for e in endpoints]
            if moved != endpoints:
                out.append(override("bridge.listen", moved))
        if isinstance(bridge.get("port"), int) and bridge.get("port"):
            out.append(override("bridge.port", free_port(socket.SOCK_DGRAM)))
    can = raw.get("can")
    if isinstance(can, dict) and can.get("interface", "udp_multicast") == "udp_multicast":
        out.append(override("can.port", free_port(socket.SOCK_DGRAM)))
    serial = raw.get("serial")
    if isinstance(serial, dict):
        for name, spec in serial.items():
            url = spec.get("listen") if isinstance(spec, dict) else None
            match = _SOCKET_URL.match(url) if isinstance(url, str) else None
            if match and int(match["port"]) != 0:
                out.append(override(f"serial.{name}.listen",
                                    f"{match['scheme']}{match['host']}:{free_port(socket.SOCK_STREAM)}"))
    return out


def _free_endpoint(endpoint: str) -> str:
    match = _ENDPOINT.match(endpoint)
    if not match or int(match["port"]) == 0:
        return endpoint
    kind = socket.SOCK_DGRAM if match["proto"] in ("udp", "quic") else socket.SOCK_STREAM
    return f"{match['proto']}/{match['host']}:{free_port(kind)}"


def free_port(kind: int = socket.SOCK_STREAM) -> int:
    """A port the kernel says is free now, never one this process handed out before."""
    with _ports_lock:
        for _ in range(100):
            with socket.socket(socket.AF_INET, kind) as s:
                if kind == socket.SOCK_STREAM:
                    s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
                s.bind(("", 0))
                port = s.getsockname()[1]
            if (kind, port) not in _given_ports:
                _given_ports.add((kind, port))
                return port
    raise OSError("no free port found in 100 tries")
