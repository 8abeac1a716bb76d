"""The AV app's settings: one dataclass per TOML table, validated with every problem named by key.

Precedence (apps_contract.md): command-line flag > config file (`--config`) >
bus environment (V2I_NAME, V2I_BUS, ...) > the defaults below. Unknown keys are
refused with a "did you mean"; a value of the wrong type or out of range names
its key and what was expected. `ConfigError.problems` holds every problem, so
a user fixes a file in one go (the CLI prints them and exits 2).

Paths in the file (the trust anchor, a DBC) are relative to the file's folder.
"""
from __future__ import annotations

import difflib
import math
import os
import tomllib
from dataclasses import dataclass, field, fields, is_dataclass, replace
from pathlib import Path
from typing import Any


class ConfigError(ValueError):
    """A bad configuration: `problems` lists "key: reason" for each fault."""

    def __init__(self, problems: list[str], source: str = "config"):
        self.problems, self.source = list(problems), source
        super().__init__(f"{source}: " + "; ".join(self.problems))


def _f(default, doc: str, *, low: float | None = None, high: float | None = None, positive: bool = False,
       choices: tuple | None = None):
    """A field with its documentation and range (read by the validator and by `--help`)."""
    meta = {"doc": doc, "low": low, "high": high, "positive": positive, "choices": choices}
    if isinstance(default, list):
        return field(default_factory=lambda: list(default), metadata=meta)
    return field(default=default, metadata=meta)


@dataclass(frozen=True)
class AppSection:
    name: str = _f("", "participant name on the bus (default: $V2I_NAME, else 'cav')")
    role: str = _f("", "role announced to the master (default: $V2I_ROLE, else 'av_app')")
    station: str = _f("", "V2X station whose air this app hears (default: the participant name)")
    vehicle: str = _f("", "world vehicle whose lidar/<vehicle> and gnss/<vehicle> streams are ours (default: name)")
    stats_every_s: float = _f(5.0, "wall seconds between stats lines on stderr (0: none)", low=0.0)
    join_timeout_s: float = _f(30.0, "wall seconds to wait for the master's welcome", positive=True)
    plan_log: str = _f("", "write one JSON line per plan (ego, objects, conflicts, decision) to this file")
    sensor_wait_s: float = _f(2.0, "lockstep: wall seconds to wait for a lidar scan, GNSS fix or AV_Status "
                                    "that is due at a tick but has not arrived", low=0.0)


@dataclass(frozen=True)
class BusSection:
    transport: str = _f("", "zenoh | udp | memory (default: $V2I_BUS)")
    prefix: str = _f("", "run prefix of every key (default: $V2I_PREFIX)")
    connect: list = _f([], "endpoints to connect to, e.g. ['tcp/192.168.1.10:7447'] (default: $V2I_CONNECT)")


@dataclass(frozen=True)
class SecuritySection:
    trust_anchor: str = _f("", "the scenario CA certificate (v2i pki init writes v2i-scenario-ca.cert); "
                                "required unless allow_unsecured")
    max_age_s: float = _f(0.5, "oldest accepted 1609.2 generation time, s before the arrival", positive=True)
    max_future_s: float = _f(0.05, "newest accepted generation time, s after the arrival", low=0.0)
    allow_unsecured: bool = _f(False, "accept unsigned frames (lab only)")


@dataclass(frozen=True)
class ObuSection:
    max_age_s: float = _f(1.0, "drop a V2X object whose measurement (BSM secMark) is older than this", positive=True)
    default_length: float = _f(4.5, "object length when a BSM says 'unavailable', m", positive=True)
    default_width: float = _f(1.8, "object width when a BSM says 'unavailable', m", positive=True)
    position_sigma: float = _f(1.0, "position std of a BSM without accuracy, m (fusion weight)", positive=True)
    sdsm_psids: list = _f([0x90], "PSIDs an SDSM may be signed under (deployments differ: 0x90, or its "
                                   "1609.12 p-encoded form written 0x8010)")
    self_gate_m: float = _f(2.5, "an RSU's surrogate BSM whose centre is within this distance of the ego's own "
                                 "centre describes the ego itself (any speed and heading: the footprints would "
                                 "overlap), not an obstacle; a vehicle's own BSM (PSID 0x20) also needs the ego's "
                                 "heading (30 deg) and speed (2 m/s); 0: no BSM is the ego, m", low=0.0)
    self_hold_factor: float = _f(2.0, "a surrogate BSM id once recognised as the ego stays the ego while its centre "
                                      "is within this many self_gate_m of the ego's (and its heading within "
                                      "self_hold_heading_deg); beyond, the id is forgotten", low=1.0)
    self_hold_heading_deg: float = _f(45.0, "heading agreement an id held as the ego needs, deg", low=0.0,
                                      high=180.0)
    self_hold_lag_s: float = _f(1.5, "... or within it of a heading the ego had in this last while: an RSU's "
                                     "constant-velocity track lags a turn (measured 45 deg behind just after the "
                                     "case study's right turn), s", low=0.0)
    self_hold_slow_speed: float = _f(1.5, "an id held as the ego needs no heading agreement while it or the ego is "
                                          "slower than this (a standing vehicle's track heading is noise), m/s",
                                     low=0.0)


@dataclass(frozen=True)
class PerceptionSection:
    enabled: bool = _f(True, "run the lidar pipeline")
    rate_hz: float = _f(10.0, "lockstep: the lidar's scan rate, to wait for a scan that is due (0: never wait)",
                        low=0.0)
    ground_z: float = _f(0.3, "points below this height above the road are ground (the kerb is 0.15 m)", low=0.0)
    max_z: float = _f(4.0, "points above this height are ignored (overhead structure), m", positive=True)
    min_range: float = _f(1.0, "ignore returns closer than this (horizontal), m", low=0.0)
    max_range: float = _f(80.0, "ignore returns farther than this (horizontal), m", positive=True)
    voxel: float = _f(0.15, "2-D voxel size of the bird's-eye downsampling before clustering, m", positive=True)
    cluster_tolerance: float = _f(0.7, "Euclidean clustering distance, m", positive=True)
    min_points: int = _f(3, "smallest cluster (occupied voxels) that makes an obstacle", low=1)
    static_length: float = _f(9.0, "a cluster whose box is longer than this is static structure, m", positive=True)
    static_width: float = _f(4.0, "a cluster whose box is wider than this is static structure, m", positive=True)
    road_margin_m: float = _f(2.0, "a cluster whose centre is farther than this beyond the kerb (off the roads "
                                    "the master describes) is static structure (0: keep every cluster)", low=0.0)
    gate_m: float = _f(2.5, "association gate between a track's prediction and a cluster, m", positive=True)
    fragments: bool = _f(True, "a cluster whose centre is inside the footprint of a track that took another "
                               "cluster of the scan is a piece of that vehicle (an occluder split it), not a new "
                               "track")
    fragment_margin_m: float = _f(0.5, "how far beyond a track's footprint (its longest and widest box, along "
                                       "its motion) a piece's centre may lie, m", low=0.0)
    confirm_scans: int = _f(2, "scans a track needs before it is reported", low=1)
    max_missed: int = _f(2, "scans a track survives without a cluster", low=0)
    accel_noise: float = _f(4.0, "track filter process noise (m/s^2, white acceleration)", positive=True)
    measurement_sigma: float = _f(0.3, "cluster-centre measurement std, m", positive=True)


@dataclass(frozen=True)
class FusionSection:
    gate_m: float = _f(3.0, "a V2X object and a lidar track closer than this (plus half of what the lidar box "
                                   "misses of the BSM's size) are one object, m", positive=True)
    lidar_sigma: float = _f(0.3, "position std of a lidar track, m (fusion weight)", positive=True)


@dataclass(frozen=True)
class EgoSection:
    gnss_rate_hz: float = _f(10.0, "lockstep: GNSS fix rate, to wait for a fix that is due (0: never wait)", low=0.0)
    gnss_sigma_h: float = _f(0.5, "GNSS horizontal std per axis, m", positive=True)
    gnss_sigma_heading_deg: float = _f(1.0, "GNSS heading std, deg", positive=True)
    gnss_sigma_speed: float = _f(0.1, "GNSS speed std, m/s", positive=True)
    status_sigma_speed: float = _f(0.02, "AV_Status speed std, m/s", positive=True)
    status_sigma_yaw_rate: float = _f(0.005, "AV_Status yaw-rate std, rad/s", positive=True)
    accel_noise: float = _f(2.0, "process noise: longitudinal acceleration std, m/s^2", positive=True)
    yaw_accel_noise: float = _f(1.0, "process noise: yaw acceleration std, rad/s^2", positive=True)
    stale_s: float = _f(1.0, "no GNSS fix for this long (sim s): state DEGRADED", positive=True)


@dataclass(frozen=True)
class VehicleSection:
    length: float = _f(4.5, "body length, m", positive=True)
    width: float = _f(1.8, "body width, m", positive=True)
    rear_overhang: float = _f(0.95, "body behind the rear axle, m", low=0.0)
    wheelbase: float = _f(2.3927, "m", positive=True)
    max_steer: float = _f(0.91, "front-wheel angle limit, rad", positive=True, high=1.5)
    max_accel: float = _f(2.0, "largest acceleration the planner asks for, m/s^2", positive=True)
    max_decel: float = _f(8.0, "hardest braking the planner asks for (the vehicle's limit), m/s^2", positive=True)
    road_load_c0: float = _f(0.1177, "road load at standstill speed (rolling), m/s^2: fed forward", low=0.0)
    road_load_c2: float = _f(3.23e-4, "road load per (m/s)^2 (drag), m/s^2: fed forward", low=0.0)


@dataclass(frozen=True)
class RouteSection:
    waypoints: list = _f([[1.75, -120.0], [1.75, -1.75], [120.0, -1.75]],
                         "lane-centre polyline [[x, y], ...] in local metres (x east, y north)")
    corner_radius: float = _f(6.0, "radius of the arc that rounds each corner of the polyline, m", positive=True)
    cruise_speed: float = _f(8.333, "speed on straight road, m/s (30 km/h)", positive=True)
    lateral_accel_max: float = _f(2.0, "the speed in curves keeps v^2 * curvature below this, m/s^2",
                                  positive=True)


@dataclass(frozen=True)
class CoverageSection:
    edges: list = _f([], "where the RSU's detection coverage ends on each approach whose traffic crosses or joins "
                         "the route: [[x, y, heading_deg, speed], ...] (local metres, the approach's lane centre; its "
                         "travel heading, degrees CCW from east; its design speed, m/s: the limit plus a margin). "
                         "While the RSU is heard a phantom vehicle stands there at that speed: what the RSU cannot "
                         "see is not empty")
    max_silence_s: float = _f(1.5, "phantoms only while a V2X frame was heard within this (the RSU sends a MAP "
                                   "every second): without the RSU its coverage says nothing", positive=True)
    length: float = _f(4.5, "a phantom's length, m", positive=True)
    width: float = _f(1.8, "a phantom's width, m", positive=True)


@dataclass(frozen=True)
class ControlSection:
    lookahead_min_m: float = _f(3.0, "pure pursuit: shortest look-ahead, m", positive=True)
    lookahead_time_s: float = _f(0.6, "pure pursuit: look-ahead = max(min, speed * this)", low=0.0)
    speed_kp: float = _f(1.0, "longitudinal: acceleration per m/s of speed error, 1/s", low=0.0)
    accel_comfort: float = _f(1.5, "acceleration of the speed profile, m/s^2", positive=True)
    decel_curve: float = _f(1.5, "deceleration before curves, m/s^2", positive=True)
    decel_stop: float = _f(2.0, "planned deceleration to stop before a conflict or a red light, m/s^2",
                           positive=True)
    decel_comfort: float = _f(3.0, "the most a stop may need and still count as comfortable; beyond it the "
                                   "planner brakes as hard as needed, up to vehicle.max_decel (m/s^2)",
                              positive=True)
    hold_decel: float = _f(1.5, "braking that holds the vehicle at standstill, m/s^2", positive=True)


@dataclass(frozen=True)
class PlannerSection:
    horizon_s: float = _f(6.0, "prediction horizon of the collision estimator, s", positive=True)
    dt_s: float = _f(0.1, "prediction time step, s", positive=True)
    path_ds: float = _f(0.5, "station step of the ego path, m", positive=True)
    margin_m: float = _f(0.4, "safety margin added on every side of both footprints, m", low=0.0)
    pet_margin_s: float = _f(1.5, "yield when the post-encroachment time would be shorter, s", low=0.0)
    pet_margin_emergency_s: float = _f(3.0, "the same for an emergency vehicle (give way), s", low=0.0)
    pet_margin_emergency_merge_s: float = _f(2.5, "... where the ego would join the emergency vehicle's lane ahead "
                                                  "of it (turning into it, then speeding up ahead of it) rather "
                                                  "than cross its path, s", low=0.0)
    stop_margin_m: float = _f(1.0, "stop this far before the conflict zone, m", low=0.0)
    stationary_speed: float = _f(0.5, "objects slower than this are predicted standing still, m/s", low=0.0)
    ignore_behind_m: float = _f(0.0, "objects behind the ego's rear in its lane and going its way are its "
                                     "followers' business: not yielded to", low=0.0)
    lane_prediction: bool = _f(True, "predict a moving object on a road arm along its lane when its heading is "
                                      "within 45 degrees of it (map-based prediction)")
    motion: str = _f("ctrv", "object prediction: cv (constant velocity) or ctrv (constant turn rate)",
                     choices=("cv", "ctrv"))
    merge_gap_s: float = _f(1.0, "going on through a conflict zone (instead of yielding) is safe when the object, "
                                 "holding its speed, reaches every station the ego occupies through the zone and "
                                 "the merge at least this long after the ego has left it, s", low=0.0)
    merge_gap_m: float = _f(5.0, "... and at least this many metres behind it (at the object's speed), m", low=0.0)
    merge_heading_deg: float = _f(15.0, "the merge into an object's lane ends where the ego's path heads within "
                                        "this of the object's heading (plus one vehicle length); beyond, the object "
                                        "follows the ego", positive=True, high=90.0)
    slow_yield: bool = _f(True, "give way by slowing down (the highest speed, in steps of 0.1 m/s, at which the object "
                                "passes first and the PET margin holds) before stopping for it; the object must "
                                "leave the zone within the horizon")
    slow_yield_min_speed: float = _f(2.0, "... down to this speed; below it a stop before the zone is the plan, m/s",
                                     positive=True)
    slow_yield_horizon_s: float = _f(10.0, "... judged on the objects predicted this far ahead (a slower ego arrives "
                                           "later than horizon_s looks), s", positive=True)
    speed_window_s: float = _f(2.0, "a slow-down is judged on the object's speed fitted to its reported positions "
                                    "over this long (a reported speed's noise moves its passage by tenths of a "
                                    "second); 0: the reported speed", low=0.0)
    escape_speed_max: float = _f(22.222, "ahead of a faster vehicle in its lane (after merging ahead of it, or "
                                         "with one closing from behind) the ego speeds up to its speed, up to "
                                         "this (80 km/h), m/s", positive=True)
    escape_accel: float = _f(4.0, "... at this acceleration (also when going on through a conflict zone); the "
                                  "case study's vehicle can do 11.5 m/s^2 below 4.8 m/s and is power-limited "
                                  "above (fmus/vehicle: 6.8 m/s^2 at 8 m/s, 3.3 at 16.7), m/s^2", positive=True)


@dataclass(frozen=True)
class SignalsSection:
    enabled: bool = _f(True, "stop at a red signal group of the ego's approach (needs SPaT and MAP)")
    max_age_s: float = _f(1.0, "a SPaT older than this is not used, s", positive=True)


@dataclass(frozen=True)
class CanSection:
    interface: str = _f("udp_multicast", "python-can interface (udp_multicast, virtual, socketcan, pcan, ...)")
    channel: str = _f("", "channel / multicast group (default per interface)")
    port: int = _f(0, "udp_multicast port (0: 43113); must match the scenario's [can] port", low=0, high=65535)
    iface: str = _f("127.0.0.1", "udp_multicast: IPv4 address of the interface to join on")
    bitrate: int = _f(0, "real buses: bit/s (0: the adapter's)", low=0)
    dbc: str = _f("", "a DBC with the cav.dbc names (default: bridges/can/cav.dbc)")
    status_rate_hz: float = _f(50.0, "the gateway's AV_Status rate (lockstep: a status is due at these times)",
                               positive=True)
    heartbeat_hz: float = _f(10.0, "AV_Heartbeat rate (sim time; 0: none)", low=0.0)


@dataclass(frozen=True)
class LatencySection:
    """Fixed-policy charges for stages the scenario's [participants.NAME] latencies do not give."""

    verify: float = _f(0.001, "fixed policy: simulated s from receive to verified", low=0.0)
    decode: float = _f(0.0003, "fixed policy: s from verified to decoded and in local metres", low=0.0)
    fuse: float = _f(0.0003, "fixed policy: s from decoded to in the fused object list", low=0.0)
    plan: float = _f(0.001, "fixed policy: s from a status tick to the plan", low=0.0)
    can_command: float = _f(0.0002, "fixed policy: s from the plan to the AV_Command on the bus", low=0.0)
    perception: float = _f(0.03, "fixed policy: s from a lidar scan to its obstacles", low=0.0)


@dataclass(frozen=True)
class AvConfig:
    app: AppSection = field(default_factory=AppSection)
    bus: BusSection = field(default_factory=BusSection)
    security: SecuritySection = field(default_factory=SecuritySection)
    obu: ObuSection = field(default_factory=ObuSection)
    perception: PerceptionSection = field(default_factory=PerceptionSection)
    fusion: FusionSection = field(default_factory=FusionSection)
    ego: EgoSection = field(default_factory=EgoSection)
    vehicle: VehicleSection = field(default_factory=VehicleSection)
    route: RouteSection = field(default_factory=RouteSection)
    coverage: CoverageSection = field(default_factory=CoverageSection)
    control: ControlSection = field(default_factory=ControlSection)
    planner: PlannerSection = field(default_factory=PlannerSection)
    signals: SignalsSection = field(default_factory=SignalsSection)
    can: CanSection = field(default_factory=CanSection)
    latency: LatencySection = field(default_factory=LatencySection)
    base_dir: Path = field(default=Path("."), metadata={"internal": True})

    def path(self, value: str) -> Path | None:
        """A path from the config, relative to the config file's folder; None for ''."""
        if not value:
            return None
        p = Path(value).expanduser()
        return p if p.is_absolute() else self.base_dir / p

    def to_dict(self) -> dict[str, Any]:
        return {s.name: {f.name: getattr(getattr(self, s.name), f.name) for f in fields(getattr(self, s.name))}
                for s in fields(self) if not s.metadata.get("internal")}


SECTIONS = {f.name: f.default_factory for f in fields(AvConfig) if not f.metadata.get("internal")}


def _did_you_mean(word: str, options) -> str:
    close = difflib.get_close_matches(word, list(options), n=1, cutoff=0.6)
    return f" (did you mean '{close[0]}'?)" if close else ""


def _check(key: str, value: Any, default: Any, meta: dict, problems: list[str]) -> Any:
    """`value` converted to the default's type, or a problem recorded (returns the default then)."""
    kind = type(default)
    if kind is bool:
        if not isinstance(value, bool):
            problems.append(f"{key}: expected true or false, got {value!r}")
            return default
        return value
    if kind in (int, float):
        if isinstance(value, bool) or not isinstance(value, (int, float)) or (kind is int and not isinstance(value, int)):
            problems.append(f"{key}: expected {'an integer' if kind is int else 'a number'}, got {value!r}")
            return default
        if not math.isfinite(value):
            problems.append(f"{key}: expected a finite number, got {value!r}")
            return default
        low, high = meta.get("low"), meta.get("high")
        if meta.get("positive") and value <= 0:
            problems.append(f"{key}: expected a number > 0, got {value!r}")
            return default
        if low is not None and value < low or high is not None and value > high:
            span = f"{low if low is not None else '-inf'}..{high if high is not None else 'inf'}"
            problems.append(f"{key}: expected {span}, got {value!r}")
            return default
        return kind(value)
    if kind is str:
        if not isinstance(value, str):
            problems.append(f"{key}: expected a string, got {value!r}")
            return default
        choices = meta.get("choices")
        if choices and value not in choices:
            problems.append(f"{key}: expected one of {', '.join(choices)}, got {value!r}{_did_you_mean(value, choices)}")
            return default
        return value
    if kind is list:
        if not isinstance(value, list):
            problems.append(f"{key}: expected a list, got {value!r}")
            return default
        return list(value)
    raise TypeError(f"no check for {kind}")  # a field type this module forgot


def _section(name: str, table: Any, problems: list[str]):
    cls = SECTIONS[name]
    base = cls()
    if not isinstance(table, dict):
        problems.append(f"{name}: expected a table, got {type(table).__name__}")
        return base
    known = {f.name: f for f in fields(cls)}
    values = {}
    for key, value in table.items():
        if key not in known:
            problems.append(f"{name}.{key}: unknown key{_did_you_mean(key, known)} "
                            f"(keys of [{name}]: {', '.join(known)})")
            continue
        f = known[key]
        values[key] = _check(f"{name}.{key}", value, getattr(base, key), dict(f.metadata), problems)
    return replace(base, **values)


def _semantic(cfg: AvConfig, problems: list[str]) -> None:
    """Checks across keys: route geometry, vehicle geometry, file paths."""
    wps = cfg.route.waypoints
    ok = len(wps) >= 2 and all(isinstance(p, list) and len(p) == 2 and all(
        isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) for v in p) for p in wps)
    if not ok:
        problems.append(f"route.waypoints: expected at least two [x, y] pairs of finite numbers, got {wps!r}")
    else:
        for i, (a, b) in enumerate(zip(wps, wps[1:])):
            if math.dist(a, b) < 1e-6:
                problems.append(f"route.waypoints: points {i} and {i + 1} coincide ({a})")
    edges = cfg.coverage.edges
    if not isinstance(edges, list):
        problems.append(f"coverage.edges: expected a list of [x, y, heading_deg, speed], got {edges!r}")
    else:
        for i, e in enumerate(edges):
            ok = isinstance(e, list) and len(e) == 4 and all(
                isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) for v in e)
            if not ok:
                problems.append(f"coverage.edges[{i}]: expected [x, y, heading_deg, speed] as finite numbers, "
                                f"got {e!r}")
            elif e[3] <= 0:
                problems.append(f"coverage.edges[{i}]: the speed must be > 0, got {e[3]!r}")
    psids = cfg.obu.sdsm_psids
    if not psids or not all(isinstance(v, int) and not isinstance(v, bool) and 0 <= v <= 0xFFFFFFFF for v in psids):
        problems.append(f"obu.sdsm_psids: expected a list of PSIDs (integers 0..0xFFFFFFFF), got {psids!r}")
    if cfg.vehicle.rear_overhang >= cfg.vehicle.length:
        problems.append(f"vehicle.rear_overhang: {cfg.vehicle.rear_overhang} must be shorter than vehicle.length "
                        f"{cfg.vehicle.length}")
    if cfg.perception.ground_z >= cfg.perception.max_z:
        problems.append(f"perception.max_z: must be above perception.ground_z ({cfg.perception.ground_z})")
    if cfg.perception.min_range >= cfg.perception.max_range:
        problems.append(f"perception.max_range: must be above perception.min_range ({cfg.perception.min_range})")
    if cfg.planner.dt_s > cfg.planner.horizon_s:
        problems.append(f"planner.dt_s: {cfg.planner.dt_s} is longer than planner.horizon_s {cfg.planner.horizon_s}")
    if not cfg.security.trust_anchor and not cfg.security.allow_unsecured:
        problems.append("security.trust_anchor: required (the scenario CA certificate, e.g. "
                        "keys/v2i-scenario-ca.cert from `v2i pki init keys`) unless security.allow_unsecured = true")
    for key, value in (("security.trust_anchor", cfg.security.trust_anchor), ("can.dbc", cfg.can.dbc)):
        p = cfg.path(value)
        if p is not None and not p.is_file():
            problems.append(f"{key}: no such file: {p}")
    for key, value in (("app.name", cfg.app.name), ("app.station", cfg.app.station), ("app.vehicle", cfg.app.vehicle)):
        if value and ("/" in value or "*" in value or value.strip() != value):
            problems.append(f"{key}: {value!r} must be one key chunk (no '/', '*' or spaces)")


def build(tables: dict[str, Any] | None = None, *, base_dir: Path | str = ".", source: str = "config",
          environ=os.environ) -> AvConfig:
    """An AvConfig from TOML-like tables (unknown tables and keys refused), env defaults filled in.

    `tables` is what a config file holds, with flags already merged on top (flag > file); the
    environment fills what neither gave (V2I_NAME, V2I_ROLE, V2I_BUS, V2I_PREFIX, V2I_CONNECT).
    """
    tables = dict(tables or {})
    problems: list[str] = []
    sections = {}
    for name, table in tables.items():
        if name not in SECTIONS:
            problems.append(f"{name}: unknown table{_did_you_mean(name, SECTIONS)} (tables: {', '.join(SECTIONS)})")
            continue
        sections[name] = _section(name, table, problems)
    cfg = AvConfig(**sections, base_dir=Path(base_dir))
    app, bus = cfg.app, cfg.bus
    name = app.name or environ.get("V2I_NAME") or "cav"
    app = replace(app, name=name, role=app.role or environ.get("V2I_ROLE") or "av_app",
                  station=app.station or name, vehicle=app.vehicle or name)
    connect = bus.connect or [c.strip() for c in environ.get("V2I_CONNECT", "").split(",") if c.strip()]
    bus = replace(bus, transport=bus.transport or environ.get("V2I_BUS", ""),
                  prefix=bus.prefix or environ.get("V2I_PREFIX", ""), connect=connect)
    if not all(isinstance(c, str) for c in bus.connect):
        problems.append(f"bus.connect: expected a list of endpoint strings, got {bus.connect!r}")
    cfg = replace(cfg, app=app, bus=bus)
    _semantic(cfg, problems)
    if problems:
        raise ConfigError(problems, source)
    return cfg


def load(path: str | Path | None = None, overrides: dict[str, dict[str, Any]] | None = None,
         environ=os.environ) -> AvConfig:
    """The config from a TOML file (or none) with `overrides` (from flags) on top; ConfigError on faults."""
    tables: dict[str, Any] = {}
    base_dir = Path(".")
    source = "config"
    if path is not None:
        path = Path(path)
        source = str(path)
        try:
            tables = tomllib.loads(path.read_text())
        except OSError as exc:
            raise ConfigError([f"cannot read: {exc.strerror}"], source) from None
        except tomllib.TOMLDecodeError as exc:
            raise ConfigError([f"not valid TOML: {exc}"], source) from None
        base_dir = path.resolve().parent
    for section, values in (overrides or {}).items():
        if isinstance(tables.get(section), dict):
            tables[section] = {**tables[section], **values}
        else:
            tables[section] = dict(values)
    return build(tables, base_dir=base_dir, source=source, environ=environ)


def describe() -> str:
    """Every table and key with its default and meaning (for --help)."""
    lines = []
    for name, cls in SECTIONS.items():
        lines.append(f"[{name}]")
        for f in fields(cls):
            default = getattr(cls(), f.name)
            lines.append(f"  {f.name} = {default!r}: {f.metadata.get('doc', '')}")
    return "\n".join(lines)


__all__ = ["AvConfig", "ConfigError", "SECTIONS", "build", "load", "describe"]
assert all(is_dataclass(c) for c in SECTIONS.values())
