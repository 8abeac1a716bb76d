"""bridges.allocator: freed frame-sized buffers stay in the process instead of being mapped afresh each frame.

Counted in page faults (the kernel's count for the process, not a timing): a loop that makes and drops a
640x480 frame's worth of float buffers faults again on a large share of their pages under glibc's defaults, and
hardly at all once keep_freed_memory() has run. Each case runs in a fresh interpreter: the setting is the
process's, and sticks.
"""
from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from bridges import allocator

ROOT = Path(__file__).resolve().parent.parent

# make and drop, 60 times, the buffers of one frame through a network: 3.7 MB in, four 4.9 MB feature maps
LOOP = """
import json, resource, sys
import numpy as np
{setup}
def frame():
    x = np.ones((1, 3, 480, 640), np.float32)
    maps = [np.ones((1, 16, 240, 320), np.float32) for _ in range(4)]
    return float(x[0, 0, 0, 0] + sum(m[0, 0, 0, 0] for m in maps))
frame()
before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
for _ in range(60):
    frame()
print(json.dumps({{"faults": resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before, "said": said}}))
"""
PAGES = 60 * (3 * 480 * 640 + 4 * 16 * 240 * 320) * 4 // 4096  # every page of LOOP's buffers, once per frame


def _run(setup: str, **env) -> dict:
    full = {k: v for k, v in os.environ.items() if k not in (allocator.ENV_OPT_OUT, *allocator.GLIBC_ENV)}
    full.update(env)
    out = subprocess.run([sys.executable, "-c", LOOP.format(setup=setup)], capture_output=True, text=True,
                         env=full, timeout=120)
    assert out.returncode == 0, out.stderr
    return json.loads(out.stdout.strip().splitlines()[-1])


glibc = pytest.mark.skipif(allocator._glibc_mallopt() is None, reason="not glibc: keep_freed_memory does nothing here")
KEEP = "from bridges.allocator import keep_freed_memory\nsaid = keep_freed_memory()"


@glibc
def test_freed_frame_buffers_are_reused_not_faulted_in_again():
    default = _run("said = None")
    kept = _run(KEEP)
    assert kept["said"].startswith("glibc: mmap threshold 64 MiB")
    pages = PAGES
    assert default["faults"] > 0.3 * pages, default  # glibc's defaults: its trims give pages back, faulted again
    assert kept["faults"] < 0.02 * pages, kept  # kept: the first frame's pages serve the rest


@glibc
def test_the_user_can_keep_glibcs_own_behaviour():
    """V2I_MALLOC=system leaves glibc as it is; glibc's own variables, set by the user, are theirs to keep."""
    pages = PAGES
    opted_out = _run(KEEP, V2I_MALLOC="system")
    assert opted_out["said"] == "left as the C library has it (V2I_MALLOC=system)"
    assert opted_out["faults"] > 0.3 * pages
    theirs = _run(KEEP, MALLOC_TRIM_THRESHOLD_="0")
    assert theirs["said"] == "left to the environment's MALLOC_TRIM_THRESHOLD_"


def test_a_mistyped_choice_is_refused_by_name(monkeypatch):
    """V2I_MALLOC is "kept" (the default) or "system"; anything else is an error naming the variable."""
    monkeypatch.setattr(allocator, "_applied", None)
    monkeypatch.setenv("V2I_MALLOC", "sytem")
    with pytest.raises(ValueError, match=r"V2I_MALLOC='sytem': not one of kept, system \(did you mean 'system'\?\)"):
        allocator.keep_freed_memory()
    assert allocator._applied is None  # nothing set: the next call, with the variable mended, still decides


def test_the_torch_detector_and_the_camera_set_it_when_built():
    """Where frames are made, the maker sets it when built (as torch's thread count is set): the torch
    detector (RSU app, evaluation, benchmarks) and the world's camera (sensor workers, datasets).
    ONNX Runtime keeps its own arena (benchmarks/allocator.py: no change), so the onnx backend leaves the C
    library alone."""
    tell = "\nfrom bridges import allocator\nsaid = allocator._applied"
    scenario = ROOT / "scenarios" / "ima_world.toml"
    said = {backend: _run(f"from rsu_app.perception import make_detector\nmake_detector({backend!r}, threads=1)"
                          + tell)["said"] for backend in ("torch", "onnx")}
    said["camera"] = _run("from master.scenario.loader import load_scenario\nfrom master.world.world import World\n"
                          f"w = World(load_scenario({str(scenario)!r}).world, renderer='tiny')\n"
                          "assert w.cameras\nw.close()" + tell)["said"]
    for who in ("torch", "camera"):
        assert said[who] is not None and said[who].startswith(("glibc: mmap threshold", "not glibc")), said
    assert said["onnx"] is None, said
