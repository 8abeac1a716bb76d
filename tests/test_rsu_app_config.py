"""The RSU app's configuration: flags > config file > environment > defaults, and every problem named by key.

Through the real entry point (`python -m rsu_app` in a subprocess) where the
process's behaviour is the point (exit code 2, the messages on stderr, --help),
in process for the precedence rules.
"""
from __future__ import annotations

import json
import subprocess
import sys
import uuid

import pytest
from conftest import has_cxx_compiler

from rsu_app.config import SCHEMA, ConfigError, build_settings

from test_rsu_app_support import ROOT, bridge_tables, free_port, make_pki, rsu_table


def rsu(*args: str, cwd=None, env=None) -> subprocess.CompletedProcess:
    import os

    environ = {k: v for k, v in os.environ.items() if not k.startswith("V2I_")}
    environ.update(env or {})
    return subprocess.run([sys.executable, "-m", "rsu_app", *args], capture_output=True, text=True, timeout=120,
                          cwd=cwd or ROOT, env=environ)


def test_a_bad_config_file_exits_2_naming_every_key(tmp_path):
    bad = tmp_path / "bad.toml"
    bad.write_text("""
nmae = "rsu"
[detector]
backend = "onx"
threads = 0
[tracker]
confirm_hit = 3
max_missed = -1
[spat]
baud = "fast"
[timing]
hardware = "cpu-i9"
[sptat]
rate_hz = 10
""")
    r = rsu("--config", str(bad), "--security", "unsecured")
    assert r.returncode == 2, r.stderr
    lines = r.stderr.strip().splitlines()
    expected = ["nmae: unknown key (did you mean 'name'?)",
                "detector.backend: expected one of onnx, torch, classical, got 'onx' (did you mean 'onnx'?)",
                "detector.threads: must be >= 1, got 0",
                "tracker.confirm_hit: unknown key (did you mean 'confirm_hits'?)",
                "tracker.max_missed: must be >= 0, got -1",
                "spat.baud: expected an integer, got 'fast'",
                "timing.hardware: expected one of cpu-i7, gpu-gtx1650, fpga-zynq7020, got 'cpu-i9' (did you mean "
                "'cpu-i7'?)",
                "sptat: unknown key (did you mean 'spat'?)"]
    for e in expected:
        assert any(e in line for line in lines), (e, r.stderr)
    assert all(line.startswith("rsu_app: config: ") for line in lines)
    assert not r.stdout


@pytest.mark.parametrize("content,match", [
    ("[detector\nbackend = 1", "--config: .* is not valid TOML"),
    (None, "--config: cannot read"),
])
def test_an_unreadable_config_file_exits_2(tmp_path, content, match):
    import re

    path = tmp_path / "c.toml"
    if content is not None:
        path.write_text(content)
    r = rsu("--config", str(path))
    assert r.returncode == 2 and re.search(match, r.stderr), r.stderr


def test_credentials_are_checked_before_joining(tmp_path):
    r = rsu("--pki-dir", str(tmp_path / "nowhere"))
    assert r.returncode == 2 and "security.pki_dir: cannot load the credentials 'rsu'" in r.stderr, r.stderr
    r = rsu()
    assert r.returncode == 2 and "security.pki_dir: signed messages need" in r.stderr
    make_pki(tmp_path / "keys", {"rsu": "0x7f"})  # surrogate BSMs only: no SPaT/MAP permission
    r = rsu("--pki-dir", str(tmp_path / "keys"))
    assert r.returncode == 2 and "security.credential: certificate 'rsu' may not sign SPaT/MAP (0x82)" in r.stderr
    r = rsu("--pki-dir", str(tmp_path / "keys"), "--set", "map.enabled=false", "--bus", "zenoh")
    assert r.returncode == 2 and "bus: no bus configured" in r.stderr  # past the credentials: the bus is next


def test_bad_weights_are_named(tmp_path):
    r = rsu("--security", "unsecured", "--weights", str(tmp_path / "none.onnx"))
    assert r.returncode == 2 and "detector.weights: weights file not found" in r.stderr, r.stderr


def test_help_documents_every_key():
    r = rsu("--help")
    assert r.returncode == 0
    for spec in SCHEMA:
        assert f"    {spec.name} = " in r.stdout, spec.dotted
        if spec.flag:
            assert spec.flag in r.stdout
    assert "Exit codes" in r.stdout and "hardware profile" in r.stdout


def test_precedence_flag_over_config_over_environment_over_default(tmp_path):
    config = {"name": "from-config", "tracker": {"max_missed": 7}, "detector": {"threads": 2},
              "security": {"mode": "unsecured"}}
    env = {"V2I_NAME": "from-env", "V2I_CONNECT": "tcp/10.0.0.1:7447,tcp/10.0.0.2:7447"}
    s = build_settings({"name": "from-flag", "detector.threads": "3"}, config, env)
    assert s.name == "from-flag" and s.detector.threads == 3 and s.tracker.max_missed == 7
    assert s.bus.connect == ["tcp/10.0.0.1:7447", "tcp/10.0.0.2:7447"]
    s = build_settings({}, config, env)
    assert s.name == "from-config" and s.detector.threads == 2
    s = build_settings({"security.mode": "unsecured"}, {}, env)
    assert s.name == "from-env" and s.detector.threads == 1 and s.tracker.max_missed == 5
    with pytest.raises(ConfigError) as err:
        build_settings({"security.mode": "unsecured"}, {}, {"V2I_BUS": "carrier-pigeon"})
    assert err.value.problems[0][0] == "bus.transport" and "from $V2I_BUS" in err.value.problems[0][1]


def test_print_config_resolves_paths_relative_to_the_config_file(tmp_path):
    (tmp_path / "apps").mkdir()
    (tmp_path / "apps" / "rsu.toml").write_text('[security]\npki_dir = "../keys"\n[detector]\nthreads = 2\n')
    r = rsu("--config", str(tmp_path / "apps" / "rsu.toml"), "--print-config", "--threads", "4")
    assert r.returncode == 0, r.stderr
    out = json.loads(r.stdout)
    assert out["security"]["pki_dir"] == str(tmp_path / "apps" / "../keys") and out["detector"]["threads"] == 4


def test_the_case_study_config_is_valid():
    r = rsu("--config", str(ROOT / "scenarios" / "apps" / "rsu.toml"), "--print-config")
    assert r.returncode == 0, r.stderr
    out = json.loads(r.stdout)
    assert out["name"] == "rsu" and out["detector"]["backend"] == "onnx" and out["camera"]["names"] == ["rsu_cam"]


def test_a_started_app_with_a_bad_config_fails_the_run_naming_it(tmp_path, fmu_dir):
    prefix, port = f"test/rsu-bad-{uuid.uuid4().hex[:8]}", free_port()
    text = '[scenario]\nname = "bad_app"\n[time]\nstop = 1.0\nstep = 0.01\n[fmus.car]\nfmu = "VehicleDynamics"\n' + \
        bridge_tables(prefix, port) + rsu_table("rsu", "--set", "tracker.motion=ctrw", "--security", "unsecured")
    path = tmp_path / "bad.toml"
    path.write_text(text)
    r = subprocess.run([sys.executable, "-m", "master.cli", "run", str(path), "--out", str(tmp_path / "out"),
                        "--quiet"], capture_output=True, text=True, timeout=300, cwd=tmp_path)
    assert r.returncode == 1
    assert "rsu" in r.stderr + r.stdout and "exited with code 2" in r.stderr + r.stdout
    log = (tmp_path / "out" / "participant-rsu.log").read_text()
    assert "tracker.motion: expected one of cv, ctrv, got 'ctrw' (did you mean 'ctrv'?)" in log


def test_the_detections_trace_switch_defaults_on_and_a_misspelt_key_is_named():
    base = {"security": {"mode": "unsecured"}}
    assert build_settings({}, base, {}).app.trace_detections is True
    assert build_settings({"app.trace_detections": "false"}, base, {}).app.trace_detections is False
    assert build_settings({}, {**base, "app": {"trace_detections": False}}, {}).app.trace_detections is False
    with pytest.raises(ConfigError) as err:
        build_settings({}, {**base, "app": {"trace_detection": True}}, {})
    assert err.value.problems == [("app.trace_detection", "unknown key (did you mean 'trace_detections'?) "
                                                          "(known in [app]: trace_detections)")]
    with pytest.raises(ConfigError) as err:
        build_settings({}, {**base, "app": {"trace_detections": "yes"}}, {})
    assert err.value.problems[0][0] == "app.trace_detections" and "expected true or false" in err.value.problems[0][1]


def test_the_ground_noise_and_ranges_are_checked_and_match_the_geometry_s_defaults():
    """The box noise the app's ground covariances assume: its defaults are geo.BoxNoise's (one calibration,
    docs/rsu_app.md), each bad value is named, and a track range short of the broadcast range is refused."""
    from rsu_app.perception.geo import BoxNoise
    from rsu_app.perception_stage import box_noise

    base = {"security": {"mode": "unsecured"}}
    s = build_settings({}, base, {})
    assert box_noise(s) == BoxNoise()
    assert s.perception.track_range_m >= s.perception.max_range_m
    with pytest.raises(ConfigError) as err:
        build_settings({}, {**base, "perception": {"track_range_m": 50.0, "box_edge_px": 0.0, "size_rel": -0.1,
                                                   "ground_covariance": "maybe"},
                            "tracker": {"init_speed_std": 0}}, {})
    keys = [k for k, _ in err.value.problems]
    assert keys == ["perception.box_edge_px", "perception.size_rel", "perception.ground_covariance",
                    "tracker.init_speed_std", "perception.track_range_m"], err.value.problems
    assert "must be >= perception.max_range_m (60.0), got 50.0" in dict(err.value.problems)["perception.track_range_m"]
    s = build_settings({"perception.track_range_m": "60", "perception.ground_covariance": "true"}, base, {})
    assert s.perception.track_range_m == 60.0 and s.perception.ground_covariance is True


def test_only_the_torch_backend_compiles():
    """detector.compile reaches the torch backend; with another backend it is a named error, not ignored."""
    base = {"security": {"mode": "unsecured"}}
    s = build_settings({"detector.backend": "torch", "detector.compile": "true"}, base, {})
    assert s.detector.compile is True
    assert build_settings({}, base, {}).detector.compile is False
    if has_cxx_compiler():  # the app builds its detector compiled (it needs a compiler)
        from rsu_app.app import make_rsu_detector

        assert make_rsu_detector(s).compiled
    with pytest.raises(ConfigError) as err:
        build_settings({"detector.compile": "true"}, base, {})
    assert err.value.problems == [("detector.compile", "only the torch backend compiles its network; "
                                                       "detector.backend is 'onnx'")]


def test_bsm_slots_follow_only_sensors_the_rsu_has():
    base = {"security": {"mode": "unsecured"}, "radar": {"names": ["west"]}}
    s = build_settings({"timing.bsm_follows": "rsu_cam,west"}, base, {})
    assert s.timing.bsm_follows == ["rsu_cam", "west"] and build_settings({}, base, {}).timing.bsm_follows == []
    with pytest.raises(ConfigError) as err:
        build_settings({"timing.bsm_follows": "rsu_cma,lidar"}, base, {})
    assert err.value.problems == [
        ("timing.bsm_follows", "'rsu_cma' is none of the RSU's sensors (did you mean 'rsu_cam'?) (camera.names, "
                               "radar.names: rsu_cam, west)"),
        ("timing.bsm_follows", "'lidar' is none of the RSU's sensors (camera.names, radar.names: rsu_cam, west)")]
