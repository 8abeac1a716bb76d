"""Errors a user can act on: each names the file, key or instance at fault."""
from __future__ import annotations


class ScenarioError(ValueError):
    """A scenario file is invalid; `problems` holds one line per fault (`key: reason`)."""

    def __init__(self, path, problems: list[str]):
        self.path = str(path)
        self.problems = list(problems)
        lines = "\n".join(f"  {self.path}: {p}" for p in self.problems)
        super().__init__(f"invalid scenario {self.path} ({len(self.problems)} problem(s)):\n{lines}")


class SimulationError(RuntimeError):
    """An FMU failed during a run; names the instance and the simulated time."""

    def __init__(self, instance: str, time: float, call: str, detail: str):
        self.instance, self.time, self.call, self.detail = instance, time, call, detail
        super().__init__(f"instance '{instance}' failed in {call} at t = {time:.6g} s: {detail}")


class DeadlineMissError(RuntimeError):
    """Realtime mode with the `abort` overrun policy missed a deadline."""
