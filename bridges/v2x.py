"""What the V2X air and the apps agree on: bus keys, trace-stamp names and the latency stages.

The RSU app, the AV app, the master's air and the metrics all name these once,
here, so a stamp written by one process is read by another under the same name.

Keys (relative to the run prefix)::

    v2x/tx/<station>   app -> air     an encoded frame (J2735 in the 1609.2 envelope) at its t_sim
    v2x/rx/<station>   air -> app     the same bytes at their simulated arrival time, if delivered
    trace/<app>        app -> master  one JSON record per frame the app finished with (its stamps)

Trace stamps travel in the bridge envelope (`Message.stamps`, int64), never in
the J2735 bytes, so the wire format stays standard. Each stamp is a
*simulation* time in integer nanoseconds (`stamp_ns(t)`): in lockstep the
latency policy decides it (fixed per-stage latencies, or the app's measured
compute time added to its input's time); in realtime runs it is the
simulation time read off the master's clock mapping, so it is the wall clock
scaled by the real-time factor. A frame carries forward every stamp it was
given and adds its own, so the record at the end of the chain holds them all.
"""
from __future__ import annotations

import math

TX_KEY = "v2x/tx/{}"
RX_KEY = "v2x/rx/{}"
TRACE_KEY = "trace/{}"


def tx_key(station: str) -> str:
    """Where station `station` publishes what it transmits."""
    return TX_KEY.format(station)


def rx_key(station: str) -> str:
    """Where the air delivers what station `station` receives."""
    return RX_KEY.format(station)


def trace_key(app: str) -> str:
    """Where app `app` publishes its trace records (JSON: the stamps of one finished frame)."""
    return TRACE_KEY.format(app)


# -- trace stamps, in the order a camera frame's information passes through the chain --------------
FRAME = "frame"                # the camera frame's simulation time (the RSU app copies it)
DETECT_START = "detect_start"  # RSU: the detector started on that frame
DETECT_END = "detect_end"      # RSU: detections ready (projected to the ground, tracked)
ENCODE = "encode"              # RSU: the J2735 message is encoded (UPER)
SIGN = "sign"                  # RSU: wrapped in the signed 1609.2 envelope
SEND = "send"                  # RSU: published on v2x/tx (the frame's t_sim)
AIR_ARRIVAL = "air_arrival"    # air: delivered to the receiver (the rx message's t_sim)
RECEIVE = "receive"            # AV: taken off v2x/rx
VERIFY = "verify"              # AV: envelope verified
DECODE = "decode"              # AV: J2735 decoded into a typed message
FUSE = "fuse"                  # AV: the object is in the fused object list
PLAN = "plan"                  # AV: the speed plan that used it is ready
CAN_COMMAND = "can_command"    # AV: the AV_Command frame computed from that plan went out
CAN_APPLIED = "can_applied"    # master: the gateway applied that command to the vehicle model

STAMPS = (FRAME, DETECT_START, DETECT_END, ENCODE, SIGN, SEND, AIR_ARRIVAL, RECEIVE, VERIFY, DECODE, FUSE,
          PLAN, CAN_COMMAND, CAN_APPLIED)

# latency stages of the case study (DESIGN: the seed paper's stages 1, 2, 3), as (from stamp, to stamp)
STAGES = {
    "stage1": (FRAME, DETECT_END),        # camera frame -> objects (the paper: 3600 ms on a CPU)
    "stage2": (DETECT_END, SEND),         # objects -> signed BSM on the air (the paper: 8.1 ms)
    "air": (SEND, AIR_ARRIVAL),           # the radio channel
    "stage3": (AIR_ARRIVAL, CAN_COMMAND), # receive -> verify -> decode -> fuse -> plan -> CAN (the paper: 19 ms)
    "e2e": (FRAME, CAN_APPLIED),          # camera frame -> command applied to the vehicle
}


# -- the UTC instant of a simulation time -------------------------------------------------------------
# J2735 secMark and the 1609.2 generation time are UTC. The master tells every app, in its join reply
# (Welcome.world[EPOCH]), the Unix time that simulation time 0 stands for (the wall clock when the run
# opened its bus), so the apps stamp and check messages on one calendar, and certificates issued for
# the run are valid at its simulated instants.
EPOCH = "epoch_unix_s"


def unix_time(t_sim: float, epoch_unix_s: float) -> float:
    """The Unix time (s) of simulation time `t_sim` in a run whose time 0 is `epoch_unix_s`."""
    return epoch_unix_s + t_sim


def stamp_ns(t_sim: float) -> int:
    """A simulation time (s) as a trace stamp (int ns); ValueError for a non-finite time."""
    if not math.isfinite(t_sim):
        raise ValueError(f"a trace stamp needs a finite time, got {t_sim!r}")
    return round(t_sim * 1e9)


def stamp_s(ns: int) -> float:
    """A trace stamp back in simulation seconds."""
    return ns / 1e9


def stage_ms(stamps: dict[str, int], stage: str) -> float | None:
    """The duration of `stage` (a key of STAGES) in ms from a record's stamps; None when one end is missing."""
    start, end = STAGES[stage]
    if start not in stamps or end not in stamps:
        return None
    return (stamps[end] - stamps[start]) / 1e6
