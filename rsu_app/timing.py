"""How much simulated time each stage of the RSU costs: the run's latency policy, or a hardware profile.

Stage names (what a scenario's `[participants.NAME] latencies = {...}` sets
under the `fixed` policy): ``detect`` (stage 1: frame -> objects ready:
detected, projected to the ground, tracked), ``encode`` (J2735 UPER) and
``sign`` (1609.2); optionally ``radar`` (a radar scan's objects ready). Stage 2 of the seed paper is encode + sign (+ the send,
which costs no simulated time here: the air adds the radio's own latency).

* lockstep, ``fixed``: the configured value, whatever the computer did, so a
  run repeats bit for bit; a stage the scenario leaves out costs 0 (logged once).
* lockstep, ``measured``: the wall-clock compute time of the stage.
* realtime: the wall-clock compute time scaled by the run clock's rate when the
  stage ends (the real-time factor; lower while the clock slews after a slip).
* a hardware profile (``--hardware``, ``--inference-s``) replaces stage 1 in
  every mode by a fixed inference time per frame, so one run can ask "would
  this RSU computer be fast enough?" (the seed paper's CPU at 0.27 FPS, FPGA at
  10 FPS, GPU at 30 FPS: ANCHORS I7). Frames that arrive while the detector is
  busy in simulated time are dropped (`camera.BusyGate`).
"""
from __future__ import annotations

import logging

log = logging.getLogger(__name__)

DETECT, ENCODE, SIGN = "detect", "encode", "sign"
STAGE_NAMES = (DETECT, ENCODE, SIGN)
RADAR = "radar"  # a radar scan's objects -> ground points: optional under `fixed` (default 0, no warning): the
                 # radar did its own detection before it sent the scan, what is left costs microseconds


class LatencyModel:
    def __init__(self, mode: str, policy: str, latencies: dict[str, float] | None = None,
                 inference_s: float | None = None, rtf: float = 1.0):
        if mode not in ("lockstep", "realtime"):
            raise ValueError(f"mode must be lockstep or realtime, got {mode!r}")
        if mode == "lockstep" and policy not in ("fixed", "measured"):
            raise ValueError(f"latency policy must be fixed or measured, got {policy!r}")
        self.mode, self.policy = mode, policy if mode == "lockstep" else "realtime"
        self.latencies = {k: float(v) for k, v in (latencies or {}).items()}
        self.inference_s = inference_s
        self.rtf = float(rtf) if rtf and rtf > 0 else 1.0
        # realtime: where the run clock's current rate comes from (the master's mapping, which changes while
        # the clock slews after a slip); read when a stage ends, so a stage that spans the change is charged
        # at the rate the clock ran when it ended, not at the rate when the step began
        self.rate_source = None
        self.missing: set[str] = set()

    def describe(self) -> dict:
        out = {"mode": self.mode, "policy": self.policy}
        if self.policy == "fixed":
            out["latencies_s"] = {s: self.latencies.get(s, 0.0) for s in STAGE_NAMES}
            if self.missing:
                out["missing_stages"] = sorted(self.missing)
        if self.policy == "realtime":
            out["rtf"] = self.rtf  # simulated seconds per wall second the stages are charged at
        if self.inference_s is not None:
            out["inference_s"] = self.inference_s
        return out

    def stage(self, name: str, compute_s: float) -> float:
        """Simulated seconds charged for stage `name` that took `compute_s` wall seconds."""
        if name == DETECT and self.inference_s is not None:
            return self.inference_s
        if self.policy == "fixed":
            if name == RADAR:
                return self.latencies.get(RADAR, 0.0)
            if name not in self.latencies:
                if name not in self.missing:
                    self.missing.add(name)
                    log.warning("no fixed latency for stage %r in the scenario (latencies = { %s = ... } in its "
                                "[participants] table): it costs 0 simulated seconds", name, name)
                return 0.0
            return self.latencies[name]
        if self.policy == "measured":
            return max(0.0, compute_s)
        if self.rate_source is not None:
            self.rtf = float(self.rate_source())
        return max(0.0, compute_s) * self.rtf  # realtime: the wall clock, in simulated seconds
