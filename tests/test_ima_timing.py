"""The IMA case study off its designed timing (issue 38), end to end as a user runs it: `v2i run` on the
shipped case study (RSU app and AV app as processes on zenoh, lockstep, fixed latency policy) with the
emergency vehicle (ev) starting further out or closer in, everything else as shipped except longer road
arms and a route that goes on east (so that a cav that merges ahead has road to speed up on).

* ev 1.5 s late (x0 = -140 m): when the RSU first reports it, the cav is already turning into its lane;
  before issue 38 it braked at 8 m/s^2 and stood in the lane until the ev hit it. Now it goes on, merges
  ahead, and the ev (holding 60 km/h, not braking) never reaches it.
* ev 0.5 s early (x0 = -108 m; without the RSU a collision): the cav yields before the ev's lane.
* ev 1.5 s early (x0 = -91 m): the ev passes first; the cav gives way by slowing down just enough (never
  below 80 % of its turn speed) and passes behind it with the emergency PET margin.
* no ev (parked 216 m out, beyond the RSU's and the lidar's view): the cav takes its turn at its turn speed.
* ev 4 s late (x0 = -183 m): no conflict at the junction; the cav neither stops nor brakes hard in front of
  the ev closing from behind in its lane (it did: 8 m/s^2 to 0.5 m/s, hit from behind), and speeds up.

The full picture (57 timings x RSU on/off) is the sweep scenarios/sweeps/ima_timing.toml; these are the
points that show each behaviour, kept few because each is a full run (about a minute).
"""
from __future__ import annotations

import csv
import json
import math
import subprocess
import sys
from pathlib import Path

import pytest

from test_case_study import copy_study
from test_rsu_app_support import free_port, run_pairwise

V2I = Path(sys.executable).with_name("v2i")
pytest.importorskip("zenoh")
pytest.importorskip("pybullet")
# four full runs in one module fixture: about 4 x 40 s on a quiet machine, several times that on a busy one
pytestmark = pytest.mark.timeout(1800)

EV_SPEED = 16.667
DESIGNED_S = 116.0 / EV_SPEED  # the shipped ev reaches the junction at 6.96 s
LANE_Y = (-3.5, 0.0)  # the ev's (eastbound) lane; the road is 7 m wide
CAV = dict(length=4.5, width=1.8, rear_overhang=0.95)  # scenarios/apps/av.toml [vehicle]
TURN_SPEED = math.sqrt(4.0 * 6.0)  # av.toml: lateral_accel_max 4.0 on the 6 m corner


def run_timing(study: Path, name: str, out: Path, offset_s: float, stop: float, parked: bool = False) -> dict:
    """The shipped case study with the ev `offset_s` late (negative: early); `parked`: standing there."""
    bus, can = free_port(), free_port()
    x0 = -EV_SPEED * (DESIGNED_S + offset_s)
    park = "v0 = 0.0\n[fmus.ev.start]\naccel_cmd = 0.0" if parked else ""
    variant = study / f"{name}.toml"
    variant.write_text(f"""
[scenario]
extends = "ima_case_study.toml"
[time]
stop = {stop}
[record]
camera = false
[world.intersection]
arm_length = 230.0
[fmus.ev.parameters]
x0 = {x0:.2f}
{park}
[bridge]
listen = ["tcp/127.0.0.1:{bus}"]
[can]
port = {can}
[participants.rsu]
timeout_s = 300.0
[participants.cav]
timeout_s = 300.0
command = ["{{python}}", "-m", "av_app", "--config", "apps/av.toml", "--can-port", "{can}",
           "--plan-log", "{{run}}/plan-cav.jsonl",
           "--set", "route.waypoints=[[1.75, -120.0], [1.75, -1.75], [200.0, -1.75]]"]
""")
    run = out / name
    proc = subprocess.run([str(V2I), "run", str(variant), "--out", str(run), "--quiet", "--no-report"],
                          capture_output=True, text=True, timeout=900)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    with (run / "timeseries.csv").open() as f:
        rows = [{k: float(v) for k, v in r.items()} for r in csv.DictReader(f)]
    return {"metrics": json.loads((run / "metrics.json").read_text()), "rows": rows,
            "plans": [json.loads(line) for line in (run / "plan-cav.jsonl").read_text().splitlines()]}


def corners(r: dict) -> list[tuple[float, float]]:
    """The cav's footprint corners (x, y) at a time series row."""
    c, s = math.cos(r["cav.yaw"]), math.sin(r["cav.yaw"])
    return [(r["cav.x"] + u * c - v * s, r["cav.y"] + u * s + v * c)
            for u in (-CAV["rear_overhang"], CAV["length"] - CAV["rear_overhang"])
            for v in (-CAV["width"] / 2, CAV["width"] / 2)]


def footprint_y(r: dict) -> tuple[float, float]:
    """(min, max) y of the cav's footprint corners at a time series row."""
    ys = [y for _, y in corners(r)]
    return min(ys), max(ys)


def footprint_x(r: dict) -> tuple[float, float]:
    xs = [x for x, _ in corners(r)]
    return min(xs), max(xs)


def in_lane(r: dict) -> bool:
    lo, hi = footprint_y(r)
    return hi > LANE_Y[0] and lo < LANE_Y[1]


def ev_behind(r: dict) -> bool:
    """The ev in the cav's lane behind it (the cav has turned east)."""
    return abs(r["cav.yaw"]) < math.radians(30) and r["ev.x"] < r["cav.x"]


@pytest.fixture(scope="module")
def runs(tmp_path_factory, fmu_dir):
    study = copy_study(tmp_path_factory.mktemp("ima-timing"))
    out = tmp_path_factory.mktemp("ima-timing-runs")
    jobs = {"late": ("late", 1.44, 10.0), "early": ("early", -0.5, 9.0), "very_late": ("very_late", 4.0, 12.0),
            "no_ev": ("no_ev", 6.0, 8.0, True), "very_early": ("very_early", -1.5, 9.0)}
    return run_pairwise(lambda job: run_timing(study, job[0], out, *job[1:]), jobs)


def test_a_late_ev_the_cav_merges_ahead_instead_of_stopping_in_its_lane(runs):
    run = runs["late"]
    assert run["metrics"]["collision"] is False
    assert run["metrics"]["min_gap_m"] > 2.0
    rows = run["rows"]
    # it never stands with any part in the ev's lane
    assert not [r["time"] for r in rows if in_lane(r) and r["cav.v"] < 0.5]
    # it decided to go on once it could no longer stop before the zone, and said why in the plan log
    whys = {ch[2] for p in run["plans"] for ch in p.get("choices", [])}
    assert "merge_ahead" in whys or "committed_unsafe" in whys
    assert not {p["decision"] for p in run["plans"]} & {"yield", "brake_hard"}
    # ahead of the ev it speeds up, and does not brake hard in front of it
    after = [r for r in rows if ev_behind(r)]
    assert after and min(r["cav.a"] for r in after) > -4.0
    assert after[-1]["cav.v"] > 12.0


def test_an_early_ev_the_cav_yields_before_its_lane(runs):
    run = runs["early"]
    assert run["metrics"]["collision"] is False
    rows = run["rows"]
    decisions = {p["decision"] for p in run["plans"]}
    assert decisions & {"yield", "slow", "brake_hard"}
    # while the ev crosses the cav's path (its body within 6 m of x = 1.75), the cav is out of its lane
    crossing = [r for r in rows if abs(r["ev.x"] - 1.75) < 6.0]
    assert crossing and max(footprint_y(r)[1] for r in crossing) < LANE_Y[0]
    assert min(r["cav.a"] for r in rows) > -4.5  # the ev was reported about 3 s before the zone


def test_a_very_early_ev_the_cav_slows_only_as_much_as_giving_way_needs(runs):
    run = runs["very_early"]
    assert run["metrics"]["collision"] is False
    rows = run["rows"]
    turning = [r for r in rows if r["cav.y"] > -15.0]
    assert turning and min(r["cav.v"] for r in turning) >= 0.8 * TURN_SPEED  # no stop, no crawl
    assert min(r["cav.a"] for r in rows) > -3.0 - 0.3  # a comfortable slow-down
    whys = {ch[2] for p in run["plans"] for ch in p.get("choices", [])}
    assert "slow_yield" in whys and not {p["decision"] for p in run["plans"]} & {"brake_hard", "go", "go_unsafe"}
    # it passes behind the ev with the ordinary PET margin (1.5 s, av.toml's pet_margin_s): when its footprint
    # first enters the ev's lane, the ev's tail (rear axle - 1.42 m, ima_world.toml) is that far ahead of it
    first_in = next(r for r in rows if in_lane(r))
    ahead = first_in["ev.x"] - 1.42 - max(footprint_x(first_in))
    assert ahead / first_in["ev.v"] >= 1.5, (first_in["time"], ahead)


def test_a_very_late_ev_no_phantom_brake_and_the_cav_speeds_up_ahead_of_it(runs):
    run = runs["very_late"]
    assert run["metrics"]["collision"] is False
    rows = run["rows"]
    turning = [r for r in rows if r["cav.y"] > -15.0]
    assert min(r["cav.v"] for r in turning) >= 0.8 * TURN_SPEED  # no needless slow-down: no conflict
    after = [r for r in rows if ev_behind(r)]
    assert after and min(r["cav.a"] for r in after) > -4.0  # never a hard brake in front of the ev
    assert after[-1]["cav.v"] > 8.333 + 2.0  # it sped up beyond its cruise speed to keep the gap


def test_no_ev_no_needless_stop(runs):
    run = runs["no_ev"]
    assert run["metrics"]["collision"] is False
    turning = [r for r in run["rows"] if r["cav.y"] > -15.0]
    assert turning and min(r["cav.v"] for r in turning) >= 0.8 * TURN_SPEED
    assert min(r["cav.a"] for r in run["rows"]) > -2.0  # only the slow-down for the curve (decel_curve 1.5)
    assert not {p["decision"] for p in run["plans"]} & {"yield", "brake_hard", "go", "go_unsafe"}
