"""The RSU app's settings: one schema for the TOML config file, the command-line flags and `--help`.

Precedence (the apps' contract): flag > config file > environment > default.
Every key is declared once below (section, name, type, default, help, and the
flag that sets it, if any), so the config file, `--set SECTION.KEY=VALUE`,
the flags and the help text cannot drift apart. A bad value or an unknown key
is reported with every problem at once, each naming its key (with a "did you
mean" for a misspelt one); the process then exits 2.

Config file (all keys optional; `scenarios/apps/rsu.toml` is the case study's)::

    name = "rsu"                 # participant name (default $V2I_NAME, else "rsu")
    [app]
    trace_detections = true      # a trace record of each processed frame's boxes (the report's clip)
    [detector]
    backend = "onnx"
    [tracker]
    confirm_hits = 3
    ...
"""
from __future__ import annotations

import difflib
import math
import os
import tomllib
from dataclasses import MISSING, dataclass, field, fields
from pathlib import Path
from typing import Any

# hardware profiles: a fixed inference time per frame instead of the measured or configured one (ANCHORS I7:
# the seed paper's Table 2, detection rates of YOLOv7 on its RSU computers)
HARDWARE_PROFILES: dict[str, tuple[float, str]] = {
    "cpu-i7": (1 / 0.27, "8-core Intel i7 CPU, 0.27 FPS (seed paper Table 2, ANCHORS I7)"),
    "gpu-gtx1650": (1 / 30.0, "NVIDIA GTX 1650 GPU, 30 FPS (seed paper Table 2, ANCHORS I7)"),
    "fpga-zynq7020": (1 / 10.0, "Xilinx Zynq 7020 FPGA, 10 FPS (seed paper Table 2, ANCHORS I7)"),
}
DETECTORS = ("onnx", "torch", "classical")
MOTIONS = ("cv", "ctrv")
SECURITY_MODES = ("signed", "unsecured")
POLLS = ("long", "short")
TRANSPORTS = ("zenoh", "udp", "memory")
MESSAGE_KINDS = ("surrogate_bsm", "sdsm")   # what the RSU sends of its tracks ([v2x] messages)
PSID_SDSM_DEFAULT = 0x90  # IEEE 1609.12 p-encodes it as 80-10, which deployments' configs write as 0x8010


class ConfigError(ValueError):
    """Every problem of a configuration, each as (key, reason)."""

    def __init__(self, problems: list[tuple[str, str]]):
        self.problems = problems
        super().__init__("\n".join(f"{k}: {why}" for k, why in problems))


def _key(help: str, flag: str | None = None, choices=None, low=None, high=None, positive=False, env=None):
    return {"help": help, "flag": flag, "choices": choices, "low": low, "high": high, "positive": positive,
            "env": env}


@dataclass
class AppSettings:
    trace_detections: bool = field(default=True, metadata=_key(
        "publish one \"detections\" trace record per processed camera frame on trace/<name> (boxes, labels, "
        "scores, track and BSM ids): the run's trace.jsonl keeps it and `v2i report` draws it on the camera clip"))


@dataclass
class BusSettings:
    transport: str | None = field(default=None, metadata=_key(
        "bus backend: zenoh, udp or memory (default $V2I_BUS)", "--bus", choices=TRANSPORTS, env="V2I_BUS"))
    prefix: str | None = field(default=None, metadata=_key(
        "key prefix of the run, e.g. v2i/lab1 (default $V2I_PREFIX)", "--prefix", env="V2I_PREFIX"))
    connect: list[str] = field(default_factory=list, metadata=_key(
        "endpoints to connect to, e.g. tcp/10.0.0.1:7447 (default $V2I_CONNECT, comma-separated)", "--connect",
        env="V2I_CONNECT"))
    join_timeout_s: float = field(default=30.0, metadata=_key(
        "wall seconds to wait for the master's welcome", "--join-timeout", positive=True))


@dataclass
class CameraSettings:
    names: list[str] = field(default_factory=lambda: ["rsu_cam"], metadata=_key(
        "cameras to subscribe to (bus keys camera/<name>)", "--camera"))
    rate_hz: float = field(default=10.0, metadata=_key(
        "expected frame rate before two frames told it (lockstep: when the next frame is due)", positive=True))
    wait_s: float = field(default=2.0, metadata=_key(
        "lockstep: wall seconds to wait for a frame that is due before counting it late", low=0.0))


@dataclass
class RadarSettings:
    names: list[str] = field(default_factory=list, metadata=_key(
        "roadside radars to subscribe to (bus keys radar/<name>, the scenario's [world.radars]): their objects "
        "start and update tracks inside each radar's own coverage, which it states in every scan", "--radar"))
    rate_hz: float = field(default=20.0, metadata=_key(
        "expected scan rate before two scans told it (lockstep: when the next scan is due)", positive=True))
    wait_s: float = field(default=2.0, metadata=_key(
        "lockstep: wall seconds to wait for a scan that is due before counting it late", low=0.0))
    label: str = field(default="car", metadata=_key(
        "the class a radar object votes for: a radar does not tell an ambulance from a car, so a track seen only "
        "by radar is broadcast as this until a camera names it", choices=("car", "emergency")))
    score: float = field(default=0.0, metadata=_key(
        "the weight of a radar object's class vote (a camera box votes its detector score); 0: the label names "
        "only a track no camera has named, any camera box outvotes it", low=0.0, high=1.0))


@dataclass
class DetectorSettings:
    backend: str = field(default="onnx", metadata=_key(
        "detector backend", "--detector", choices=DETECTORS))
    weights: str | None = field(default=None, metadata=_key(
        "weights file (torch: .pt; onnx: .onnx or .pt); default the shipped ones", "--weights"))
    threads: int = field(default=1, metadata=_key(
        "CPU threads of the detector (torch, onnxruntime, OpenCV); 1 does not oversubscribe a 2-core machine "
        "shared with the master", "--threads", low=1, high=256))
    score_threshold: float = field(default=0.4, metadata=_key(
        "detections below this score are ignored (the operating point: lower finds more and invents more; "
        "0.4 chosen on tests/scenarios/rsu_tuning*.toml, benchmarks/rsu_app.py --tune)",
        "--score-threshold", low=0.0, high=1.0))
    background: str | None = field(default=None, metadata=_key(
        "classical backend: empty-scene image (default: learn the background, MOG2)"))
    compile: bool = field(default=False, metadata=_key(
        "torch backend: run the network through torch.compile (about 1.5x faster on a CPU core; compiling takes "
        "seconds at start and needs a C++ compiler)"))


@dataclass
class PerceptionSettings:
    max_range_m: float = field(default=60.0, metadata=_key(
        "tracks farther than this from the camera are not broadcast (box-based positions degrade with range)",
        positive=True))
    track_range_m: float = field(default=80.0, metadata=_key(
        "ground points out to this range start and update tracks (>= max_range_m), so that a vehicle's track "
        "is confirmed and settled when it enters max_range_m (80 chosen by benchmarks/rsu_app.py --tune)",
        positive=True))
    on_road_only: bool = field(default=True, metadata=_key(
        "ignore ground points off the roads of the intersection the master describes (the RSU's detection zone)"))
    road_margin_m: float = field(default=1.5, metadata=_key(
        "how far beyond the carriageway edge a ground point still counts as on the road", low=0.0))
    merge_radius_m: float = field(default=2.5, metadata=_key(
        "detections of one frame closer than this on the ground are one vehicle (0: never merge)", low=0.0))
    border_px: float = field(default=2.0, metadata=_key(
        "a box this close to the image border may update a track near it but never start one (-1: off)",
        low=-1.0))
    ground_covariance: bool = field(default=False, metadata=_key(
        "each ground point carries the covariance of its box fit (the box noise below, propagated through "
        "geo.ground_fix); false (the tuned default: the best point of the tuning sequences is without it, "
        "though with it fewer points invent tracks): every point counts as tracker.meas_std on each axis"))
    box_edge_px: float = field(default=1.0, metadata=_key(
        "std of a box edge in pixels ... (chosen on the validation set: eval-detector --ground)", positive=True))
    box_edge_rel: float = field(default=0.06, metadata=_key(
        "... plus this share of the box's width (left/right edges) or height (top/bottom)", low=0.0))
    box_cut_edge_rel: float = field(default=0.3, metadata=_key(
        "... or this share for a box cut by the image border (the detector saw part of the vehicle)", low=0.0))
    size_rel: float = field(default=0.12, metadata=_key(
        "relative std of a vehicle's length, width and height about its class's typical size", low=0.0))


@dataclass
class TrackerSettings:
    motion: str = field(default="cv", metadata=_key("motion model", "--motion", choices=MOTIONS))
    confirm_hits: int = field(default=3, metadata=_key(
        "a track is confirmed (and broadcast) after this many detections ...", "--confirm-hits", low=1, high=100))
    confirm_window: int = field(default=5, metadata=_key("... within its first this many frames", low=1, high=100))
    max_missed: int = field(default=5, metadata=_key(
        "a confirmed track stops being broadcast after this many processed frames without a detection",
        low=0, high=1000))
    meas_std: float = field(default=0.7, metadata=_key(
        "m: per-axis error of a ground position when perception.ground_covariance is off", positive=True))
    accel_std: float = field(default=3.0, metadata=_key("m/s^2: manoeuvring noise", positive=True))
    init_speed_std: float = field(default=10.0, metadata=_key(
        "m/s: velocity std of a new track (its prior is standing still; 10 chosen by benchmarks/rsu_app.py "
        "--tune)",
        positive=True))
    gate: float = field(default=13.82, metadata=_key("chi-square association gate (2 dof)", positive=True))


@dataclass
class TimingSettings:
    hardware: str | None = field(default=None, metadata=_key(
        "hardware profile: a fixed inference time per frame in simulated time, with busy frames dropped "
        f"({', '.join(HARDWARE_PROFILES)})", "--hardware", choices=tuple(HARDWARE_PROFILES)))
    inference_s: float | None = field(default=None, metadata=_key(
        "a custom fixed inference time per frame (simulated s); overrides --hardware", "--inference-s",
        positive=True))
    bsm_rate_hz: float = field(default=10.0, metadata=_key("BSMs per track per second (J2945/1: 10)",
                                                           positive=True, high=100.0))
    bsm_follows: list[str] = field(default_factory=list, metadata=_key(
        "cameras or radars (of camera.names, radar.names) whose detections open a BSM slot at once, at most one "
        "a period (a frame a quarter period early still opens one; without one the clock sends after a period and "
        "a half); empty: slots every 1/bsm_rate_hz from the first detection of any sensor, each detection waiting "
        "for the next (up to a period)"))


@dataclass
class SecuritySettings:
    mode: str = field(default="signed", metadata=_key(
        "signed: 1609.2 signed data with the station's certificate; unsecured: 1609.2 unsecured data",
        "--security", choices=SECURITY_MODES))
    pki_dir: str | None = field(default=None, metadata=_key(
        "folder with <credential>.cert and <credential>.key (`v2i pki init`)", "--pki-dir"))
    credential: str | None = field(default=None, metadata=_key(
        "name of the certificate and key files (default: the station name)"))
    certificate_interval_s: float = field(default=1.0, metadata=_key(
        "send the full certificate this often (else its digest)", positive=True))


@dataclass
class SpatSettings:
    serial: str = field(default="tlc", metadata=_key(
        "serial port name of the controller link: its URL comes from $V2I_SERIAL_<NAME> when `url` is not set"))
    url: str | None = field(default=None, metadata=_key(
        "pyserial URL of the controller (socket://HOST:PORT, /dev/ttyS0, ...)", "--serial-url"))
    controller: int = field(default=1, metadata=_key("AB3418 station address of the controller", low=0, high=63))
    baud: int = field(default=9600, metadata=_key("serial line speed (8N1)", positive=True))
    poll: str = field(default="long", metadata=_key(
        "status request: long (GetLongStatus8, with times to change) or short (GetShortStatus, greens only)",
        choices=POLLS))
    answer_timeout_s: float = field(default=1.0, metadata=_key(
        "seconds without an answer before a poll counts as lost (wall; simulated in lockstep)", positive=True))
    rate_hz: float = field(default=10.0, metadata=_key("SPaT messages per second", positive=True, high=100.0))
    max_age_s: float = field(default=0.5, metadata=_key(
        "no SPaT from a controller status older than this (simulated s): a lost controller stops the SPaT",
        positive=True))
    intersection_id: int = field(default=1, metadata=_key("J2735 IntersectionID", low=0, high=65535))
    signal_groups: list[int] = field(default_factory=list, metadata=_key(
        "signal groups to report (default: those of the signal heads the master describes, else 2, 4, 6, 8)"))


@dataclass
class PrioritySettings:
    enabled: bool = field(default=False, metadata=_key(
        "serve signal requests (SRM): verify, arbitrate, ask the controller for preemption over the serial "
        "link, answer in SSMs (needs the controller link of [spat] and a MAP)"))
    preempt_groups: list[int] = field(default_factory=lambda: [4, 8], metadata=_key(
        "signal groups the controller's preemption dwells on: a request for another group is rejected"))
    expire_s: float = field(default=2.5, metadata=_key(
        "a request not renewed for this long (simulated s) ends and releases the call", positive=True))
    ssm_rate_hz: float = field(default=10.0, metadata=_key("SSM messages per second while requests are known",
                                                           positive=True, high=100.0))
    trust_anchor: str | None = field(default=None, metadata=_key(
        "certificate of the CA the requesting vehicles' certificates chain to (default: "
        "<pki_dir>/v2i-scenario-ca.cert)"))
    max_age_s: float = field(default=0.5, metadata=_key("an SRM generated longer ago than this is refused",
                                                        positive=True))


@dataclass
class MapSettings:
    enabled: bool = field(default=True, metadata=_key(
        "broadcast a MAP of the intersection the master describes (needs a [world] in the scenario)"))
    rate_hz: float = field(default=1.0, metadata=_key("MAP messages per second", positive=True, high=10.0))
    revision: int = field(default=1, metadata=_key("msgIssueRevision of the MAP", low=0, high=127))
    stop_line_offset_m: float = field(default=1.0, metadata=_key(
        "stop lines lie this far before the crossing road's edge (as the world draws them)", low=0.0))


@dataclass
class V2xSettings:
    messages: list[str] = field(default_factory=lambda: ["surrogate_bsm"], metadata=_key(
        "what the RSU sends of its broadcastable tracks each slot (timing.bsm_rate_hz): surrogate_bsm (one SAE "
        "J2945/8 surrogate BSM per track, PSID 0x7f), sdsm (one SAE J3224 Sensor Data Sharing Message with every "
        "track, PSID v2x.sdsm_psid), or both", choices=MESSAGE_KINDS))
    sdsm_psid: int = field(default=PSID_SDSM_DEFAULT, metadata=_key(
        "PSID the SDSMs are signed under; deployments differ (0x90 here; a config that writes 0x8010 usually "
        "means 0x90 in its 1609.12 p-encoded form)", low=0, high=0xFFFFFFFF))


@dataclass
class HealthSettings:
    stats_every_s: float = field(default=5.0, metadata=_key(
        "wall seconds between stats lines on stderr (0: none)", low=0.0))
    log_level: str = field(default="warning", metadata=_key(
        "logging level", "--log-level", choices=("debug", "info", "warning", "error")))


@dataclass
class Settings:
    name: str | None = field(default=None, metadata=_key(
        "participant name (default $V2I_NAME, else rsu)", "--name", env="V2I_NAME"))
    role: str = field(default="rsu_app", metadata=_key("role announced to the master", "--role", env="V2I_ROLE"))
    station: str | None = field(default=None, metadata=_key(
        "V2X station name: the app transmits on v2x/tx/<station> (default: the participant name)", "--station"))
    seed: int | None = field(default=None, metadata=_key(
        "seed of the per-session salt of the BSMs' temporary ids (default: 0 in lockstep, random in realtime)",
        "--seed", low=0))
    app: AppSettings = field(default_factory=AppSettings)
    bus: BusSettings = field(default_factory=BusSettings)
    camera: CameraSettings = field(default_factory=CameraSettings)
    radar: RadarSettings = field(default_factory=RadarSettings)
    detector: DetectorSettings = field(default_factory=DetectorSettings)
    perception: PerceptionSettings = field(default_factory=PerceptionSettings)
    tracker: TrackerSettings = field(default_factory=TrackerSettings)
    timing: TimingSettings = field(default_factory=TimingSettings)
    security: SecuritySettings = field(default_factory=SecuritySettings)
    spat: SpatSettings = field(default_factory=SpatSettings)
    map: MapSettings = field(default_factory=MapSettings)
    v2x: V2xSettings = field(default_factory=V2xSettings)
    priority: PrioritySettings = field(default_factory=PrioritySettings)
    health: HealthSettings = field(default_factory=HealthSettings)

    # -- derived ------------------------------------------------------------------------------------
    def inference_s(self) -> float | None:
        """The fixed inference time the hardware profile (or --inference-s) imposes; None: none."""
        if self.timing.inference_s is not None:
            return self.timing.inference_s
        if self.timing.hardware:
            return HARDWARE_PROFILES[self.timing.hardware][0]
        return None

    def to_dict(self) -> dict[str, Any]:
        out: dict[str, Any] = {}
        for spec in SCHEMA:
            section = out.setdefault(spec.section, {}) if spec.section else out
            section[spec.name] = spec.get(self)
        return out


# -- the schema, read off the dataclasses --------------------------------------------------------------
@dataclass(frozen=True)
class KeySpec:
    section: str | None
    name: str
    type: str        # "str", "int", "float", "bool", "list[str]", "list[int]"
    optional: bool
    default: Any
    help: str
    flag: str | None
    choices: tuple | None
    low: float | None
    high: float | None
    positive: bool
    env: str | None

    @property
    def dotted(self) -> str:
        return f"{self.section}.{self.name}" if self.section else self.name

    def get(self, settings: Settings):
        obj = getattr(settings, self.section) if self.section else settings
        return getattr(obj, self.name)

    def set(self, settings: Settings, value) -> None:
        obj = getattr(settings, self.section) if self.section else settings
        setattr(obj, self.name, value)


def _type_of(annotation: str) -> tuple[str, bool]:
    text = annotation.replace(" ", "")
    optional = text.endswith("|None")
    return text.removesuffix("|None"), optional


def _specs(cls, section: str | None) -> list[KeySpec]:
    out = []
    for f in fields(cls):
        kind, optional = _type_of(str(f.type))
        if not f.metadata:  # a section
            out += _specs(globals()[kind], f.name)
            continue
        default = f.default if f.default is not MISSING else f.default_factory()
        md = f.metadata
        out.append(KeySpec(section, f.name, kind, optional, default, md["help"], md["flag"],
                           tuple(md["choices"]) if md["choices"] else None, md["low"], md["high"], md["positive"],
                           md["env"]))
    return out


SCHEMA: list[KeySpec] = _specs(Settings, None)
BY_KEY: dict[str, KeySpec] = {s.dotted: s for s in SCHEMA}
SECTIONS = sorted({s.section for s in SCHEMA if s.section})


def _did_you_mean(word: str, options) -> str:
    close = difflib.get_close_matches(word, list(options), n=1, cutoff=0.6)
    return f" (did you mean {close[0]!r}?)" if close else ""


def coerce(spec: KeySpec, value: Any, from_text: bool = False) -> Any:
    """`value` as the key's type; ValueError with the reason. `from_text`: it came from a flag or the environment."""
    if value is None:
        if spec.optional:
            return None
        raise ValueError("a value is required")
    kind = spec.type
    if kind.startswith("list["):
        item = kind[5:-1]
        if from_text and isinstance(value, str):
            value = [v.strip() for v in value.split(",") if v.strip()]
        if not isinstance(value, list):
            raise ValueError(f"expected a list of {item}, got {type(value).__name__} {value!r}")
        return [coerce(KeySpec(spec.section, spec.name, item, False, None, "", None, spec.choices, spec.low,
                               spec.high, spec.positive, None), v, from_text) for v in value]
    if from_text and isinstance(value, str):
        if kind == "bool":
            lowered = value.strip().lower()
            if lowered not in ("true", "false", "1", "0", "yes", "no"):
                raise ValueError(f"expected true or false, got {value!r}")
            value = lowered in ("true", "1", "yes")
        elif kind in ("int", "float"):
            try:
                value = int(value, 0) if kind == "int" else float(value)
            except ValueError:
                raise ValueError(f"expected {'an integer' if kind == 'int' else 'a number'}, got {value!r}") from None
        elif spec.optional and value.strip().lower() in ("", "none"):
            return None
    if kind == "bool":
        if not isinstance(value, bool):
            raise ValueError(f"expected true or false, got {value!r}")
        return value
    if kind == "int":
        if isinstance(value, bool) or not isinstance(value, int):
            raise ValueError(f"expected an integer, got {value!r}")
    elif kind == "float":
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
            raise ValueError(f"expected a finite number, got {value!r}")
        value = float(value)
    elif kind == "str":
        if not isinstance(value, str) or not value:
            raise ValueError(f"expected a non-empty string, got {value!r}")
    if spec.choices is not None and value not in spec.choices:
        raise ValueError(f"expected one of {', '.join(map(str, spec.choices))}, got {value!r}"
                         f"{_did_you_mean(str(value), map(str, spec.choices))}")
    if kind in ("int", "float"):
        if spec.positive and not value > 0:
            raise ValueError(f"must be > 0, got {value!r}")
        if spec.low is not None and value < spec.low:
            raise ValueError(f"must be >= {spec.low:g}, got {value!r}")
        if spec.high is not None and value > spec.high:
            raise ValueError(f"must be <= {spec.high:g}, got {value!r}")
    return value


def read_toml(path: str | os.PathLike) -> dict[str, Any]:
    """The config file's table; ConfigError for a missing or unparsable file."""
    p = Path(path)
    try:
        with open(p, "rb") as fh:
            return tomllib.load(fh)
    except OSError as exc:
        raise ConfigError([("--config", f"cannot read {str(p)!r}: {exc.strerror}")]) from None
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError([("--config", f"{str(p)!r} is not valid TOML: {exc}")]) from None


def _flatten(table: dict[str, Any], problems: list[tuple[str, str]]) -> dict[str, Any]:
    out = {}
    for key, value in table.items():
        if key in SECTIONS:
            if not isinstance(value, dict):
                problems.append((key, f"expected a [{key}] table, got {type(value).__name__}"))
                continue
            for sub, v in value.items():
                dotted = f"{key}.{sub}"
                if dotted not in BY_KEY:
                    known = [s.name for s in SCHEMA if s.section == key]
                    problems.append((dotted, f"unknown key{_did_you_mean(sub, known)} (known in [{key}]: "
                                             f"{', '.join(known)})"))
                    continue
                out[dotted] = v
        elif key in BY_KEY:
            out[key] = value
        else:
            options = [s.dotted for s in SCHEMA if not s.section] + SECTIONS
            problems.append((key, f"unknown key{_did_you_mean(key, options)} (top-level keys: "
                                  f"{', '.join(s.name for s in SCHEMA if not s.section)}; sections: "
                                  f"{', '.join(SECTIONS)})"))
    return out


def build_settings(flags: dict[str, Any] | None = None, config: dict[str, Any] | None = None,
                   environ=os.environ) -> Settings:
    """Settings from flags (dotted key -> text or value), a parsed config table and the environment."""
    problems: list[tuple[str, str]] = []
    settings = Settings()
    layers: list[tuple[str, dict[str, Any], bool]] = []  # (source, values, from_text), lowest precedence first
    env_values = {s.dotted: environ[s.env] for s in SCHEMA if s.env and environ.get(s.env)}
    layers.append(("environment", env_values, True))
    layers.append(("config", _flatten(config or {}, problems), False))
    layers.append(("flag", dict(flags or {}), True))
    for source, values, from_text in layers:
        for dotted, value in values.items():
            spec = BY_KEY.get(dotted)
            if spec is None:
                problems.append((dotted, f"unknown key{_did_you_mean(dotted, BY_KEY)}"))
                continue
            try:
                spec.set(settings, coerce(spec, value, from_text=from_text and isinstance(value, str)))
            except ValueError as exc:
                where = f" (from ${spec.env})" if source == "environment" else ""
                problems.append((dotted, f"{exc}{where}"))
    if settings.perception.track_range_m < settings.perception.max_range_m:
        pr = settings.perception
        problems.append(("perception.track_range_m", f"must be >= perception.max_range_m ({pr.max_range_m}), "
                                                     f"got {pr.track_range_m}"))
    if settings.tracker.confirm_hits > settings.tracker.confirm_window:
        t = settings.tracker
        problems.append(("tracker.confirm_hits", f"must be <= tracker.confirm_window ({t.confirm_window}), "
                                                 f"got {t.confirm_hits}"))
    messages = settings.v2x.messages
    if not messages or len(set(messages)) != len(messages):
        problems.append(("v2x.messages", f"give each of {', '.join(MESSAGE_KINDS)} at most once, at least one, "
                                         f"got {messages!r}"))
    sensors = [*settings.camera.names, *settings.radar.names]
    for name in settings.timing.bsm_follows:
        if name not in sensors:
            problems.append(("timing.bsm_follows", f"{name!r} is none of the RSU's sensors{_did_you_mean(name, sensors)}"
                                                   f" (camera.names, radar.names: {', '.join(sensors) or 'none'})"))
    if settings.detector.compile and settings.detector.backend != "torch":
        problems.append(("detector.compile", f"only the torch backend compiles its network; detector.backend is "
                                             f"{settings.detector.backend!r}"))
    if settings.security.mode == "signed" and not settings.security.pki_dir:
        problems.append(("security.pki_dir", "signed messages need the folder of the station's certificate and key "
                                             "(`v2i pki init DIR --station NAME:0x7f,0x82`), or security.mode = "
                                             "\"unsecured\""))
    if problems:
        raise ConfigError(problems)
    return settings


def help_text() -> str:
    """Every key with its default, for --help."""
    lines = ["config keys (TOML; `--set SECTION.KEY=VALUE` sets any of them; precedence flag > config > "
             "environment > default):"]
    current = object()
    for s in SCHEMA:
        if s.section != current:
            current = s.section
            lines.append(f"  [{s.section}]" if s.section else "  (top level)")
        default = s.default if not isinstance(s.default, list) else ", ".join(map(str, s.default)) or "[]"
        extra = []
        if s.flag:
            extra.append(s.flag)
        if s.env:
            extra.append(f"${s.env}")
        tail = f" [{'; '.join(extra)}]" if extra else ""
        lines.append(f"    {s.name} = {default!s:<10} {s.help}{tail}")
    return "\n".join(lines)
