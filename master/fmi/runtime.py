"""One running FMU instance over fmpy, FMI 2 or FMI 3 co-simulation.

Hides the FMI-version differences behind get/set by typed value-reference
groups (values come back as the same Python types whatever the FMI version:
str for String, 0/1 for Boolean; an FMI 3 array as its elements, flat) and
turns every failed call into a SimulationError naming the instance, the call
and the FMU's own last log messages. A value outside its variable's type range
is refused before it reaches ctypes, which would wrap or overflow it silently.
An FMU that ends the simulation itself (FMI 2: fmi2Discard with fmi2Terminated;
FMI 3: terminateSimulation) is not a failure: the instance reports it through
`on_terminate` and the master stops after the step.
"""
from __future__ import annotations

from collections import deque
from ctypes import byref
from typing import Any, Callable, Sequence

from master.errors import SimulationError
from master.fmi.variables import element_names, family, flatten, outside_type_range, shape, size, type_range

_FMI2_ACCESS = {"real": ("getReal", "setReal"), "integer": ("getInteger", "setInteger"),
                "boolean": ("getBoolean", "setBoolean"), "string": ("getString", "setString")}
_FMI3_ACCESS = {t: (f"get{t}", f"set{t}") for t in (
    "Float64", "Float32", "Int8", "Int16", "Int32", "Int64",
    "UInt8", "UInt16", "UInt32", "UInt64", "Boolean", "String")}
_FMI3_ACCESS["Enumeration"] = ("getInt64", "setInt64")
_LEVELS = ["OK", "WARNING", "DISCARD", "ERROR", "FATAL", "PENDING"]
_DISCARD, _ERROR = 2, 3  # FMI status codes (the same in FMI 2 and FMI 3)
_FMI2_TERMINATED = 3  # fmi2StatusKind fmi2Terminated


def _decode_strings(values: list) -> list[str]:
    """FMI 2 getString gives bytes (fmpy does not decode them, its FMI 3 getString does):
    decode, so that a connection can hand them to any setString and the records hold text."""
    return [v.decode("utf-8", "replace") if isinstance(v, bytes) else v for v in values]


def _booleans_as_int(values: list) -> list[int]:
    """FMI 3 getBoolean gives True/False, FMI 2 (an int type in C) gives 1/0: one
    representation, 1/0, so that timeseries.csv holds numbers whatever the FMU's version."""
    return [int(v) for v in values]


# getter key -> conversion of the values fmpy returns (keys absent: used as they come)
_FMI2_CONVERT = {"string": _decode_strings}
_FMI3_CONVERT = {"Boolean": _booleans_as_int}


class FmuInstance:
    """An instantiated FMU: life-cycle calls plus typed access by variable name."""

    def __init__(self, name: str, model_description, unzip_dir: str):
        self.name = name
        self.md = model_description
        self.unzip_dir = unzip_dir
        self.fmi3 = model_description.fmiVersion.startswith("3")
        self.variables = {v.name: v for v in model_description.modelVariables}
        self.log: deque[str] = deque(maxlen=20)
        self.time = 0.0
        self._slave = None
        self.failed: str | None = None  # "error" / "fatal" once a call failed
        self.terminated_at: float | None = None  # when a doStep ended the simulation
        # called with the reason when the FMU ends the simulation (the master's RunContext.request_stop)
        self.on_terminate: Callable[[str], None] | None = None
        self._keepalive = None  # ctypes callbacks must outlive the instance
        self._by_vr: dict[tuple[str, int], Any] | None = None  # (access key, value reference) -> variable

    # -- access ---------------------------------------------------------------
    def access_key(self, var_name: str) -> str:
        """Group key for batching: the getter/setter family of the variable."""
        var = self.variables[var_name]
        return var.type if self.fmi3 else family(var.type)

    def size(self, var_name: str) -> int:
        """How many values the variable holds (an FMI 3 array: all its elements)."""
        return size(self.variables[var_name])

    def shape(self, var_name: str) -> tuple[int, ...]:
        """An FMI 3 array's dimensions; () for a scalar."""
        return shape(self.variables[var_name])

    def _variable(self, key: str, vr: int):
        """The variable behind a value reference of a getter/setter family (the first of its aliases)."""
        if self._by_vr is None:
            self._by_vr = {}
            for var in self.md.modelVariables:
                self._by_vr.setdefault((self.access_key(var.name), var.valueReference), var)
        return self._by_vr.get((key, vr))

    def accessor(self, key: str, vrs: Sequence[int], setter: bool) -> Callable:
        """A bound get(vrs) / set(vrs, values) call for a group of variables of one kind.

        Values are flat: an array variable takes (and gives) all its elements in
        row-major order. A setter refuses a value outside the variable's type range
        (ctypes would wrap or overflow it silently) with a SimulationError naming it.
        """
        table = _FMI3_ACCESS if self.fmi3 else _FMI2_ACCESS
        method = getattr(self._slave, table[key][1 if setter else 0])
        vrs = list(vrs)
        call = "set" if setter else "get"
        variables = [self._variable(key, vr) for vr in vrs]
        if setter:
            bounded = key if self.fmi3 else {"integer": "Integer"}.get(key)
            if bounded is None or type_range(bounded, self.fmi3) is None:
                def set_values(values):
                    try:
                        method(vrs, values)
                    except Exception as exc:
                        self.fail(f"{call} values", exc)
                return set_values

            low, high = type_range(bounded, self.fmi3)
            names = [n for var, vr in zip(variables, vrs)
                     for n in (element_names(var.name, shape(var)) if var is not None else [f"#{vr}"])]
            if bounded == "Float32":
                def fits(v):
                    return not (abs(v) > high and abs(v) != float("inf"))
            else:
                def fits(v):
                    return low <= v <= high

            def set_checked(values):
                for name, value in zip(names, values):
                    if not fits(value):
                        self.refuse(f"{call} values",
                                    f"{name}: {outside_type_range(bounded, value, self.fmi3)}; not set")
                try:
                    method(vrs, values)
                except Exception as exc:
                    self.fail(f"{call} values", exc)
            return set_checked

        read, arg = self._reader(key, method, vrs, variables)

        def get_values():
            try:
                return read(arg)
            except Exception as exc:
                self.fail(f"{call} values", exc)
        # the stepping loop (master.run.algorithm) makes this call itself and turns an error into the same
        # SimulationError once around all of a step's reads: a frame and a try per call cost it per FMU and step
        get_values.read_call = (read, arg)
        return get_values

    def _reader(self, key: str, method: Callable, vrs: list[int], variables: list) -> tuple[Callable, Any]:
        """(read, arg): read(arg) gives a group's values as the master keeps them, errors left to the
        caller (`fail("get values")`).

        The common case, a scalar group without conversion, is fmpy's getter and the value references
        themselves: the loop calls fmpy as a bare loop would (a functools.partial cost ~70 ns more a call).
        """
        n_values = sum(size(var) if var is not None else 1 for var in variables)
        if self.fmi3 and n_values != len(vrs):
            raw = method

            def method(vrs):
                return raw(vrs, n_values)

        convert = (_FMI3_CONVERT if self.fmi3 else _FMI2_CONVERT).get(key)
        if convert is None:
            return method, vrs
        return (lambda vrs: convert(method(vrs))), vrs

    def set_by_name(self, values: dict[str, Any]) -> None:
        """Set variables by name; an array takes a list (nested row by row, or flat) of its elements."""
        groups: dict[str, tuple[list[int], list[Any]]] = {}
        for name, value in values.items():
            vrs, vals = groups.setdefault(self.access_key(name), ([], []))
            vrs.append(self.variables[name].valueReference)
            dims = shape(self.variables[name])
            vals.extend(flatten(value, dims) if dims else [value])
        for key, (vrs, vals) in groups.items():
            self.accessor(key, vrs, setter=True)(vals)

    def get_by_name(self, names: Sequence[str]) -> dict[str, Any]:
        """Current values by name: a scalar's value, an array's elements as a flat list."""
        out = {}
        for name in names:
            var = self.variables[name]
            got = self.accessor(self.access_key(name), [var.valueReference], setter=False)()
            out[name] = list(got) if shape(var) else got[0]
        return out

    # -- life cycle -------------------------------------------------------------
    def _logger(self, *args) -> None:
        # FMI 2: (env, instanceName, status, category, message); FMI 3: (env, status, category, message)
        status, category, message = args[-3:]
        text = message.decode("utf-8", "replace") if isinstance(message, bytes) else str(message)
        self.log.append(f"[{_LEVELS[status] if 0 <= status < len(_LEVELS) else status}] {text.strip()}")

    def instantiate(self, start_time: float, stop_time: float, start_values: dict[str, Any]) -> None:
        """Instantiate, set parameters and start values, enter initialization mode.

        Start values go in before initialization mode: FMI allows variables with
        initial="approx" to be set only then.
        """
        self.time = start_time
        try:
            if self.fmi3:
                from fmpy.fmi3 import FMU3Slave

                self._slave = FMU3Slave(guid=self.md.guid, unzipDirectory=self.unzip_dir,
                                        modelIdentifier=self.md.coSimulation.modelIdentifier,
                                        instanceName=self.name)
                self._slave.instantiate(loggingOn=True, logMessage=self._logger)
            else:
                from fmpy import calloc, free
                from fmpy.fmi2 import (FMU2Slave, fmi2CallbackAllocateMemoryTYPE, fmi2CallbackFreeMemoryTYPE,
                                       fmi2CallbackFunctions, fmi2CallbackLoggerTYPE)
                from fmpy.logging import addLoggerProxy

                callbacks = fmi2CallbackFunctions()
                callbacks.logger = fmi2CallbackLoggerTYPE(self._logger)
                callbacks.allocateMemory = fmi2CallbackAllocateMemoryTYPE(calloc)
                callbacks.freeMemory = fmi2CallbackFreeMemoryTYPE(free)
                addLoggerProxy(byref(callbacks))
                self._keepalive = callbacks
                self._slave = FMU2Slave(guid=self.md.guid, unzipDirectory=self.unzip_dir,
                                        modelIdentifier=self.md.coSimulation.modelIdentifier,
                                        instanceName=self.name)
                self._slave.instantiate(callbacks=callbacks, loggingOn=True)
                self._slave.setupExperiment(startTime=start_time, stopTime=stop_time)
        except Exception as exc:
            self.fail("instantiate", exc)
        self.set_by_name(start_values)
        try:
            if self.fmi3:
                self._slave.enterInitializationMode(startTime=start_time, stopTime=stop_time)
            else:
                self._slave.enterInitializationMode()
        except Exception as exc:
            self.fail("enterInitializationMode", exc)

    def exit_initialization(self) -> None:
        try:
            self._slave.exitInitializationMode()
        except Exception as exc:
            self.fail("exitInitializationMode", exc)

    def do_step(self, t: float, h: float) -> None:
        """One communication step from t to t + h.

        An FMU may end the simulation with this step; that is a normal end, not
        an error (FMI 2 signals it as fmi2Discard plus fmi2Terminated, FMI 3 as
        terminateSimulation), so it goes to `terminated` and the step counts.
        """
        self.time = t
        try:
            if self.fmi3:
                _, terminate, _, _ = self._slave.doStep(t, h)
                if terminate:
                    self.terminated(t + h)
            else:
                self._slave.doStep(t, h)
        except SimulationError:
            raise
        except Exception as exc:
            self.step_failed(exc, t, h)

    def stepper(self) -> Callable[[float, float], None]:
        """do(t, h) for the stepping loop, which sets `time` and hands an exception to `step_failed`.

        FMI 2: fmpy's doStep itself (a failed or discarded step raises; no frame of ours per step).
        FMI 3 reports the end of the simulation in doStep's result, not as an error: `do_step`.
        """
        return self.do_step if self.fmi3 else self._slave.doStep

    def step_failed(self, exc: BaseException, t: float, h: float) -> None:
        """doStep from t raised `exc`: the FMU ended the simulation with this step (FMI 2: fmi2Discard
        and fmi2Terminated; returns after `terminated`), or a SimulationError naming the instance and doStep."""
        if not self.fmi3 and getattr(exc, "status", None) == _DISCARD and self._fmi2_terminated():
            self.terminated(t + h)
        else:
            self.fail("doStep", exc)

    def _fmi2_terminated(self) -> bool:
        """After fmi2Discard from doStep: does the FMU want to end the simulation?
        (fmi2GetBooleanStatus(fmi2Terminated); an FMU that cannot say has not.)"""
        try:
            return bool(self._slave.getBooleanStatus(_FMI2_TERMINATED))
        except Exception:  # noqa: BLE001 -- the discard itself is reported by the caller
            return False

    def terminated(self, t_end: float) -> None:
        """The FMU ended the simulation with the step to t_end: ask the master to stop after this step.

        Without a master listening (on_terminate unset) nothing would stop the
        loop, so that case stays an error rather than going unnoticed.
        """
        self.terminated_at = t_end
        reason = f"terminated by instance {self.name!r} at t = {t_end:.6g} s"
        if self.on_terminate is None:
            raise SimulationError(self.name, t_end, "doStep", f"{reason}, but no master listens for it")
        self.on_terminate(reason)

    def close(self) -> None:
        """Terminate and free, ignoring errors: used on every exit path.

        After an error status FMI allows only freeing the instance; after a
        fatal one the instance is corrupt and pythonfmu 0.7.0 even crashes in
        fmi2FreeInstance, so it is left to the process exit (a small leak).
        """
        if self._slave is None:
            return
        calls = {None: ("terminate", "freeInstance"), "error": ("freeInstance",), "fatal": ()}[self.failed]
        for call in calls:
            try:
                getattr(self._slave, call)()
            except Exception:
                pass
        self._slave = None

    def refuse(self, call: str, detail: str):
        """The master refuses a call before it reaches the FMU: a SimulationError, but the
        instance is still sound (it is terminated and freed normally)."""
        raise SimulationError(self.name, self.time, call, detail)

    def fail(self, call: str, exc: BaseException):
        status = getattr(exc, "status", None)  # fmpy's FMICallException carries the FMI status
        # discard and error leave the instance usable enough to free; anything else is treated as fatal
        self.failed = "error" if status in (_DISCARD, _ERROR) else "fatal"
        messages = [m for m in self.log if not m.startswith("[OK]")] or list(self.log)
        detail = str(exc)
        if messages:
            detail += "; FMU log: " + " | ".join(messages[-5:])
        raise SimulationError(self.name, self.time, call, detail) from exc
