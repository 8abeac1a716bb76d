"""Sweep files (master.sweep.spec): axes from lists, ranges and seeded draws, product / zip / groups, variant
axes, stable point ids and folders, and every problem of a bad file named by its key; the shipped sweeps
load and every one of their points makes a valid scenario."""
from __future__ import annotations

import textwrap
from pathlib import Path

import pytest

from master.sweep.spec import SweepError, load_sweep

ROOT = Path(__file__).resolve().parent.parent
TINY = ROOT / "tests" / "scenarios" / "sweep_tiny.toml"


@pytest.fixture
def sweep_file(tmp_path):
    def write(body: str, name: str = "s.toml") -> Path:
        path = tmp_path / name
        path.write_text(f'[sweep]\nbase = "{TINY}"\n' + textwrap.dedent(body))
        return path
    return write


def test_product_of_values_range_and_labels(sweep_file):
    spec = load_sweep(sweep_file("""
        [[sweep.axis]]
        key = "fmus.ev.parameters.v0"
        values = [12.0, 16.667]
        [[sweep.axis]]
        name = "cav"
        key = "fmus.cav.parameters.v0"
        range = { start = 6.0, stop = 9.0, step = 1.5 }
    """))
    points = spec.points()
    assert [a.name for a in spec.axes] == ["v0", "cav"]  # a key's last part names its axis by default
    assert spec.axis("cav").values == (6.0, 7.5, 9.0)  # the stop is included when a step lands on it
    assert [(p.params["v0"], p.params["cav"]) for p in points] == [
        (12.0, 6.0), (12.0, 7.5), (12.0, 9.0), (16.667, 6.0), (16.667, 7.5), (16.667, 9.0)]
    assert [o.text for o in points[1].overrides] == ["fmus.ev.parameters.v0=12.0", "fmus.cav.parameters.v0=7.5"]
    assert points[1].folder == f"v0=12_cav=7.5-{points[1].id}"
    assert len({p.id for p in points}) == 6


def test_zip_groups_and_variants(sweep_file):
    spec = load_sweep(sweep_file("""
        [[sweep.axis]]
        key = "fmus.ev.parameters.v0"
        values = [11.0, 15.0, 20.0]
        group = "ev"
        [[sweep.axis]]
        key = "fmus.ev.parameters.x0"
        values = [-77.0, -105.0, -140.0]
        group = "ev"
        [[sweep.axis]]
        name = "side"
        labels = ["as is", "east"]
        [[sweep.axis.values]]
        [[sweep.axis.values]]
        "fmus.ev.parameters.y0" = 1.75
        "fmus.ev.parameters.yaw0" = 3.14159
    """))
    points = spec.points()
    assert len(points) == 6  # (v0, x0) move together, times the two variants
    assert {(p.params["v0"], p.params["x0"]) for p in points} == {(11.0, -77.0), (15.0, -105.0), (20.0, -140.0)}
    east = [p for p in points if p.labels["side"] == "east"][0]
    assert [o.key for o in east.overrides] == ["fmus.ev.parameters.v0", "fmus.ev.parameters.x0",
                                               "fmus.ev.parameters.y0", "fmus.ev.parameters.yaw0"]
    assert east.params["side"] == "east"  # a variant's column is its label
    zipped = load_sweep(sweep_file("""
        combine = "zip"
        [sweep.axes]
        "fmus.ev.parameters.v0" = [11.0, 15.0]
        "fmus.cav.parameters.v0" = { values = [5.0, 8.0], name = "cav_v0" }
    """, "zip.toml"))
    assert [(p.params["v0"], p.params["cav_v0"]) for p in zipped.points()] == [(11.0, 5.0), (15.0, 8.0)]


def test_seeded_random_draws_repeat(sweep_file):
    body = """
        [[sweep.axis]]
        key = "v2x.channel.loss_prob"
        random = { dist = "uniform", low = 0.0, high = 0.5, n = 5, seed = 3 }
        [[sweep.axis]]
        key = "fmus.ev.parameters.v0"
        random = { dist = "normal", mean = 16.0, std = 1.0, n = 2, seed = 1 }
    """
    a, b = load_sweep(sweep_file(body, "a.toml")), load_sweep(sweep_file(body, "b.toml"))
    assert a.axis("loss_prob").values == b.axis("loss_prob").values
    assert len(set(a.axis("loss_prob").values)) == 5 and all(0 <= v < 0.5 for v in a.axis("loss_prob").values)
    assert [p.id for p in a.points()] == [p.id for p in b.points()]
    other = load_sweep(sweep_file(body.replace("seed = 3", "seed = 4"), "c.toml"))
    assert other.axis("loss_prob").values != a.axis("loss_prob").values


def test_a_point_keeps_its_id_when_the_axes_grow(sweep_file):
    """The id hashes what a point sets, so adding values keeps the finished points' folders (resume)."""
    small = load_sweep(sweep_file('[sweep.axes]\n"fmus.ev.parameters.v0" = [12.0, 14.0]\n', "small.toml"))
    grown = load_sweep(sweep_file('[sweep.axes]\n"fmus.ev.parameters.v0" = [10.0, 12.0, 13.0, 14.0]\n', "g.toml"))
    assert {p.folder for p in small.points()} <= {p.folder for p in grown.points()}
    with_set = load_sweep(sweep_file('[sweep.set]\n"time.stop" = 4.0\n[sweep.axes]\n'
                                     '"fmus.ev.parameters.v0" = [12.0, 14.0]\n', "set.toml"))
    assert not {p.id for p in small.points()} & {p.id for p in with_set.points()}  # other settings, new points


@pytest.mark.parametrize("body, expected", [
    ('baes = 1\n[sweep.axes]\n"time.stop" = [1.0]\n', "sweep.baes: unknown key .*did you mean 'base'"),
    ('combine = "prodct"\n[sweep.axes]\n"time.stop" = [1.0]\n', "sweep.combine: expected one of product, zip.*did you mean 'product'"),
    ('[[sweep.axis]]\nkey = "time.stop"\nvalues = [1.0]\nrange = { start = 1, stop = 2, step = 1 }\n',
     r"sweep.axis\[0\]: give exactly one of values"),
    ('[[sweep.axis]]\nkey = "time.stop"\nvalus = [1.0]\n', r"sweep.axis\[0\].valus: unknown key .*did you mean 'values'"),
    ('[[sweep.axis]]\nkey = "time.stop"\nrange = { start = 1, stop = 0, step = 1 }\n', r"sweep.axis\[0\].range: expected numbers"),
    ('[[sweep.axis]]\nkey = "v"\nrandom = { dist = "unifrom", low = 0, high = 1, n = 2, seed = 0 }\n',
     r"sweep.axis\[0\].random: dist: .*did you mean 'uniform'"),
    ('[[sweep.axis]]\nkey = "v"\nrandom = { dist = "uniform", low = 0, high = 1, n = 2 }\n', "missing seed"),
    ('[[sweep.axis]]\nname = "x"\nvalues = [1, 2]\n', r"sweep.axis\[0\].values: without `key`, each value is a table"),
    ('[[sweep.axis]]\nkey = "a b"\nvalues = [1]\n', r"sweep.axis\[0\].key: expected '.' or '\['"),
    ('[[sweep.axis]]\nkey = "time.stop"\nvalues = [1.0, 2.0]\nlabels = ["a"]\n', r"sweep.axis\[0\].labels: expected 2"),
    ('combine = "zip"\n[sweep.axes]\n"time.stop" = [1.0, 2.0]\n"time.step" = [0.1]\n', "needs axes of one length"),
    ('[sweep.axes]\n"time.stop" = [1.0]\n"scenario.stop" = [2.0]\n', "two axes are named 'stop'"),
    ('[sweep.axes]\n"time.stop" = [1.0]\n[sweep.plots]\ncurves = { x = "stp" }\n',
     r"sweep.plots.curves.x: expected the name of an axis \(stop\), got 'stp'; did you mean 'stop'"),
    ('[sweep.axes]\n"time.stop" = [1.0]\n[sweep.summary]\nsafe_limit = "stp"\n', "sweep.summary.safe_limit: no axis named 'stp'"),
    ('', "sweep: no axes"),
    ('[[sweep.axis]]\nname = "status"\nkey = "time.stop"\nvalues = [1.0]\n',
     r"sweep.axis\[0\].name: 'status' is a column of the table already"),
])
def test_bad_sweep_files_name_the_key(sweep_file, body, expected):
    with pytest.raises(SweepError, match=expected) as info:
        load_sweep(sweep_file(body))
    assert "invalid sweep" in str(info.value)


def test_every_problem_at_once_and_a_missing_base(tmp_path):
    path = tmp_path / "s.toml"
    path.write_text('[sweep]\nbase = "nowhere.toml"\ntimeout_s = -1\n[[sweep.axis]]\nkey = "time.stop"\n')
    with pytest.raises(SweepError) as info:
        load_sweep(path)
    text = "\n".join(info.value.problems)
    assert "sweep.base: no such scenario file" in text
    assert "sweep.timeout_s: expected wall seconds > 0" in text
    assert "sweep.axis[0]: give exactly one of values" in text


@pytest.mark.parametrize("name, n", [("dse", 12), ("radio_loss", 21), ("nhtsa_variants", 40), ("ima_timing", 114),
                                     ("evsp_baud", 6), ("evsp_variants", 9)])
def test_the_shipped_sweeps_load_and_every_point_is_a_valid_scenario(fmu_dir, name, n):
    from master.sweep.runner import check_points
    from master.sweep.dse import check_dse

    spec = load_sweep(ROOT / "scenarios" / "sweeps" / f"{name}.toml")
    points = spec.points()
    assert len(points) == n
    assert check_dse(spec) == []
    assert check_points(spec, points) == {}
