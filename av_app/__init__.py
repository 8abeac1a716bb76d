"""The connected automated vehicle's software, stage 3 of the IMA case study (docs/av_app.md).

A process (`python -m av_app`, `v2i-av`) that imports only `bridges` of the
project, so the same code runs beside the master on loopback or on an AV
computer over Ethernet and a real CAN adapter:

    V2X air --> obu (verify 1609.2, decode J2735, local metres)  --+
    lidar   --> perception (crop, grid, Euclidean clusters, boxes, tracks) --> fusion --> estimator --> planner
    GNSS + AV_Status --> ego (UKF)                                                 route + pure pursuit --+
                                                                     can_driver: AV_Command (echo), heartbeat

Modules, one job each: `config` (TOML + flags, every problem by key),
`obu`, `selfid` (which BSMs are the ego itself), `perception`, `fusion`,
`ego`, `route` (and pure pursuit), `lanes` (map-based prediction),
`estimator` (swept-box conflicts: TTC, PET), `planner` (speed profile, yield,
control), `signals` (MAP + SPaT), `can_driver`,
`timing` (the stage clock), `health`; `core` ties them together without any
I/O, `app` is the process shell (bus, time protocol, CAN), `cli` the entry.

Timing model (lockstep). Inputs are used in simulated time: a V2X frame that
arrived at t_a is verified, decoded and fused at t_a + the stage latencies
(`fixed`: the scenario's `latencies` for verify/decode/fuse, else the
config's `[latency]`; `measured`: the real compute time); from that FUSE time
on, plans may use it. A lidar scan of time t_s gives obstacles from
t_s + perception. Each AV_Status of time t is answered at the tick of t by one
AV_Command computed only from inputs usable at t (PLAN = t + plan,
CAN_COMMAND = PLAN + can_command), which the gateway applies at t + one step.
So stage 3 (AIR_ARRIVAL -> CAN_COMMAND) is the charged processing plus the
wait for the next control cycle, and a lockstep run under `fixed` repeats
bit for bit.
"""
