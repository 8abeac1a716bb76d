"""[pki]: a scenario's credentials are made when a run needs them, kept when valid, renewed when not."""
from __future__ import annotations

from datetime import datetime, timedelta, timezone

import pytest

from bridges.security import ScenarioCA, load_credentials
from master.errors import ScenarioError
from master.scenario.pki import CA_NAME, PkiSpec, ensure
from master.scenario.loader import load_scenario

STATIONS = {"rsu": [0x7F, 0x82], "cav": [0x20]}


def test_made_once_then_kept(tmp_path):
    spec = PkiSpec(tmp_path / "keys", dict(STATIONS))
    assert ensure(spec)["made"] == [CA_NAME, "rsu", "cav"]
    before = (tmp_path / "keys" / "rsu.cert").read_bytes()
    assert ensure(spec) == {"dir": str(tmp_path / "keys"), "made": [], "kept": ["rsu", "cav"]}
    assert (tmp_path / "keys" / "rsu.cert").read_bytes() == before
    rsu = load_credentials(tmp_path / "keys", "rsu").certificate
    ca = load_credentials(tmp_path / "keys", CA_NAME).certificate
    assert rsu.psids == {0x7F, 0x82} and rsu.issuer_digest == ca.digest


def _ensure_after(barrier, directory) -> bytes:
    barrier.wait()
    ensure(PkiSpec(directory, dict(STATIONS)))
    return load_credentials(directory, "rsu").certificate.issuer_digest


def test_runs_starting_at_once_make_one_ca(tmp_path):
    """Four processes provisioning one empty keys folder at the same instant (two `v2i run`s of scenarios in
    one folder): one CA is made, and every station certificate each of them then reads is that CA's."""
    import multiprocessing

    ctx = multiprocessing.get_context("spawn")
    barrier = ctx.Manager().Barrier(4)
    with ctx.Pool(4) as pool:
        issuers = pool.starmap(_ensure_after, [(barrier, tmp_path / "keys")] * 4)
    ca = load_credentials(tmp_path / "keys", CA_NAME).certificate
    assert set(issuers) == {ca.digest}
    for name in STATIONS:
        assert load_credentials(tmp_path / "keys", name).certificate.issuer_digest == ca.digest


def test_expired_foreign_or_short_of_a_psid_is_issued_again(tmp_path):
    keys = tmp_path / "keys"
    ensure(PkiSpec(keys, dict(STATIONS)))
    ca = ScenarioCA(load_credentials(keys, CA_NAME))
    ca.issue("rsu", [0x7F, 0x82], start=datetime.now(timezone.utc) - timedelta(hours=3), hours=1).save(keys)
    ScenarioCA.create().issue("cav", [0x20]).save(keys)  # signed by another CA
    assert ensure(PkiSpec(keys, dict(STATIONS)))["made"] == ["rsu", "cav"]
    assert ensure(PkiSpec(keys, {"cav": [0x20, 0x7F]}))["made"] == ["cav"]  # a PSID it lacked
    assert load_credentials(keys, "cav").certificate.psids == {0x20, 0x7F}


@pytest.mark.parametrize("table, reason", [
    ('stations = { rsu = "0x7f" }', "pki.dir: required"),
    ('dir = "keys"\nstations = { rsu = "seven" }', "pki.stations.rsu: 'seven': PSIDs must be integers"),
    ('dir = "keys"\nstations = { rsu = 127 }', "pki.stations.rsu: expected PSIDs as a string"),
    ('dir = "keys"\nstations = {}', "pki.stations: expected at least one station"),
    ('dir = "keys"\nstaions = { rsu = "0x7f" }', "did you mean 'stations'"),
])
def test_a_bad_pki_table_is_refused_naming_the_key(write_scenario, table, reason):
    with pytest.raises(ScenarioError) as err:
        load_scenario(write_scenario(f'[fmus.cav]\nfmu = "{{vehicle}}"\n[pki]\n{table}\n'))
    assert reason in str(err.value)


def test_a_run_makes_the_keys_before_anything_else(write_scenario, tmp_path):
    from master.run.cosim import CoSimulation

    sc = load_scenario(write_scenario('[time]\nstop = 0.05\n[fmus.cav]\nfmu = "{vehicle}"\n'
                                      '[pki]\ndir = "run-keys"\nstations = { rsu = "0x7f" }\n'))
    result = CoSimulation(sc, tmp_path / "run", quiet=True).run()
    assert result.status == "completed" and result.metadata["pki"]["made"] == [CA_NAME, "rsu"]
    assert (sc.path.parent / "run-keys" / "rsu.key").stat().st_mode & 0o777 == 0o600
