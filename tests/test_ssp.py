"""SSP 1.0 exchange (master.scenario.ssp_export, master.scenario.ssp_import): `v2i export-ssp`, `v2i run system.ssp`.

What is checked, each against something independent of our own reader where one exists:

* the package: the SSD validates against the standard's XSDs (as FMPy ships them), inline parameter
  sets against the ssv XSD, FMPy's reader accepts it, the FMUs inside are the built files, and the
  same scenario gives the same bytes;
* FMPy's simulation of the package (`fmpy.ssp.simulation.simulate_ssp`) and `v2i run` of the
  scenario give the same values of the same variables (three project FMUs, four connections);
* `v2i run system.ssp` gives the same time series as `v2i run scenario.toml` (real processes), also
  with `--set`, and the package loads back into the same Scenario (String, Boolean, step multiples,
  stop conditions, mode and ordering included);
* sections SSP cannot carry are left out with a warning naming them;
* bad packages are refused before anything runs, each problem naming the SSD element.
"""
from __future__ import annotations

import csv
import hashlib
import os
import subprocess
import sys
import zipfile
from pathlib import Path

import numpy as np
import pytest
from lxml import etree

from master.errors import ScenarioError
from master.scenario.loader import load_scenario
from master.scenario.ssp import NS, schema
from master.scenario.ssp_export import export_ssp
from master.scenario.ssp_import import read_ssp

ROOT = Path(__file__).resolve().parent.parent
THREE = ROOT / "tests" / "scenarios" / "ssp_three_fmus.toml"
TWO_VEHICLES = ROOT / "scenarios" / "two_vehicles.toml"


@pytest.fixture(autouse=True)
def project_fmus(fmu_dir, monkeypatch, tmp_path):
    """Project FMU names resolve to the built FMUs; extracted packages go to this test's folder."""
    monkeypatch.setenv("V2I_FMU_DIR", str(fmu_dir))
    monkeypatch.setenv("V2I_SSP_CACHE", str(tmp_path / "ssp-cache"))


def v2i(*args: str, cwd: Path) -> subprocess.CompletedProcess:
    """The `v2i` command in a real process (the environment carries V2I_FMU_DIR and V2I_SSP_CACHE)."""
    exe = Path(sys.executable).with_name("v2i")
    return subprocess.run([str(exe), *args], cwd=cwd, env=dict(os.environ), capture_output=True, text=True,
                          timeout=120)


def run_series(*args: str, cwd: Path, out: str) -> tuple[list[str], np.ndarray]:
    """`v2i run ... --out OUT`: the header and the values of its timeseries.csv."""
    result = v2i("run", *args, "--quiet", "--no-report", "--out", out, cwd=cwd)
    assert result.returncode == 0, result.stderr
    with open(cwd / out / "timeseries.csv", newline="") as f:
        rows = list(csv.reader(f))
    return rows[0], np.array(rows[1:], dtype=float)


def ssd_of(package: Path) -> etree._Element:
    with zipfile.ZipFile(package) as zf:
        return etree.fromstring(zf.read("SystemStructure.ssd"))


def with_ssd(package: Path, out: Path, edit) -> Path:
    """A copy of `package` whose SystemStructure.ssd text went through `edit` (None: left out)."""
    with zipfile.ZipFile(package) as src, zipfile.ZipFile(out, "w") as dst:
        for name in src.namelist():
            data = src.read(name)
            if name == "SystemStructure.ssd":
                text = edit(data.decode())
                if text is None:
                    continue
                data = text.encode()
            dst.writestr(name, data)
    return out


@pytest.fixture
def three_ssp(tmp_path) -> Path:
    out = tmp_path / "three.ssp"
    assert export_ssp(load_scenario(THREE), out) == []  # nothing left out: the scenario is all FMUs
    return out


# -- the package ---------------------------------------------------------------------------------------
def test_export_is_a_valid_ssp_package(three_ssp, fmu_dir, tmp_path):
    root = ssd_of(three_ssp)
    ssd_schema = schema("ssd")
    assert ssd_schema.validate(root), ssd_schema.error_log
    psets = root.findall(".//ssd:ParameterValues/ssv:ParameterSet", NS)
    assert [p.get("name") for p in psets] == ["cav", "ev", "chan"]
    for pset in psets:
        assert schema("ssv").validate(etree.ElementTree(pset)), schema("ssv").error_log

    from fmpy.ssp.ssd import read_ssd

    ssd = read_ssd(str(three_ssp), validate=True)  # FMPy's own reader, with its schema check
    assert [(c.name, c.source) for c in ssd.system.elements] == [
        ("cav", "resources/VehicleDynamics.fmu"), ("ev", "resources/VehicleDynamics.fmu"),
        ("chan", "resources/V2XChannel.fmu")]
    assert sorted((c.startElement, c.startConnector, c.endElement, c.endConnector)
                  for c in ssd.system.connections) == sorted([
        ("ev", "x", "chan", "tx_x"), ("ev", "y", "chan", "tx_y"), ("cav", "x", "chan", "rx_x"),
        ("cav", "y", "chan", "rx_y")])
    chan = ssd.system.elements[2]
    values = {p.name: (p.type, p.value) for b in chan.parameterBindings for s in b.parameterValues
              for p in s.parameters}
    assert values == {"seed": ("Integer", "7"), "tx_power_dbm": ("Real", "20.0"), "packet_bytes": ("Integer", "300")}
    kinds = {c.name: c.kind for c in chan.connectors}
    assert kinds["tx_x"] == "input" and kinds["distance_m"] == "output" and kinds["seed"] == "parameter"
    assert "packet_bytes" not in kinds  # an unconnected input's start value needs no connector
    experiment = root.find("ssd:DefaultExperiment", NS)
    assert (float(experiment.get("startTime")), float(experiment.get("stopTime"))) == (0.0, 2.0)

    with zipfile.ZipFile(three_ssp) as zf:  # each FMU once, as built
        assert sorted(zf.namelist()) == ["SystemStructure.ssd", "resources/V2XChannel.fmu",
                                         "resources/VehicleDynamics.fmu"]
        for name in ("V2XChannel", "VehicleDynamics"):
            assert zf.read(f"resources/{name}.fmu") == (fmu_dir / f"{name}.fmu").read_bytes()
    again = tmp_path / "again.ssp"
    export_ssp(load_scenario(THREE), again)
    assert again.read_bytes() == three_ssp.read_bytes()  # no timestamps: the same scenario, the same bytes


def test_fmpy_simulation_of_the_package_agrees_with_v2i_run(three_ssp, tmp_path):
    """FMPy 0.3.32's simulate_ssp runs the package; `v2i run` runs the scenario file.

    Both are Jacobi masters over the same FMU binaries with the same step, so the values must be the
    same numbers: the tolerance (rtol 1e-12, atol 1e-12) leaves room for rounding only, and a value
    exported or read wrongly (a parameter, a start value, a connection) is far outside it. Two
    differences of FMPy are accounted for, not tolerated: (1) its result row labelled t holds the
    values after the step from t, i.e. at t + h; (2) it starts every connector at 0.0 instead of the
    source's initial output, so the channel's first step sees the vehicles at the origin: its
    outputs are compared from the second point on (the vehicles', which no connection feeds, from
    the first). simulate_ssp also leaves the SSD's parameter bindings to its caller: they are read
    with FMPy's own reader (read_ssd) and handed to it, named component.variable as it expects."""
    from fmpy.ssp.simulation import simulate_ssp
    from fmpy.ssp.ssd import Parameter, ParameterSet, read_ssd

    ssd = read_ssd(str(three_ssp))
    bindings = ParameterSet(name="bindings")
    for comp in ssd.system.elements:
        for binding in comp.parameterBindings:
            for pset in binding.parameterValues:
                bindings.parameters += [Parameter(name=f"{comp.name}.{p.name}", type=p.type, value=p.value)
                                        for p in pset.parameters]
    assert len(bindings.parameters) == 13
    h = 0.01
    theirs = simulate_ssp(str(three_ssp), start_time=0.0, stop_time=2.0, step_size=h, parameter_set=bindings)

    header, ours = run_series(str(THREE), cwd=tmp_path, out="run")
    assert len(ours) == 201
    n = min(len(theirs), len(ours) - 1)
    assert n >= 199
    np.testing.assert_allclose(theirs["time"][:n] + h, ours[1:n + 1, 0], rtol=0, atol=1e-9)
    compared = 0
    for column, name in enumerate(header[1:], 1):
        first = 1 if name.startswith("chan.") else 0
        np.testing.assert_allclose(theirs[name][first:n], ours[1 + first:n + 1, column], rtol=1e-12, atol=1e-12,
                                   err_msg=name)
        compared += 1
    assert compared == 10
    # the run did something worth comparing: the vehicles moved and the link's distance changed
    assert ours[-1, header.index("cav.y")] - ours[0, header.index("cav.y")] > 15
    assert np.ptp(ours[1:, header.index("chan.distance_m")]) > 20


def test_v2i_run_of_the_package_gives_the_same_series_as_the_scenario(tmp_path):
    """`v2i export-ssp` then `v2i run system.ssp` (with a --set, and an instance stepping every 2 steps)."""
    result = v2i("export-ssp", str(TWO_VEHICLES), "-o", "tv.ssp", cwd=tmp_path)
    assert result.returncode == 0, result.stderr
    assert "warning" not in result.stderr
    assert "tv.ssp: SSP 1.0, 2 components, 0 connections" in result.stdout
    header_toml, toml = run_series(str(TWO_VEHICLES), "--set", "time.stop=2.0", cwd=tmp_path, out="toml")
    header_ssp, ssp = run_series("tv.ssp", "--set", "time.stop=2.0", cwd=tmp_path, out="ssp")
    assert header_ssp == header_toml == ["time", "cav.x", "cav.y", "cav.v", "cav.a", "ev.x", "ev.y", "ev.v", "ev.a"]
    assert toml.shape == (201, 9)
    assert (tmp_path / "ssp" / "timeseries.csv").read_text() == (tmp_path / "toml" / "timeseries.csv").read_text()
    assert ssp[-1, 5] > -70  # the ev drove its 30 m


def test_the_package_loads_back_into_the_same_scenario(write_scenario, fmu_dir, tmp_path):
    path = write_scenario(f"""
        connections = ["lead.x -> link.tx_x", "follower.x -> link.rx_x", "lead.v -> follower.accel_cmd"]
        [scenario]
        name = "round_trip"
        description = "every kind of value"
        [time]
        start = 1.0
        stop = 3.0
        step = 0.02
        mode = "realtime"
        ordering = "gauss-seidel"
        rtf = 4.0
        overrun = "skip"
        stop_on = ["lead.x > 500", "distance(lead, follower) < 1"]
        [fmus.lead]
        fmu = "{fmu_dir / 'VehicleDynamics.fmu'}"
        [fmus.lead.parameters]
        v0 = 12
        [fmus.lead.start]
        reverse = false
        steer_cmd = 0.01
        [fmus.follower]
        fmu = "VehicleDynamics"
        step_multiple = 5
        [fmus.link]
        fmu = "V2XChannel"
        [fmus.link.parameters]
        technology = "cv2x"
        cv2x_subchannels = 2
        [record]
        variables = ["lead.x", "follower.*", "link.per", "lead.accel_cmd"]
        """)
    toml = load_scenario(path)
    package = tmp_path / "round_trip.ssp"
    assert export_ssp(toml, package) == []
    ssp = load_scenario(package)
    assert (ssp.name, ssp.description, ssp.time) == (toml.name, toml.description, toml.time)
    assert ssp.connections == toml.connections
    assert ssp.record == toml.record
    assert list(ssp.instances) == list(toml.instances)
    for name, inst in toml.instances.items():
        back = ssp.instances[name]
        assert hashlib.sha256(back.path.read_bytes()).digest() == hashlib.sha256(inst.path.read_bytes()).digest()
        assert (back.parameters, back.start, back.step_multiple) == (inst.parameters, inst.start, inst.step_multiple)
        assert {k: type(v) for k, v in back.start.items()} == {k: type(v) for k, v in inst.start.items()}
    assert ssp.instances["link"].parameters == {"technology": "cv2x", "cv2x_subchannels": 2}
    assert ssp.instances["lead"].start == {"reverse": False, "steer_cmd": 0.01}


def test_sections_ssp_cannot_carry_are_left_out_with_a_warning(tmp_path):
    """intersection_signal.toml serves the controller's serial port: no SSP element can say that."""
    result = v2i("export-ssp", str(ROOT / "scenarios" / "intersection_signal.toml"), "-o", "tlc.ssp", cwd=tmp_path)
    assert result.returncode == 0, result.stderr
    assert "warning: left out of tlc.ssp (SSP 1.0 has no place for them): [serial]" in result.stderr
    raw = read_ssp(tmp_path / "tlc.ssp")
    assert set(raw) == {"scenario", "time", "fmus", "record"}
    assert raw["fmus"]["tlc"]["parameters"]["parity"] == "N"


# -- what is refused ----------------------------------------------------------------------------------------
def refused(package: Path) -> list[str]:
    with pytest.raises(ScenarioError) as info:
        load_scenario(package)
    return info.value.problems


def test_refuses_a_package_without_its_ssd(three_ssp, tmp_path):
    problems = refused(with_ssd(three_ssp, tmp_path / "no_ssd.ssp", lambda text: None))
    assert problems == ["SystemStructure.ssd: missing: an SSP holds its system in SystemStructure.ssd at the top "
                        "of the zip (the package holds: resources/VehicleDynamics.fmu, resources/V2XChannel.fmu)"]
    (tmp_path / "plain.ssp").write_text("not a zip")
    assert refused(tmp_path / "plain.ssp") == ["not an SSP package (an SSP is a zip file): File is not a zip file"]
    assert refused(tmp_path / "none.ssp") == ["cannot read file: No such file or directory"]


def test_refuses_a_connection_to_an_unknown_component(three_ssp, tmp_path):
    bad = with_ssd(three_ssp, tmp_path / "bad.ssp",
                   lambda t: t.replace('startElement="ev" startConnector="x"', 'startElement="evv" startConnector="x"'))
    assert refused(bad) == ["Connection evv.x -> chan.tx_x: no component 'evv' (did you mean 'ev'?)"]


def test_refuses_a_connection_to_a_missing_variable(three_ssp, tmp_path):
    bad = with_ssd(three_ssp, tmp_path / "bad.ssp",
                   lambda t: t.replace('endConnector="rx_y"', 'endConnector="rx_yy"'))
    assert refused(bad) == ["Connection cav.y -> chan.rx_yy: component 'chan' has no connector 'rx_yy' "
                            "(did you mean 'rx_y' or 'tx_y' or 'rx_x'?; V2XChannel.fmu has no variable 'rx_yy' either)"]


def test_refuses_a_connector_or_parameter_the_fmu_does_not_have(three_ssp, tmp_path):
    def edit(text):
        text = text.replace('<ssd:Connector name="distance_m"', '<ssd:Connector name="distanse_m"')
        return text.replace('<ssv:Parameter name="mass">', '<ssv:Parameter name="mas">')
    problems = refused(with_ssd(three_ssp, tmp_path / "bad.ssp", edit))
    assert problems == [
        "Component 'ev': ParameterBinding 1: Parameter 'mas': VehicleDynamics.fmu has no variable 'mas' "
        "(did you mean 'mass'?)",
        "Component 'chan': Connector 'distanse_m': V2XChannel.fmu has no variable 'distanse_m' "
        "(did you mean 'distance_m' or 'min_distance_m' or 'inside_m'?)",
    ]


@pytest.mark.parametrize("edit, expected", [
    (lambda t: t.replace('implementation="CoSimulation">', 'implementation="ModelExchange">', 1),
     "Component 'cav': implementation 'ModelExchange' is not supported"),
    (lambda t: t.replace('endElement="chan" endConnector="tx_x"/>',
                         'endElement="chan" endConnector="tx_x"><ssc:LinearTransformation factor="2"/>'
                         '</ssd:Connection>'),
     "Connection ev.x -> chan.tx_x: LinearTransformation is not supported"),
    (lambda t: t.replace("</ssd:Elements>", '<ssd:System name="sub"/></ssd:Elements>'),
     "System 'ssp_three_fmus': System 'sub': nested systems are not supported"),
    (lambda t: t.replace('source="resources/V2XChannel.fmu"', 'source="resources/V2XChanel.fmu"'),
     "Component 'chan': source 'resources/V2XChanel.fmu' is not in the package (did you mean "
     "'resources/V2XChannel.fmu'"),
    (lambda t: t.replace('startConnector="y" endElement="chan" endConnector="tx_y"',
                         'startConnector="v0" endElement="chan" endConnector="tx_y"'),
     "Connection ev.v0 -> chan.tx_y: connects a parameter to a input"),
    (lambda t: t.replace('<v2i:Master step="0.01"', '<v2i:Master stepp="0.01"'),
     "DefaultExperiment: Annotation 'org.v2i-cosim.master': Master has an unknown attribute 'stepp' "
     "(did you mean 'step'?)"),
    (lambda t: t.replace('version="1.0" name="ssp_three_fmus"', 'name="ssp_three_fmus"', 1),
     "SystemStructure.ssd: breaks the SSP 1.0 schema: line 2: Element "),
])
def test_refuses_what_it_cannot_run_naming_the_element(three_ssp, tmp_path, edit, expected):
    problems = refused(with_ssd(three_ssp, tmp_path / "bad.ssp", edit))
    assert len(problems) == 1 and problems[0].startswith(expected), problems


def test_v2i_run_of_a_bad_package_exits_2_before_running(three_ssp, tmp_path):
    bad = with_ssd(three_ssp, tmp_path / "bad.ssp", lambda t: t.replace('endConnector="rx_y"', 'endConnector="ry"'))
    result = v2i("run", str(bad), "--quiet", "--out", "never", cwd=tmp_path)
    assert result.returncode == 2
    assert f"invalid scenario {bad} (1 problem(s))" in result.stderr
    assert "Connection cav.y -> chan.ry: component 'chan' has no connector 'ry'" in result.stderr
    assert not (tmp_path / "never").exists()


# -- a package written the way other tools write them ---------------------------------------------------
FOREIGN_SSD = """<?xml version="1.0" encoding="UTF-8"?>
<ssd:SystemStructureDescription xmlns:ssd="http://ssp-standard.org/SSP1/SystemStructureDescription"
    xmlns:ssc="http://ssp-standard.org/SSP1/SystemStructureCommon" version="1.0" name="foreign">
  <ssd:System name="root">
    <ssd:ParameterBindings>
      <ssd:ParameterBinding prefix="car.">
        <ssd:ParameterValues>
          <ssv:ParameterSet xmlns:ssv="http://ssp-standard.org/SSP1/SystemStructureParameterValues"
              version="1.0" name="car">
            <ssv:Parameters><ssv:Parameter name="v0"><ssv:Real value="5"/></ssv:Parameter></ssv:Parameters>
          </ssv:ParameterSet>
        </ssd:ParameterValues>
      </ssd:ParameterBinding>
    </ssd:ParameterBindings>
    <ssd:Elements>
      <ssd:Component name="car" source="resources/car.fmu">
        <ssd:Connectors>
          <ssd:Connector name="x" kind="output"><ssc:Real unit="m"/></ssd:Connector>
        </ssd:Connectors>
        <ssd:ElementGeometry x1="0" y1="0" x2="10" y2="10"/>
      </ssd:Component>
      <ssd:Component name="link" source="resources/channel.fmu">
        <ssd:Connectors>
          <ssd:Connector name="rx_x" kind="input"><ssc:Real unit="m"/></ssd:Connector>
        </ssd:Connectors>
        <ssd:ParameterBindings>
          <ssd:ParameterBinding source="resources/link.ssv"/>
        </ssd:ParameterBindings>
      </ssd:Component>
    </ssd:Elements>
    <ssd:Connections>
      <ssd:Connection startElement="link" startConnector="rx_x" endElement="car" endConnector="x"/>
    </ssd:Connections>
    <ssd:Annotations><ssc:Annotation type="com.example.tool"><layout/></ssc:Annotation></ssd:Annotations>
  </ssd:System>
  <ssd:DefaultExperiment startTime="0" stopTime="0.5"/>
</ssd:SystemStructureDescription>
"""
FOREIGN_SSV = """<?xml version="1.0" encoding="UTF-8"?>
<ssv:ParameterSet xmlns:ssv="http://ssp-standard.org/SSP1/SystemStructureParameterValues" version="1.0" name="l">
  <ssv:Parameters>
    <ssv:Parameter name="seed"><ssv:Integer value="3"/></ssv:Parameter>
    <ssv:Parameter name="technology"><ssv:String value="cv2x"/></ssv:Parameter>
  </ssv:Parameters>
</ssv:ParameterSet>
"""


def test_reads_a_package_written_by_another_tool(fmu_dir, tmp_path):
    """Bindings from an .ssv file and on the System with a prefix, a connection written input-first,
    geometry and another tool's annotation (ignored), no annotation of ours (the loader's defaults)."""
    package = tmp_path / "foreign.ssp"
    with zipfile.ZipFile(package, "w") as zf:
        zf.writestr("SystemStructure.ssd", FOREIGN_SSD)
        zf.writestr("resources/link.ssv", FOREIGN_SSV)
        zf.writestr("resources/car.fmu", (fmu_dir / "VehicleDynamics.fmu").read_bytes())
        zf.writestr("resources/channel.fmu", (fmu_dir / "V2XChannel.fmu").read_bytes())
    sc = load_scenario(package)
    assert sc.name == "foreign"
    assert [str(c) for c in sc.connections] == ["car.x -> link.rx_x"]
    assert sc.instances["car"].parameters == {"v0": 5.0}
    assert sc.instances["link"].parameters == {"seed": 3, "technology": "cv2x"}
    assert (sc.time.start, sc.time.stop, sc.time.step, sc.time.ordering) == (0.0, 0.5, 0.01, "jacobi")
    assert ("car", "x") in sc.record and ("link", "distance_m") in sc.record  # default: every output
