"""Where the points of a sweep run: engines chosen by name, each an existing scheduler, none home-made.

* ``local`` (default): a concurrent.futures pool of `--jobs` workers on this
  machine. Each point is its own `v2i run` process (master.sweep.point), so
  the pool's workers are threads that start one and wait for it: the points run
  in parallel processes, and nothing is forked from a process that holds zenoh
  or pybullet state.
* ``ray``: one Ray task per point (`ray.remote`), on a Ray cluster
  (`--address auto` or HOST:PORT: one started with `ray start`) or, without an
  address, on a local Ray instance of `--jobs` CPUs. Each task reserves
  `cpus_per_point` CPUs of the cluster; a node runs its points as above. The
  nodes need the project at the same path (the same checkout and virtual
  environment); the driver writes the table from what the tasks return, so it
  is complete even when the run folders stay on the nodes.

An engine is `open_engine(name, jobs=..., address=...)`, a context manager whose
`map(fn, items)` yields `(item, fn(item), None)` for every item as each
finishes (in completion order), or `(item, None, exception)` when the engine
could not get a result (a worker died): the sweep records that point as failed
and goes on. Ray is an optional extra (`pip install 'v2i-cosim[ray]'`).
"""
from __future__ import annotations

import importlib
from concurrent.futures import FIRST_COMPLETED, ThreadPoolExecutor, wait
from typing import Any, Callable, Iterable, Iterator

ENGINES: dict[str, str] = {  # name -> "module:class", imported only when chosen
    "local": "master.sweep.engines:LocalEngine",
    "ray": "master.sweep.engines:RayEngine",
}


def open_engine(name: str, *, jobs: int = 1, address: str | None = None, cpus_per_point: float = 1.0):
    """The engine `name` (ValueError naming the known ones); ModuleNotFoundError when its library is missing."""
    if name not in ENGINES:
        from master.scenario.tables import did_you_mean

        hint = did_you_mean(name, ENGINES)
        raise ValueError(f"unknown engine {name!r} (engines: {', '.join(ENGINES)})" + (f"; {hint}" if hint else ""))
    module, _, cls = ENGINES[name].partition(":")
    return getattr(importlib.import_module(module), cls)(jobs=jobs, address=address, cpus_per_point=cpus_per_point)


class LocalEngine:
    """A pool of `jobs` workers on this machine."""

    name = "local"

    def __init__(self, jobs: int = 1, address: str | None = None, cpus_per_point: float = 1.0):
        if address:
            raise ValueError("--address is for the ray engine (the local engine runs on this machine)")
        self.jobs = max(1, int(jobs))
        self.pool: ThreadPoolExecutor | None = None

    def __enter__(self) -> LocalEngine:
        self.pool = ThreadPoolExecutor(max_workers=self.jobs, thread_name_prefix="sweep-point")
        return self

    def __exit__(self, *exc) -> None:
        self.pool.shutdown(wait=exc[0] is None, cancel_futures=True)

    def describe(self) -> str:
        return f"local, {self.jobs} job(s)"

    def map(self, fn: Callable[[Any], Any], items: Iterable[Any]) -> Iterator[tuple[Any, Any, BaseException | None]]:
        futures = {self.pool.submit(fn, item): item for item in items}
        pending = set(futures)
        while pending:
            done, pending = wait(pending, return_when=FIRST_COMPLETED)
            for future in done:
                error = future.exception()
                yield futures[future], None if error else future.result(), error


class RayEngine:
    """One Ray task per point, on a cluster (`address`) or a local Ray instance of `jobs` CPUs."""

    name = "ray"

    def __init__(self, jobs: int = 1, address: str | None = None, cpus_per_point: float = 1.0):
        import ray  # the optional extra: a missing one surfaces as ModuleNotFoundError (the CLI names the extra)

        self.ray = ray
        self.jobs, self.address, self.cpus = max(1, int(jobs)), address, cpus_per_point
        self._started = False

    def __enter__(self) -> RayEngine:
        import logging

        ray = self.ray
        if not ray.is_initialized():
            options: dict[str, Any] = {"logging_level": logging.WARNING, "log_to_driver": False,
                                       "include_dashboard": False}
            if self.address:
                ray.init(address=self.address, **options)
            else:  # a local instance for this sweep only
                ray.init(num_cpus=self.jobs, **options)
            self._started = True
        return self

    def __exit__(self, *exc) -> None:
        if self._started:
            self.ray.shutdown()

    def describe(self) -> str:
        resources = self.ray.cluster_resources()
        where = self.address or "a local Ray instance"
        return f"ray at {where}, {resources.get('CPU', 0):g} CPU(s) in {len(self.ray.nodes())} node(s), " \
               f"{self.cpus:g} per point"

    def map(self, fn: Callable[[Any], Any], items: Iterable[Any]) -> Iterator[tuple[Any, Any, BaseException | None]]:
        ray = self.ray
        remote = ray.remote(num_cpus=self.cpus, max_retries=0)(fn)
        refs = {remote.remote(item): item for item in items}
        pending = list(refs)
        try:
            while pending:
                done, pending = ray.wait(pending, num_returns=1)
                for ref in done:
                    try:
                        result, error = ray.get(ref), None
                    except Exception as exc:  # noqa: BLE001 -- a task whose worker died: that point failed
                        result, error = None, exc
                    yield refs[ref], result, error
        finally:
            for ref in pending:  # an interrupted sweep: the points not finished are cancelled
                ray.cancel(ref, force=True)
