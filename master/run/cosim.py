"""The co-simulation master: fixed communication steps over FMU instances, with hooks around each.

A run instantiates the scenario's FMUs, binds every observed variable to a slot
of one value table, opens the hooks (master.hooks: apps, serial and CAN
gateways, the world and its sensor streams, the V2X air, the recorder) and then,
per base step k: manipulators' before_step, the master algorithm
(master.run.algorithm: Jacobi or Gauss-Seidel), observers' after_step. Every hook
closes with the run's outcome, whatever happened, and the run folder keeps what
was recorded.
"""
from __future__ import annotations

import json
import platform
import shutil
import time
from array import array
from dataclasses import dataclass
from datetime import datetime, timezone
from operator import itemgetter
from pathlib import Path
from typing import Any

from bridges.timesync.errors import TimeSyncError
from master import __version__
from master.errors import DeadlineMissError, SimulationError
from master.run.algorithm import read_outputs, step_plan
from master.links.can_bridge import CanBridge
from master.run.collision import CollisionHook
from master.scenario.conditions import COLLISION, StopConditions
from master.fmi.runtime import FmuInstance
from master.fmi.variables import element_names
from master.hooks import Hook, Member, Outcome, RunContext, open_order, overrides
from master.run.initialization import initialize
from master.scenario.input_file import InputFiles
from master.run.interrupts import Interrupted, SignalGuard
from master.run.metrics import METRICS, run_metrics, write_metrics
from master.run.pacing import Pacer, restore_nice, set_loop_nice
from master.links.participants import ParticipantBridge, open_run_bus
from master.links.radio_bridge import RadioBridge
from master.run.recorder import METADATA, RunRecorder
from master.run.run_records import CameraArchive, TraceRecorder
from master.scenario.loader import Scenario
from master.links.serial_bridge import SerialBridges
from master.stats import percentiles
from master.links.streams import StreamsHook


@dataclass
class RunResult:
    run_dir: Path
    status: str
    metadata: dict[str, Any]
    error: str | None = None


def default_run_dir(scenario: Scenario, root: Path = Path("runs")) -> Path:
    stamp = datetime.now().strftime("%Y%m%d-%H%M%S")
    base = root / f"{scenario.name}-{stamp}"
    path, n = base, 1
    while path.exists():
        n += 1
        path = Path(f"{base}-{n}")
    return path


def connection_delays(scenario: Scenario) -> list[dict[str, Any]]:
    """The delay each connection adds under the scenario's ordering (documented in metadata)."""
    order = list(scenario.instances)
    h = scenario.time.step
    rows = []
    for conn in scenario.connections:
        src_step = scenario.instances[conn.src].step_multiple * h
        if scenario.time.ordering == "jacobi" or order.index(conn.src) >= order.index(conn.dst):
            delay = src_step
        else:
            delay = 0.0
        rows.append({"connection": str(conn), "delay_s": delay})
    return rows


class RecorderHook(Hook):
    """The last observer: the time-series row of t_next, after every other hook has acted."""

    name = "recorder"

    def __init__(self, recorder: RunRecorder, values: list[Any], slots: list[int]):
        self.recorder, self.values, self.slots = recorder, values, slots
        self._pick = _picker(slots, len(values))
        self._row = recorder.row

    def after_step(self, k: int, t_next: float) -> None:
        pick = self._pick
        self._row(t_next, pick(self.values) if pick is not None else self.values)


def _picker(slots: list[int], n_values: int):
    """values -> the recorded slots' values, in C (a list comprehension over 30 slots cost 0.5 us a step);
    None when every slot is recorded in slot order (the default [record]): the table as it is."""
    if list(slots) == list(range(n_values)):
        return None
    if len(slots) == 1:
        only = slots[0]
        return lambda values: (values[only],)
    return itemgetter(*slots) if slots else (lambda values: ())


class CoSimulation:
    """Runs one scenario into one run folder.

    The gateways and observers of the scenario's sections are hooks (master.hooks),
    kept as attributes so that tests and tools can reach them (`cosim.serial.urls`)
    or replace one before the run (`v2i snapshot` runs the world without sensors).
    """

    def __init__(self, scenario: Scenario, run_dir: Path | None = None, quiet: bool = False):
        self.scenario = scenario
        self.run_dir = Path(run_dir) if run_dir else default_run_dir(scenario)
        self.quiet = quiet
        self._tmp_dirs: list[str] = []
        self.serial = SerialBridges(scenario.serial, scenario.time.mode, quiet)  # serial ports (socket:// URLs)
        self.can = CanBridge(scenario.can, scenario.time.mode, quiet)  # the CAV's drive-by-wire gateway ([can])
        self.world = None  # master.world.world.WorldParticipant when the scenario has a [world]
        if scenario.world is not None:
            from master.world.world import WorldParticipant

            self.world = WorldParticipant(scenario.world, scenario.time.start,
                                          workers=scenario.world.sensor_processes)
        self.radio = RadioBridge(scenario.v2x) if scenario.v2x is not None else None  # the V2X air ([v2x])
        # apps over a bus following the master's clock ([bridge], [participants.NAME])
        self.participants = ParticipantBridge(scenario.participants, scenario.time.mode, scenario.time.rtf,
                                              scenario.name, quiet,
                                              world=scenario.world.describe() if scenario.world else None)
        # did the vehicles touch? (every scenario with a world of two or more vehicles)
        self.collision = CollisionHook.for_scenario(scenario, COLLISION in scenario.time.stop_on)
        self.stop_conditions = StopConditions.for_scenario(scenario)  # [time] stop_on over signals
        self.inputs = InputFiles(scenario)  # inputs driven from CSV files ([fmus.NAME] input)
        self.extra_hooks: list[Hook] = []  # observers added by tools and tests, after the scenario's own

    def hooks(self) -> list[Hook]:
        """The scenario's hooks in step order: manipulators (apps, serial, CAN), then observers.

        Record keepers come first so they open before (and close after) the apps and the world
        they listen to; they do nothing in the steps themselves.
        """
        sc = self.scenario
        hooks: list[Hook] = []
        if sc.pki is not None:  # credentials before any app starts
            from master.scenario.pki import PkiHook

            hooks.append(PkiHook(sc.pki))
        if self.participants:
            hooks.append(TraceRecorder())
        if self.world is not None and sc.record_camera:
            hooks.append(CameraArchive(self.world))
        if sc.events:  # before the apps' tick and the gateways: an event acts on the step of its time
            from master.scenario.scenario_events import ScenarioEvents, Targets

            hooks.append(ScenarioEvents(sc.events, Targets(self.participants or None, self.radio, self.can or None,
                                                           self.serial or None)))
        hooks += [h for h in (self.inputs, self.participants, self.serial, self.can) if h]
        if self.world is not None:
            if self.participants:  # the world's sensors reach the apps over the bus
                hooks.append(StreamsHook(self.world, sc.participants.bridge.camera_encoding))
            hooks.append(self.world)
        if self.radio is not None:
            hooks.append(self.radio)
        if self.collision is not None:
            hooks.append(self.collision)
        if self.stop_conditions is not None:
            hooks.append(self.stop_conditions)
        return hooks + list(self.extra_hooks)

    # -- set-up -------------------------------------------------------------
    def _instantiate(self, members: dict[str, Member]) -> None:
        """Extract and instantiate every FMU into `members` (filled as it goes, so a
        failure part-way still lets the caller free the instances made so far)."""
        from fmpy import extract

        unzipped: dict[Path, str] = {}
        t = self.scenario.time
        for inst in self.scenario.instances.values():
            if inst.path not in unzipped:
                try:
                    unzipped[inst.path] = extract(str(inst.path))
                except Exception as exc:  # file gone or corrupt since validation
                    raise SimulationError(inst.name, t.start, "extract", f"{inst.path}: {exc}") from exc
                self._tmp_dirs.append(unzipped[inst.path])
            fmu = FmuInstance(inst.name, inst.model_description, unzipped[inst.path])
            members[inst.name] = Member(fmu, inst.step_multiple)
            fmu.instantiate(t.start, t.stop, {**inst.parameters, **inst.start})

    def _bind(self, members: dict[str, Member]) -> tuple[list[Any], list[int], list[str]]:
        """Give every observed variable a slot in one flat list and pre-bind the transfers."""
        sc = self.scenario
        observed: dict[str, list[str]] = {name: [] for name in members}
        for conn in sc.connections:
            if conn.src_var not in observed[conn.src]:
                observed[conn.src].append(conn.src_var)
        for inst_name, var in sc.record:
            if var not in observed[inst_name]:
                observed[inst_name].append(var)

        slot_of: dict[tuple[str, str], int] = {}
        next_slot = 0
        for name, member in members.items():
            fmu = member.fmu
            groups: dict[str, list[str]] = {}
            for var in observed[name]:
                groups.setdefault(fmu.access_key(var), []).append(var)
            for key, names in groups.items():
                vrs = [fmu.variables[n].valueReference for n in names]
                width = sum(fmu.size(n) for n in names)  # an FMI 3 array takes one slot per element
                member.outputs.append((fmu.accessor(key, vrs, setter=False), next_slot, next_slot + width))
                for n in names:
                    slot_of[(name, n)] = next_slot
                    next_slot += fmu.size(n)

        for name, member in members.items():
            fmu = member.fmu
            groups_in: dict[str, list] = {}
            for conn in (c for c in sc.connections if c.dst == name):
                vrs, slots = groups_in.setdefault(fmu.access_key(conn.dst_var), ([], []))
                vrs.append(fmu.variables[conn.dst_var].valueReference)
                first = slot_of[(conn.src, conn.src_var)]
                slots.extend(range(first, first + fmu.size(conn.dst_var)))  # sizes match (scenario check)
            for key, (vrs, slots) in groups_in.items():
                member.inputs.append((fmu.accessor(key, vrs, setter=True), slots))

        values: list[Any] = [0.0] * next_slot
        record_slots, columns = [], []
        for i, v in sc.record:  # an array: one column per element, name[1], name[2], ...
            names = element_names(f"{i}.{v}", members[i].fmu.shape(v))
            record_slots += range(slot_of[(i, v)], slot_of[(i, v)] + len(names))
            columns += names
        return values, record_slots, columns

    # -- metadata -------------------------------------------------------------
    def _metadata(self, status: str) -> dict[str, Any]:
        import fmpy
        import numpy

        sc, t = self.scenario, self.scenario.time
        return {
            "status": status,
            "scenario": sc.name,
            "scenario_file": str(sc.path),
            "started_at": self.started_at,
            "versions": {"v2i-cosim": __version__, "python": platform.python_version(),
                         "fmpy": fmpy.__version__, "numpy": numpy.__version__, "platform": platform.platform()},
            "mode": t.mode,
            "ordering": t.ordering,
            "step_s": t.step,
            "start_s": t.start,
            "stop_s": t.stop,
            "realtime": {"target_rtf": t.rtf, "overrun_policy": t.overrun} if t.mode == "realtime" else None,
            "ordering_note": ("jacobi: each connection delivers its source's output from the previous "
                              "communication point (one source step of delay)" if t.ordering == "jacobi" else
                              "gauss-seidel: instances step in file order; forward connections have no "
                              "delay, backward ones one source step"),
            "connection_delays": connection_delays(sc),
            "instances": {
                i.name: {"fmu": str(i.path), "fmi_version": i.model_description.fmiVersion,
                         "model_identifier": i.model_description.coSimulation.modelIdentifier,
                         "step_multiple": i.step_multiple}
                for i in sc.instances.values()
            },
        }

    # -- the loop -------------------------------------------------------------
    def run(self) -> RunResult:
        sc, t = self.scenario, self.scenario.time
        if self.run_dir.exists() and any(self.run_dir.iterdir()):
            raise FileExistsError(f"run folder {self.run_dir} exists and is not empty; "
                                  "choose another --out (runs are never overwritten)")
        self.started_at = datetime.now(timezone.utc).isoformat(timespec="seconds")
        members: dict[str, Member] = {}
        recorder: RunRecorder | None = None
        ctx: RunContext | None = None
        opened: list[Hook] = []
        meta = self._metadata("running")
        compute = array("d")
        lags = array("d")
        misses = array("b")  # realtime: 1 where the step missed its deadline (timing.csv)
        pacer = Pacer(t.step / t.rtf, t.overrun) if t.mode == "realtime" else None
        steps_done, error, status = 0, None, "completed"
        wall0 = time.perf_counter()
        guard = SignalGuard(lambda: [m.fmu.unzip_dir for m in members.values()])
        guard.install()
        progress = None
        try:
            self._instantiate(members)
            values, record_slots, columns = self._bind(members)
            recorder = RunRecorder(self.run_dir, columns)
            recorder.write_resolved(sc.resolved())
            recorder.write_metadata(meta)
            meta["initialization"] = initialize(members, values, sc, self.inputs)  # consistent t = start row
            for m in members.values():
                m.fmu.exit_initialization()
            ctx = RunContext(sc, self.run_dir, members, self.quiet)
            ctx.pacer = pacer  # realtime: the wall-clock schedule the run clock's mapping is anchored on
            for m in members.values():  # an FMU that ends the simulation stops the run after its step
                m.fmu.on_terminate = ctx.request_stop
            if self.participants:  # the master owns the run's bus; hooks share it
                ctx.prefix = self.participants.prefix
                ctx.bus = open_run_bus(sc.participants.bridge, ctx.prefix)
            hooks = self.hooks() + [RecorderHook(recorder, values, record_slots)]
            for hook in open_order(hooks):
                opened.append(hook)  # closed whatever happens from here on
                section = hook.open(ctx)
                if section is not None:
                    meta[hook.name] = section
                    recorder.write_metadata(meta)
            read_outputs(members.values(), values)
            recorder.row(t.start, [values[s] for s in record_slots])
            recorder.write_metadata(meta)

            befores = [h.before_step for h in hooks if overrides(h, "before_step")]
            afters = [h.after_step for h in hooks if overrides(h, "after_step")]
            step = step_plan(t.ordering, members.values(), values, t.step)  # members, transfers fixed from here
            progress = self._progress(t)
            n, h, start = t.n_steps, t.step, t.start
            wall0 = time.perf_counter()
            if pacer:
                meta["realtime"]["loop_nice"] = set_loop_nice(t.loop_nice)
                pacer.start()
            clock, timed = time.perf_counter, compute.append
            for k in range(n):
                lag = pacer.wait(k) if pacer else None
                t_k = start + k * h
                for before in befores:
                    before(k, t_k)
                c0 = clock()
                step(k, t_k)
                t_next = start + (k + 1) * h
                for after in afters:
                    after(k, t_next)
                steps_done = k + 1
                c1 = clock()
                timed(c1 - c0)
                if pacer:
                    misses.append(pacer.finished(k, t_k))
                    lags.append(lag)
                if progress is not None and (k & 63) == 0:
                    self._tick(progress, t_next - start, c1 - wall0)
                if guard.pending is not None:  # a signal held while FMU code ran: this step is kept and timed
                    guard.check()
                if ctx.stop_reason is not None:
                    status = "stopped"
                    break
            recorder.flush()  # the rows kept since the last flush are formatted now: in the loop's time, its cost
        except SimulationError as exc:
            status, error = "failed", str(exc)
            meta.update(failed_instance=exc.instance, failed_time_s=exc.time, failed_call=exc.call)
        except DeadlineMissError as exc:
            status, error = "failed", str(exc)
        except TimeSyncError as exc:  # a participant timed out, left, was refused or never joined
            status, error = "failed", str(exc)
            meta.update(failed_participant=getattr(exc, "name", None) or getattr(exc, "missing", None))
        except (Interrupted, KeyboardInterrupt):
            status, error = "interrupted", "interrupted by signal"
        except Exception as exc:  # a bug of ours: record it with the data, then let it surface
            status, error = "failed", f"internal error: {type(exc).__name__}: {exc}"
            raise
        finally:
            wall = time.perf_counter() - wall0
            if pacer and meta["realtime"].get("loop_nice"):
                restore_nice(meta["realtime"]["loop_nice"])  # the closing and the report at the thread's own
            if progress is not None:
                progress.close()
            sim_elapsed = steps_done * t.step
            outcome = Outcome(status, error, steps_done, t.start + sim_elapsed,
                              ctx.stop_reason if ctx is not None else None)
            for hook in reversed(opened):
                section = self._close_hook(hook, outcome)
                if section is not None:
                    meta[hook.name] = section
            if ctx is not None:
                events = ctx.close_events()
                if events is not None:
                    meta["events"] = events
                if ctx.bus is not None:
                    ctx.bus.close()
            for m in members.values():
                m.fmu.close()
            for d in self._tmp_dirs:
                shutil.rmtree(d, ignore_errors=True)
            guard.restore()
            meta.update(status=status, error=error, steps_done=steps_done, sim_time_reached_s=t.start + sim_elapsed,
                        wall_time_s=wall, rtf=self._rtf_stats(sim_elapsed, wall, compute, t.step))
            if outcome.stop_reason is not None:
                meta["stop_reason"] = outcome.stop_reason
            meta["step_compute_s"] = percentiles(compute)
            if pacer:
                meta["realtime"].update(lag_s=percentiles(lags), deadline_misses=pacer.misses,
                                        skipped_slots=pacer.skipped_slots)
            if recorder is not None:
                recorder.close()
                recorder.write_timing(t.start, t.step, compute, lags, misses)
                meta["parquet"] = recorder.write_parquet() or "timeseries.parquet"
                metrics = run_metrics(self.run_dir, meta)
                if metrics is not None:  # the verdict: collision, gaps, the latency chain
                    write_metrics(self.run_dir, metrics)
                    meta["metrics"] = METRICS
                recorder.write_metadata(meta)
            elif error is not None or status != "completed":
                # failed before the run folder opened: still leave a trace of why
                self.run_dir.mkdir(parents=True, exist_ok=True)
                (self.run_dir / METADATA).write_text(json.dumps(meta, indent=2, default=str) + "\n")
        return RunResult(self.run_dir, status, meta, error)

    @staticmethod
    def _close_hook(hook: Hook, outcome: Outcome) -> dict[str, Any] | None:
        """Close one hook; a hook that fails to close is noted, and the others still close."""
        try:
            return hook.close(outcome)
        except Exception as exc:  # noqa: BLE001 -- the run's records matter more than one hook's tidy-up
            return {"close_error": f"{type(exc).__name__}: {exc}"}

    @staticmethod
    def _rtf_stats(sim_elapsed: float, wall: float, compute: array, h: float) -> dict[str, Any]:
        per_step = array("d", (h / c for c in compute if c > 0))
        return {"achieved": sim_elapsed / wall if wall > 0 else None,
                "per_step_compute": percentiles(per_step, (1, 50, 99))}

    def _progress(self, t):
        if self.quiet:
            return None
        from tqdm import tqdm

        return tqdm(total=round(t.stop - t.start, 9), unit="s sim", disable=None, leave=False,
                    bar_format="{l_bar}{bar}| {n:.2f}/{total:.2f} s sim [{elapsed}<{remaining}{postfix}]")

    @staticmethod
    def _tick(progress, sim_elapsed: float, wall: float) -> None:
        progress.n = round(sim_elapsed, 6)
        progress.set_postfix_str(f"RTF {sim_elapsed / wall:.1f}" if wall > 0 else "", refresh=False)
        progress.refresh()
