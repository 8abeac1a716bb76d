"""`v2i sweep SWEEP.toml`: every point of a sweep a full `v2i run`, one table of their metrics, plots.

    v2i sweep scenarios/sweeps/radio_loss.toml --jobs 2                 # local pool of 2
    v2i sweep scenarios/sweeps/radio_loss.toml --engine ray --address auto   # a Ray cluster
    v2i sweep scenarios/sweeps/radio_loss.toml --dry-run               # list the points only

The sweep folder (`--out`, default runs/sweeps/<sweep name>) holds one run
folder per point (named from its parameters and id), `points.jsonl` (each
finished attempt, as it finishes), `sweep.csv` and `sweep.parquet` (one row per
point: parameters, status, error, every metric), the plots the file asks for,
`dse.md` for a DSE sweep, `summary.json` and `summary.md`.

Run the same command again to resume: points already `ok` are skipped, failed
ones run again. A failed point (bad override, run error, timeout, lost worker)
is recorded with the end of its output and never stops the others. Exit codes:
0 every point ok, 1 some point failed, 2 a bad sweep file or arguments.
"""
from __future__ import annotations

import json
import os
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from master.sweep.point import PointTask, run_point
from master.sweep.spec import Point, SweepError, SweepSpec, load_sweep
from master.sweep.table import Ledger, rows, write_table

DEFAULT_ROOT = Path("runs") / "sweeps"


@dataclass
class SweepResult:
    folder: Path
    points: list[Point]
    table: list[dict[str, Any]]
    ran: int = 0  # points run by this invocation
    skipped: int = 0  # points finished by an earlier one
    wall_s: float = 0.0
    engine: str = ""
    outputs: list[Path] = field(default_factory=list)

    @property
    def ok(self) -> int:
        return sum(1 for r in self.table if r["status"] == "ok")

    @property
    def failed(self) -> list[dict[str, Any]]:
        return [r for r in self.table if r["status"] == "failed"]

    @property
    def collisions(self) -> int:
        return sum(1 for r in self.table if r["status"] == "ok" and r.get("collision") is True)

    @property
    def points_per_hour(self) -> float | None:
        return self.ran / self.wall_s * 3600.0 if self.ran and self.wall_s > 0 else None


def sweep_folder(spec: SweepSpec, out: str | os.PathLike | None) -> Path:
    return Path(out) if out else DEFAULT_ROOT / spec.name


def tasks_for(spec: SweepSpec, points: list[Point], folder: Path) -> list[PointTask]:
    from master.scenario.loader import fmu_search_dir

    env = {"V2I_FMU_DIR": str(fmu_search_dir().resolve())}  # the workers may start elsewhere
    return [PointTask(p.id, str(spec.base), [o.text for o in p.overrides], str((folder / p.folder).resolve()),
                      spec.name, os.getcwd(), spec.timeout_s, spec.report, env) for p in points]


def run_sweep(spec: SweepSpec, folder: Path, engine: str = "local", jobs: int = 1, address: str | None = None,
              quiet: bool = False) -> SweepResult:
    """Run the points not finished yet, then write the table, plots and summary (ScenarioError when the base
    scenario with the [sweep.set] values does not load: no point could run)."""
    prepare(spec)
    folder.mkdir(parents=True, exist_ok=True)
    points = spec.points()
    _write_definition(spec, points, folder)
    ledger = Ledger(folder)
    finished = ledger.finished()
    todo = [p for p in points if p.id not in finished]
    result = SweepResult(folder, points, [], skipped=len(points) - len(todo))
    interrupted = False
    if todo:
        result.engine, interrupted = _run_points(spec, todo, folder, ledger, result, engine, jobs, address, quiet)
    else:
        result.engine = "none (every point finished earlier)"
    result.table = rows(points, ledger.latest())
    result.outputs = write_outputs(spec, result)
    if interrupted:
        raise KeyboardInterrupt
    return result


def prepare(spec: SweepSpec) -> None:
    """Load the base with the sweep's constant overrides (a bad base fails the sweep before any point), and
    make the scenario's credentials once here ([pki]): points running side by side would race to make them."""
    from master.scenario.loader import load_scenario

    scenario = load_scenario(spec.base, list(spec.constants))
    if scenario.pki is not None:
        from master.scenario.pki import ensure

        ensure(scenario.pki)


def check_points(spec: SweepSpec, points: list[Point]) -> dict[str, str]:
    """point id -> why its scenario does not load (each point's overrides over the base, validated)."""
    from master.errors import ScenarioError
    from master.scenario.loader import load_scenario

    bad = {}
    for p in points:
        try:
            load_scenario(spec.base, list(p.overrides))
        except ScenarioError as exc:
            bad[p.id] = "; ".join(exc.problems)
    return bad


def _run_points(spec: SweepSpec, todo: list[Point], folder: Path, ledger: Ledger, result: SweepResult, engine: str,
                jobs: int, address: str | None, quiet: bool) -> tuple[str, bool]:
    """Run `todo` on the engine, each outcome into the ledger as it comes: (the engine's description,
    whether Ctrl-C ended it)."""
    from tqdm import tqdm

    from master.sweep.engines import open_engine

    by_id = {p.id: p for p in todo}
    wall0 = time.perf_counter()
    interrupted = False
    with open_engine(engine, jobs=jobs, address=address, cpus_per_point=spec.cpus_per_point) as eng:
        bar = tqdm(total=len(result.points), initial=result.skipped, unit="point", disable=quiet, desc=spec.name,
                   dynamic_ncols=True)
        counts = {"ok": 0, "failed": 0, "collisions": 0}
        try:
            for task, outcome, error in eng.map(run_point, tasks_for(spec, todo, folder)):
                if error is not None:
                    outcome = {"id": task.point_id, "run_dir": task.run_dir, "status": "failed",
                               "error": f"the engine lost the point: {type(error).__name__}: {error}",
                               "metrics": None}
                point = by_id[outcome["id"]]
                ledger.append({**outcome, "folder": point.folder, "labels": point.labels, "engine": eng.name})
                result.ran += 1
                counts[outcome["status"]] = counts.get(outcome["status"], 0) + 1
                counts["collisions"] += bool((outcome.get("metrics") or {}).get("collision"))
                bar.set_postfix(counts, refresh=False)
                bar.update(1)
                if outcome["status"] != "ok" and not quiet:
                    bar.write(f"  failed: {point.describe()}: {str(outcome.get('error')).splitlines()[-1]}")
        except KeyboardInterrupt:  # Ctrl-C reached the running points too; keep what finished, then say so
            interrupted = True
        finally:
            bar.close()
            result.wall_s = time.perf_counter() - wall0
        return eng.describe(), interrupted


def write_outputs(spec: SweepSpec, result: SweepResult) -> list[Path]:
    """The table, the plots and the DSE table from what the ledger holds (also after an interrupted sweep)."""
    out = write_table(result.folder, result.table, result.points)
    try:
        from master.sweep.plots import write_plots

        out += write_plots(spec, result.points, result.table, result.folder)
    except Exception as exc:  # noqa: BLE001 -- a plot never costs the table; say why and go on
        print(f"  plots: not written ({type(exc).__name__}: {exc})", file=sys.stderr)
    if spec.dse:
        from master.sweep.dse import write_dse

        out.append(write_dse(spec, result.points, result.table, result.folder))
    summary = summarize(spec, result)
    (result.folder / "summary.json").write_text(json.dumps(summary, indent=2, default=str) + "\n")
    (result.folder / "summary.md").write_text(format_summary(spec, result, summary) + "\n")
    return out + [result.folder / "summary.json", result.folder / "summary.md"]


def _write_definition(spec: SweepSpec, points: list[Point], folder: Path) -> None:
    """sweep.points.json: what each point's folder was run with (the sweep file as it was, resolved)."""
    doc = {"sweep": str(spec.path.resolve()), "name": spec.name, "base": str(spec.base), "combine": spec.combine,
           "axes": [{"name": a.name, "key": a.key, "labels": list(a.labels), "group": a.group} for a in spec.axes],
           "points": [{"id": p.id, "folder": p.folder, "labels": p.labels,
                       "overrides": [o.text for o in p.overrides]} for p in points]}
    (folder / "sweep.points.json").write_text(json.dumps(doc, indent=2, default=str) + "\n")


# -- summary ------------------------------------------------------------------------------------------------
def safe_limits(spec: SweepSpec, result: SweepResult) -> dict[str, Any] | None:
    """[sweep.summary] safe_limit = AXIS: for each combination of the other axes, the largest value of AXIS
    up to which every point ran and none collided (None: the first value already collides or failed)."""
    name = spec.summary.get("safe_limit")
    if not name:
        return None
    axis = spec.axis(name)
    order = {label: i for i, label in enumerate(axis.labels)}
    groups: dict[str, list[tuple[int, dict[str, Any]]]] = {}
    for p, row in zip(result.points, result.table):
        rest = ", ".join(f"{k}={v}" for k, v in p.labels.items() if k != name) or "all"
        groups.setdefault(rest, []).append((order[p.labels[name]], row))
    out: dict[str, Any] = {}
    for rest, items in groups.items():
        limit = None
        for i, row in sorted(items, key=lambda item: item[0]):
            if row["status"] != "ok" or row.get("collision") is not False:
                break
            limit = axis.column(i)
        out[rest] = limit
    return out


def summarize(spec: SweepSpec, result: SweepResult) -> dict[str, Any]:
    return {"sweep": spec.name, "points": len(result.points), "ok": result.ok, "failed": len(result.failed),
            "pending": sum(1 for r in result.table if r["status"] == "pending"), "skipped": result.skipped,
            "ran": result.ran, "collisions": result.collisions, "wall_s": round(result.wall_s, 3),
            "points_per_hour": result.points_per_hour, "engine": result.engine,
            "mean_point_wall_s": _mean([r["wall_s"] for r in result.table if r.get("wall_s") is not None]),
            "safe_limit": {"axis": spec.summary.get("safe_limit"), "limits": safe_limits(spec, result)}
            if spec.summary.get("safe_limit") else None,
            "failed_points": [{"folder": r["folder"], "error": r["error"]} for r in result.failed]}


def _mean(values: list[float]) -> float | None:
    return sum(values) / len(values) if values else None


def format_summary(spec: SweepSpec, result: SweepResult, summary: dict[str, Any] | None = None) -> str:
    s = summary or summarize(spec, result)
    pph = s["points_per_hour"]
    lines = [f"sweep {spec.name}: {s['points']} points — {s['ok']} ok, {s['failed']} failed"
             + (f", {s['pending']} not run" if s["pending"] else "")
             + f" ({s['ran']} run now, {s['skipped']} finished earlier); {s['collisions']} collision(s)",
             f"  engine: {s['engine']}; wall {s['wall_s']:.1f} s"
             + (f", {pph:.1f} points/hour" if pph else "")
             + (f"; mean point {s['mean_point_wall_s']:.1f} s" if s["mean_point_wall_s"] else ""),
             f"  folder: {result.folder}"]
    lines += [f"  wrote: {p.name}" for p in result.outputs if p.name not in ("summary.json", "summary.md")]
    for failed in s["failed_points"]:
        lines.append(f"  failed: {failed['folder']}: {str(failed['error']).splitlines()[-1]}")
    if s.get("safe_limit"):
        axis = s["safe_limit"]["axis"]
        for rest, limit in s["safe_limit"]["limits"].items():
            lines.append(f"  largest {axis} with no collision ({rest}): "
                         + ("none (the first value collides or failed)" if limit is None else f"{limit}"))
    return "\n".join(lines)


# -- the command ------------------------------------------------------------------------------------------
def add_parser(sub) -> None:
    p = sub.add_parser("sweep", help="run a sweep: every point a full run, one table (CSV, Parquet), plots",
                       description=__doc__.split("\n\n")[0])
    p.add_argument("file", help="the sweep file (scenarios/sweeps/*.toml)")
    p.add_argument("--jobs", type=int, default=1, help="points at once (local engine; ray: the CPUs of a local "
                                                       "Ray instance) (default 1)")
    p.add_argument("--engine", default="local", help="local (default: a pool on this machine) or ray")
    p.add_argument("--address", help="ray: the cluster to join (auto, or HOST:PORT of `ray start --head`); "
                                     "without it a local Ray instance")
    p.add_argument("--out", help="the sweep folder (default runs/sweeps/<sweep name>); rerun to resume")
    p.add_argument("--dry-run", action="store_true", help="list the points and their folders, run nothing")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=_cmd_sweep)


def _cmd_sweep(args) -> int:
    from master.errors import ScenarioError
    from master.sweep.dse import check_dse
    from master.sweep.engines import ENGINES

    try:
        spec = load_sweep(args.file)
        problems = check_dse(spec)
        if problems:
            raise SweepError(args.file, problems)
    except SweepError as exc:
        print(exc, file=sys.stderr)
        return 2
    if args.jobs < 1:
        print(f"error: --jobs must be >= 1, got {args.jobs}", file=sys.stderr)
        return 2
    if args.engine not in ENGINES:
        print(f"error: --engine: unknown engine {args.engine!r} (engines: {', '.join(ENGINES)})", file=sys.stderr)
        return 2
    folder = sweep_folder(spec, args.out)
    if args.dry_run:  # each point's scenario is loaded and checked, nothing runs
        points = spec.points()
        finished, bad = Ledger(folder).finished(), check_points(spec, points)
        for p in points:
            state = "invalid" if p.id in bad else "done" if p.id in finished else "todo"
            print(f"{p.index:4d} {state:7s} {p.folder}  " + " ".join(o.text for o in p.overrides))
            if p.id in bad:
                print(f"       {bad[p.id]}")
        print(f"{len(points)} points: {len(points) - len(bad)} load, {len(bad)} do not; "
              f"{sum(p.id in finished for p in points)} finished in {folder}")
        return 2 if bad else 0
    try:
        result = run_sweep(spec, folder, args.engine, args.jobs, args.address, args.quiet)
    except ScenarioError as exc:  # the base with [sweep.set] does not load
        print(exc, file=sys.stderr)
        return 2
    except ValueError as exc:  # e.g. --address with the local engine
        print(f"error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"\ninterrupted: finished points are in {folder / 'points.jsonl'}; run the same command to resume",
              file=sys.stderr)
        return 1
    print(format_summary(spec, result))
    return 1 if result.failed else 0

