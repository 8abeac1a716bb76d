"""One running FMU instance over fmpy, FMI 2 or FMI 3 co-simulation.

Hides the FMI-version differences behind get/set by typed value-reference
groups and turns every failed call into a SimulationError naming the
instance, the call and the FMU's own last log messages.
"""
from __future__ import annotations

from collections import deque
from ctypes import byref
from typing import Any, Callable, Sequence

from master.errors import SimulationError
from master.fmu_variables import family

_FMI2_ACCESS = {"real": ("getReal", "setReal"), "integer": ("getInteger", "setInteger"),
                "boolean": ("getBoolean", "setBoolean"), "string": ("getString", "setString")}
_FMI3_ACCESS = {t: (f"get{t}", f"set{t}") for t in (
    "Float64", "Float32", "Int8", "Int16", "Int32", "Int64",
    "UInt8", "UInt16", "UInt32", "UInt64", "Boolean", "String")}
_FMI3_ACCESS["Enumeration"] = ("getInt64", "setInt64")
_LEVELS = ["OK", "WARNING", "DISCARD", "ERROR", "FATAL", "PENDING"]


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
        self._keepalive = None  # ctypes callbacks must outlive the instance

    # -- access ---------------------------------------------------------------
    def access_key(self, var_name: str) -> str:
        """Group key for batching: the getter/setter family of the variable."""
        var = self.variables[var_name]
        return var.type if self.fmi3 else family(var.type)

    def accessor(self, key: str, vrs: Sequence[int], setter: bool) -> Callable:
        """A bound get(vrs) / set(vrs, values) call for a group of variables of one kind."""
        table = _FMI3_ACCESS if self.fmi3 else _FMI2_ACCESS
        method = getattr(self._slave, table[key][1 if setter else 0])
        vrs = list(vrs)
        call = "set" if setter else "get"
        if setter:
            def set_values(values):
                try:
                    method(vrs, values)
                except Exception as exc:
                    self.fail(f"{call} values", exc)
            return set_values

        def get_values():
            try:
                return method(vrs)
            except Exception as exc:
                self.fail(f"{call} values", exc)
        return get_values

    def set_by_name(self, values: dict[str, Any]) -> None:
        groups: dict[str, tuple[list[int], list[Any]]] = {}
        for name, value in values.items():
            vrs, vals = groups.setdefault(self.access_key(name), ([], []))
            vrs.append(self.variables[name].valueReference)
            vals.append(value)
        for key, (vrs, vals) in groups.items():
            self.accessor(key, vrs, setter=True)(vals)

    def get_by_name(self, names: Sequence[str]) -> dict[str, Any]:
        out = {}
        for name in names:
            var = self.variables[name]
            out[name] = self.accessor(self.access_key(name), [var.valueReference], setter=False)()[0]
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
        self.time = t
        try:
            if self.fmi3:
                event, terminate, _, _ = self._slave.doStep(t, h)
                if terminate:
                    raise RuntimeError("the FMU asked to terminate the simulation")
            else:
                self._slave.doStep(t, h)
        except Exception as exc:
            self.fail("doStep", exc)

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

    def fail(self, call: str, exc: BaseException):
        status = getattr(exc, "status", None)  # fmpy's FMICallException carries the FMI status
        self.failed = "error" if status == 3 else "fatal"
        messages = [m for m in self.log if not m.startswith("[OK]")] or list(self.log)
        detail = str(exc)
        if messages:
            detail += "; FMU log: " + " | ".join(messages[-5:])
        raise SimulationError(self.name, self.time, call, detail) from exc
