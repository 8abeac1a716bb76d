"""Keep freed memory in the process: glibc's malloc set for loops that allocate the same large buffers each frame.

Why: a camera frame and a network's feature maps are buffers of one to several MB, made and freed every
frame. glibc serves allocations that large with a fresh mmap (its threshold moves up to 32 MB only after such
a block is freed) and hands the top of its heap back to the kernel once more than twice that lies free, so
frame after frame the kernel maps and zeroes new pages. Measured on this project's 2-core machine, 85 frames
of a 640x480-input network (RECIPE.md's stage 15) on one torch thread: 752,000 page faults, 2.0 s of kernel
time beside 4.7 s of user time, 44 ms a frame; with the thresholds below 73,000 faults, 0.4 s, 20 ms a frame,
the same detections (benchmarks/allocator.py: torch 1.9-2.2x faster, onnx unchanged). The cost is memory the
process keeps after a peak (up to `trim_threshold` at the heap's top), which a long-running app or world
would map again anyway.

Called where frames are made, when the thing that makes them is built (process-wide, as the torch thread
count is): the torch detector (the RSU app, `v2i eval-detector`, the benchmarks) and the world's camera
(`master.world.camera.Camera`: the sensor workers, `v2i dataset`, and the master, whose World holds its
cameras even when workers draw them; the master's own loop was not measured with it).
The camera's 640x480 frame faulted 3,085 pages in each time (12 MB): kept, EGL's frame takes about 12 % less
wall time and 7 % less CPU, TinyRenderer's 4-5 % less. Not called where it was measured to change nothing:
ONNX Runtime keeps its own arena, a lidar scan faults a few dozen pages (benchmarks/allocator.py). A user
who set glibc's own variables (MALLOC_MMAP_THRESHOLD_, MALLOC_TRIM_THRESHOLD_) keeps them; V2I_MALLOC=system
leaves glibc as it is. On another C library (musl, macOS) it does nothing and says so in its return value.
"""
from __future__ import annotations

import ctypes
import ctypes.util
import difflib
import os

M_TRIM_THRESHOLD = -1  # glibc's mallopt parameter numbers (malloc.h)
M_MMAP_THRESHOLD = -3
MMAP_THRESHOLD = 64 * 1024 * 1024   # blocks below this come from the heap and are reused (a 1280x720 frame: 11 MB)
TRIM_THRESHOLD = 256 * 1024 * 1024  # free memory kept at the heap's top before any goes back to the kernel
ENV_OPT_OUT = "V2I_MALLOC"
CHOICES = ("kept", "system")  # V2I_MALLOC: the thresholds below (the default), or glibc as it comes
GLIBC_ENV = ("MALLOC_MMAP_THRESHOLD_", "MALLOC_TRIM_THRESHOLD_")

_applied: str | None = None


def keep_freed_memory(mmap_threshold: int = MMAP_THRESHOLD, trim_threshold: int = TRIM_THRESHOLD) -> str:
    """Set glibc's mmap and trim thresholds for this process (once); returns what was done, in words.

    Raises ValueError for a V2I_MALLOC that is neither "kept" nor "system" (a typo would otherwise measure
    the setting the user meant to turn off)."""
    global _applied
    if _applied is not None:
        return _applied
    choice = os.environ.get(ENV_OPT_OUT, "").strip().lower() or "kept"
    if choice not in CHOICES:
        near = difflib.get_close_matches(choice, CHOICES, n=1)
        raise ValueError(f"{ENV_OPT_OUT}={os.environ[ENV_OPT_OUT]!r}: not one of {', '.join(CHOICES)}"
                         + (f" (did you mean {near[0]!r}?)" if near else ""))
    if choice == "system":
        _applied = f"left as the C library has it ({ENV_OPT_OUT}=system)"
        return _applied
    if any(k in os.environ for k in GLIBC_ENV):
        _applied = "left to the environment's " + ", ".join(k for k in GLIBC_ENV if k in os.environ)
        return _applied
    mallopt = _glibc_mallopt()
    if mallopt is None:
        _applied = "not glibc: left as the C library has it"
        return _applied
    said = [f"{what} threshold {value >> 20} MiB" if mallopt(param, value) == 1 else f"{what} threshold refused"
            for what, param, value in (("mmap", M_MMAP_THRESHOLD, mmap_threshold),
                                       ("trim", M_TRIM_THRESHOLD, trim_threshold))]
    _applied = "glibc: " + ", ".join(said)
    return _applied


def _glibc_mallopt():
    """glibc's mallopt, or None where the C library is another (no gnu_get_libc_version)."""
    name = ctypes.util.find_library("c")
    try:
        libc = ctypes.CDLL(name)
        libc.gnu_get_libc_version  # noqa: B018  (only glibc has it)
        mallopt = libc.mallopt
    except (OSError, AttributeError, TypeError):
        return None
    mallopt.argtypes, mallopt.restype = [ctypes.c_int, ctypes.c_int], ctypes.c_int
    return mallopt
