"""Tests of the V2X channel model (fmus/channel/*.py) without FMI.

Anchors (docs/anchors.md, radio channel):
  C1  WINNER+ B1 breakpoint, antennas 1.5 m, environment 0.5 m: ~78.6 m
  C2  WINNER+ B1 LOS: 89.6 / 101.7 / 117.6 dB at 100 / 200 / 500 m
  C3  TR 37.885 urban at 100 m: LOS 86.2 dB (sigma 3), NLOS 111.4 dB (sigma 4)
  C4  TR 37.885 LOS probability: urban 100 m 0.336, highway 500 m 0.515
  C5  building loss 9 dB/wall + 0.4 dB/m: 2 walls + 20 m -> 26.0 dB
  C6  Nakagami m = 1.5 below 80 m, 0.75 beyond; outage m = 1.5 at 10 dB margin 0.040
  C7  802.11p airtime 300 B at 6 Mb/s: 448 us (51 symbols)
  C8  NIST PER 300 B at 6 Mb/s: 0.019 at 7 dB, 3.9e-4 at 8 dB
  C9  noise 10 MHz: -104.0 dBm, -95.0 dBm with NF 9 dB
  C10 single-link 802.11p PDR (23 dBm, 6 Mb/s): 0.967 / 0.749 / 0.366 at 200 / 250 / 300 m
  C11 802.11p under load (0.06 veh/m, 10 Hz, 190 B): 0.852 at 200 m, 0.297 at 300 m
  C12 C-V2X mode 4 (0.1 veh/m, 10 Hz, 20 dBm, 190 B): 0.916 / 0.715 / 0.331 at 300 / 400 / 500 m
  C13 SPS mean access latency, window 4..100 ms: ~52 ms
  C14 802.11p one hop at low load: 0.4-0.6 ms on air; devices add 1-5 ms
"""
from __future__ import annotations

import csv
import math
import re
from collections import defaultdict

import numpy as np
import pytest

from fmus.channel import access, errors, pathloss
from fmus.channel.model import ChannelModel, ChannelParams

from conftest import fixture_path

ANCHOR_CSV = "anchors/pdr_vs_distance.csv"  # in tests/fixtures/: the published curves behind C11 and C12

# The published models' configurations (their code: fc 5.89 GHz and h_env 0.5 m for 802.11p,
# fc 5.91 GHz and h_env 0 m for C-V2X; noise -95 dBm in 10 MHz with NF 9 dB).
SEPULCRE = dict(technology="dsrc", freq_ghz=5.89, env_height_m=0.5, tx_power_dbm=23.0, data_rate_bps=6e6)
GONZALEZ = dict(technology="cv2x", freq_ghz=5.91, env_height_m=0.0, tx_power_dbm=20.0, cv2x_subchannels=4)


def published_curves():
    """{(technology, config, curve): (distances, pdr)} from pdr_vs_distance.csv (missing: the test fails)."""
    rows = defaultdict(list)
    with fixture_path(ANCHOR_CSV).open() as fh:
        for r in csv.DictReader(fh):
            rows[(r["technology"], r["config"], r["curve"])].append((float(r["distance_m"]), float(r["pdr"])))
    return {k: tuple(np.array(c) for c in zip(*sorted(v))) for k, v in rows.items()}


def model_for(technology: str, config: str) -> ChannelModel:
    """The model configured as one published curve (density, rate, power, size, data rate / subchannels)."""
    if technology == "IEEE 802.11p":
        m = re.fullmatch(r"PDR_([\d.]+)vehm_(\d+)Mbps_(\d+)Hz_Pt(\d+)_(\d+)Bytes", config)
        beta, rate, lam, pt, size = float(m[1]), float(m[2]) * 1e6, float(m[3]), float(m[4]), int(m[5])
        return ChannelModel(**{**SEPULCRE, "data_rate_bps": rate, "tx_power_dbm": pt}, density_veh_per_m=beta,
                            msg_rate_hz=lam, load_packet_bytes=size)
    m = re.search(r"beta([\d.]+)-lambda(\d+)-Pt(\d+)-S(\d)-B(\d+)", config)
    beta, lam, pt, sub, size = float(m[1]), float(m[2]), float(m[3]), int(m[4]), int(m[5])
    return ChannelModel(**{**GONZALEZ, "tx_power_dbm": pt, "cv2x_subchannels": sub}, density_veh_per_m=beta,
                        msg_rate_hz=lam, load_packet_bytes=size)


# ------------------------------------------------------------------- path loss
def test_C1_winner_b1_breakpoint():
    """C1: d'_BP = 4 (1.5-0.5)(1.5-0.5) f/c ~ 78.6 m (5.9 GHz: 78.7 m with the exact c)."""
    assert pathloss.winner_b1_breakpoint_m(5.9, 1.5, 1.5, 0.5) == pytest.approx(78.6, abs=0.15)


@pytest.mark.parametrize("d, expected", [(100.0, 89.6), (200.0, 101.7), (500.0, 117.6)])
def test_C2_winner_b1_los_path_loss(d, expected):
    """C2: WINNER+ B1 LOS beyond the breakpoint, 5.9 GHz, h' = 1 m."""
    assert pathloss.winner_b1_los_db(d, 5.9, 1.5, 1.5, 0.5) == pytest.approx(expected, abs=0.05)
    assert ChannelModel(freq_ghz=5.9).los_path_loss_db(d) == pytest.approx(expected, abs=0.05)


def test_C2_winner_b1_is_continuous_and_never_below_free_space():
    d = np.linspace(3.0, 1000.0, 5000)
    pl = pathloss.winner_b1_los_db(d, 5.9)
    assert np.all(np.diff(pl) > 0)
    assert np.all(pl >= pathloss.winner_free_space_db(d, 5.9) - 1e-12)
    d_bp = pathloss.winner_b1_breakpoint_m(5.9, 1.5, 1.5, 0.5)
    jump = np.diff(pathloss.winner_b1_los_db([d_bp * (1 - 1e-9), d_bp * (1 + 1e-9)], 5.9))
    assert abs(float(jump[0])) < 0.05  # the two B1 branches meet at the breakpoint


def test_C3_tr37885_urban_los_nlos():
    """C3: TR 37.885 urban at 100 m: LOS 86.2 dB (sigma 3), NLOS 111.4 dB (sigma 4)."""
    assert pathloss.tr37885_urban_db(100.0, 5.9, True) == pytest.approx(86.2, abs=0.05)
    assert pathloss.tr37885_urban_db(100.0, 5.9, False) == pytest.approx(111.4, abs=0.05)
    assert pathloss.default_shadowing_sigma_db("tr37885_urban", False) == 3.0
    assert pathloss.default_shadowing_sigma_db("tr37885_urban", True) == 4.0
    m = ChannelModel(pathloss_model="tr37885_urban", obstacle_model="tr37885_nlos")
    nlos = m.evaluate([0, 0, 0], [100, 0, 0], walls=1)
    los = m.evaluate([0, 0, 0], [100, 0, 0], walls=0)
    assert float(nlos.path_loss_db) == pytest.approx(111.4, abs=0.05)
    assert float(los.path_loss_db) == pytest.approx(86.2, abs=0.05)


def test_C4_tr37885_los_probability():
    """C4: urban 100 m -> 0.336; highway 500 m -> 0.515."""
    assert pathloss.los_probability_tr37885(100.0, "urban") == pytest.approx(0.336, abs=5e-4)
    assert pathloss.los_probability_tr37885(500.0, "highway") == pytest.approx(0.515, abs=5e-4)
    assert pathloss.los_probability_tr37885(0.0, "urban") == 1.0
    with pytest.raises(ValueError, match="scenario"):
        pathloss.los_probability_tr37885(10.0, "rural")


def test_C5_building_loss():
    """C5: 9 dB per wall + 0.4 dB per metre inside; 2 walls + 20 m -> 26.0 dB, added to the LOS loss."""
    assert pathloss.obstacle_loss_db(2, 20.0) == pytest.approx(26.0, abs=1e-12)
    m = ChannelModel()
    blocked = m.evaluate([0, 0, 0], [150, 0, 0], walls=2, inside_m=20.0)
    clear = m.evaluate([0, 0, 0], [150, 0, 0])
    assert float(blocked.obstacle_loss_db) == pytest.approx(26.0)
    assert float(blocked.path_loss_db - clear.path_loss_db) == pytest.approx(26.0, abs=1e-9)
    assert float(blocked.pdr) < 0.05 < 0.9 < float(clear.pdr)


# ------------------------------------------------------------------- fading, airtime, PER, noise
def test_C6_nakagami_shape_and_outage():
    """C6: m 1.5 below 80 m, 0.75 beyond; P(gain < -10 dB) = 0.040 for m = 1.5 (exact and sampled)."""
    assert errors.nakagami_m(79.9) == 1.5 and errors.nakagami_m(80.0) == 0.75
    assert errors.nakagami_outage(1.5, 10.0) == pytest.approx(0.040, abs=5e-4)
    u = (np.arange(200000) + 0.5) / 200000  # the inverse CDF the per-packet draws use
    assert np.mean(errors.nakagami_gain_db(1.5, u) < -10.0) == pytest.approx(0.040, abs=5e-4)
    y, w = errors.nakagami_log_gain_pdf(1.5)
    assert w.sum() == pytest.approx(1.0, abs=1e-12)
    assert np.sum(w * 10 ** (y / 10)) == pytest.approx(1.0, abs=0.01)  # unit mean power


def test_C7_80211p_airtime():
    """C7: 300 B at 6 Mb/s (10 MHz): 40 us preamble+SIGNAL + 51 x 8 us = 448 us."""
    assert errors.ofdm_80211p_airtime_s(300, 6e6) == pytest.approx(448e-6, abs=1e-12)
    assert errors.ofdm_80211p_airtime_s(300, 12e6, bandwidth_hz=20e6) == pytest.approx(224e-6, abs=1e-12)


@pytest.mark.parametrize("snr_db, expected, tol", [(7.0, 0.019, 5e-4), (8.0, 3.9e-4, 5e-6)])
def test_C8_nist_per(snr_db, expected, tol):
    """C8: NIST PER of 300 B (2400 bits) at 6 Mb/s (QPSK 1/2) over AWGN."""
    assert errors.nist_per(snr_db, 2400, 6e6) == pytest.approx(expected, abs=tol)
    assert errors.nist_per_curve(2400, 6e6)(snr_db) == pytest.approx(expected, abs=max(tol, 1e-3 * expected))


def test_C8_nist_per_is_monotone_and_rates_are_ordered():
    snr = np.linspace(-5, 30, 200)
    per = {r: errors.nist_per(snr, 2400, r) for r in errors.RATES_80211P_10MHZ}
    for r, curve in per.items():
        assert np.all(np.diff(curve) <= 1e-15), r
    # a faster MCS needs more SNR for PER 0.1
    need = [snr[np.argmax(per[r] < 0.1)] for r in sorted(per)]
    assert need == sorted(need)
    with pytest.raises(ValueError, match="data_rate_bps"):
        errors.nist_per(10.0, 100, 5e6)


def test_C9_thermal_noise():
    """C9: kTB over 10 MHz = -104.0 dBm; with 9 dB noise figure -95.0 dBm."""
    assert errors.thermal_noise_dbm(10e6) == pytest.approx(-104.0, abs=0.05)
    assert errors.thermal_noise_dbm(10e6, 9.0) == pytest.approx(-95.0, abs=0.05)
    assert ChannelParams().noise_dbm == pytest.approx(-95.0, abs=0.05)
    # C-V2X: noise over the 10 data RBs of 50 (Gonzalez-Martin et al. 2019)
    assert ChannelParams(technology="cv2x").noise_dbm == pytest.approx(-95.0 - 10 * math.log10(5), abs=0.05)


# ------------------------------------------------------------------- PDR anchors
def test_C10_single_link_80211p_pdr():
    """C10 (Sepulcre et al. 2021 model, no interference): 0.967 / 0.749 / 0.366 at 200 / 250 / 300 m.

    Target 0.01; achieved: |diff| <= 0.0015 (closed-form integral instead of the
    paper code's 0.1 dB grid, and kTB = -94.98 dBm instead of -95). Asserted at 0.003.
    """
    pdr = ChannelModel(**SEPULCRE).expected_pdr([200.0, 250.0, 300.0])
    diff = np.abs(pdr - [0.967, 0.749, 0.366])
    print(f"C10 model {np.round(pdr, 4)} vs published [0.967 0.749 0.366], max |diff| {diff.max():.4f}")
    assert diff.max() <= 0.003


def ring_links(n, radius, seed=0):
    """n links of length `radius`: transmitters spread over 100 km x 100 km (so that the
    shadowing field is sampled at independent places), receivers at random bearings."""
    rng = np.random.default_rng(seed)
    tx = np.column_stack([rng.uniform(-5e4, 5e4, (n, 2)), np.zeros(n)])
    angle = rng.uniform(0.0, 2 * np.pi, n)
    rx = tx + np.column_stack([radius * np.cos(angle), radius * np.sin(angle), np.zeros(n)])
    return tx, rx


def test_C10_per_packet_draws_reproduce_the_expected_pdr():
    """Delivered flags over many packets and places at 250 m average to the analytic PDR (C10).

    20 000 links of 250 m at independent places, one packet each: binomial standard
    error 0.003; tolerance 0.015 (5 sigma). Shadowing std over the places: 3 dB.
    """
    m = ChannelModel(**SEPULCRE)
    tx, rx = ring_links(20000, 250.0)
    st = m.evaluate(tx, rx, seq=7, rx_id=np.arange(20000))
    assert np.allclose(st.pdr, 0.749, atol=0.003)
    assert st.delivered.mean() == pytest.approx(float(st.pdr.mean()), abs=0.015)
    assert np.std(st.shadowing_db) == pytest.approx(3.0, rel=0.05)


def test_C6_nakagami_per_packet_draws_reproduce_the_expected_pdr():
    """With Nakagami fading (and the AWGN NIST curve) the per-packet draws average to the expected PDR."""
    m = ChannelModel(fading="nakagami", error_model="nist")
    for radius in (60.0, 200.0):
        tx, rx = ring_links(20000, radius, seed=int(radius))
        st = m.evaluate(tx, rx, seq=3, rx_id=np.arange(20000))
        assert st.delivered.mean() == pytest.approx(float(st.pdr.mean()), abs=0.015), radius
        assert np.mean(st.fading_db < -10) > 0.01  # fading is on
    assert ChannelModel(fading="nakagami", error_model="nist").expected_pdr(200.0) < \
        ChannelModel(error_model="nist").expected_pdr(200.0)


def test_C11_80211p_pdr_under_load():
    """C11 (Sepulcre et al. 2021, simulated): 0.852 at 200 m, 0.297 at 300 m (0.06 veh/m, 10 Hz, 190 B).

    Target 0.05; achieved 0.008 at 200 m and 0.002 at 300 m. Asserted at 0.01.
    """
    m = model_for("IEEE 802.11p", "PDR_0.06vehm_6Mbps_10Hz_Pt23_190Bytes")
    pdr = m.expected_pdr([200.0, 300.0])
    print(f"C11 model {np.round(pdr, 3)} vs published [0.852 0.297]; CBR {m.cbr:.3f}")
    assert np.abs(pdr - [0.852, 0.297]).max() <= 0.01
    assert 0.0 < m.cbr < 0.2


def test_C12_cv2x_mode4_pdr():
    """C12 (Gonzalez-Martin et al. 2019, simulated): 0.916 / 0.715 / 0.331 at 300 / 400 / 500 m.

    Target 0.05; achieved 0.037 (the published analytical model itself is 0.029 / 0.023 / 0.037
    below the simulation there; our implementation matches that analytical curve within 0.001).
    Asserted at 0.04.
    """
    m = model_for("C-V2X mode4", "cv2x_fig_CV2XMode4_beta0.1-lambda10-Pt20-S4-B190_PDR")
    pdr = m.expected_pdr([300.0, 400.0, 500.0])
    print(f"C12 model {np.round(pdr, 3)} vs published [0.916 0.715 0.331]; CBR {m.cbr:.3f}")
    assert np.abs(pdr - [0.916, 0.715, 0.331]).max() <= 0.04


def test_published_pdr_curves():
    """pdr_vs_distance.csv: every published configuration, model curve beside the published ones.

    Printed: max |model - simulation| per configuration (and, for C-V2X, against the
    published analytical curve). Asserted (all achieved values, see the table):
      802.11p: <= 0.01 for the C11 configuration, <= 0.03 for all six (worst 0.025,
               0.12 veh/m at 25 Hz);
      C-V2X:   <= 0.002 against the published analytical curve (the implementation check),
               and against simulation no further than the published analytical model is
               (+ 0.005); the worst is 0.12 (0.3 veh/m, 20 Hz), a gap of the published model.
    """
    curves = published_curves()
    lines = [f"{'technology':<13} {'config':<48} {'max|d| sim':>10} {'max|d| ana':>10} {'pub ana-sim':>11}"]
    worst = {}
    for (tech, config, kind), (dist, sim) in sorted(curves.items()):
        if kind != "simulation":
            continue
        pdr = model_for(tech, config).expected_pdr(dist)
        d_sim = float(np.max(np.abs(pdr - sim)))
        ana = curves.get((tech, config, "analytical"))
        d_ana = float(np.max(np.abs(pdr - ana[1]))) if ana else float("nan")
        pub_gap = float(np.max(np.abs(ana[1] - sim))) if ana else float("nan")
        worst[(tech, config)] = (d_sim, d_ana, pub_gap)
        lines.append(f"{tech:<13} {config.replace('cv2x_fig_CV2XMode4_', ''):<48} {d_sim:10.3f} {d_ana:10.3f} "
                     f"{pub_gap:11.3f}")
    print("\n" + "\n".join(lines))
    assert len(worst) == 18
    assert worst[("IEEE 802.11p", "PDR_0.06vehm_6Mbps_10Hz_Pt23_190Bytes")][0] <= 0.01
    for (tech, config), (d_sim, d_ana, pub_gap) in worst.items():
        if tech == "IEEE 802.11p":
            assert d_sim <= 0.03, config
        else:
            assert d_ana <= 0.002, config
            assert d_sim <= pub_gap + 0.005, config


def test_building_in_the_way_lowers_the_pdr_under_load_too():
    m = model_for("IEEE 802.11p", "PDR_0.06vehm_6Mbps_10Hz_Pt23_190Bytes")
    d = np.array([50.0, 100.0, 150.0])
    clear, blocked = m.expected_pdr(d), m.expected_pdr(d, walls=2, inside_m=10.0)
    assert np.all(blocked < clear)
    # the load loss grows with the excess loss: the building weakens the wanted signal, not the interferers
    assert np.all(m.load_loss(d, 22.0) > m.load_loss(d, 0.0))


def test_load_table_matches_the_exact_load_model():
    """The (distance x 2.5 dB excess) table that per-packet evaluation uses is within 0.005 of the exact loss."""
    for tech, config in (("IEEE 802.11p", "PDR_0.12vehm_6Mbps_25Hz_Pt23_190Bytes"),
                         ("C-V2X mode4", "cv2x_fig_CV2XMode4_beta0.2-lambda10-Pt20-S4-B190_PDR")):
        m = model_for(tech, config)
        d = np.array([1.0, 4.2, 13.0, 77.0, 104.0, 201.0, 333.0, 487.0])
        for excess in (0.0, 7.5, 23.0):
            exact = m.load.loss(d, excess)[:, 0]
            assert np.max(np.abs(m.load_loss(d, excess) - exact)) < 0.005, (config, excess)


def test_cbr_target_sets_the_density():
    for tech in ("dsrc", "cv2x"):
        m = ChannelModel(technology=tech, cbr_target=0.3)
        assert m.cbr == pytest.approx(0.3, abs=1e-3) and m.density > 0
    with pytest.raises(ValueError, match="cbr_target"):
        ChannelParams(cbr_target=1.2).validate()


# ------------------------------------------------------------------- latency
def test_C13_sps_mean_access_latency():
    """C13: SPS offset uniform over the 4..100 ms window: mean 52 ms; reservations last 5..15 packets."""
    sps = access.SpsSchedule(seed=3, t1_ms=4, t2_ms=100, rri_ms=100)
    seq = np.arange(3000)
    delays = np.concatenate([sps.access_delay_ms(tx, seq) for tx in range(40)])
    assert delays.min() >= 4 and delays.max() <= 100
    assert delays.mean() == pytest.approx(52.0, abs=1.0)
    one = sps.access_delay_ms(0, seq)
    runs = np.diff(np.flatnonzero(np.diff(one) != 0))
    assert runs.min() >= 5 and runs.max() <= 15 * 3  # a re-draw can repeat the same offset
    # the same packet gets the same offset whatever is asked before it
    fresh = access.SpsSchedule(seed=3)
    assert fresh.access_delay_ms(0, 2999) == one[2999]
    m = ChannelModel(technology="cv2x", processing_s=0.0)
    lat = [m.evaluate_one((0, 0, 0), (100, 0, 0), seq=k)["latency_s"] for k in range(400)]
    assert 0.005 <= min(lat) and max(lat) <= 0.102


def test_C14_80211p_latency_low_load_and_under_load():
    """C14: AIFS + airtime = 0.40 ms for 190 B + 30 B header at 6 Mb/s (0.4-0.6 ms on air);
    the default 2 ms of device processing lies in the 1-5 ms band. Under load it grows."""
    air = ChannelModel(processing_s=0.0)
    lat = air.evaluate_one((0, 0, 0), (100, 0, 0), packet_bytes=190)["latency_s"]
    assert 0.4e-3 <= lat <= 0.6e-3
    assert lat == pytest.approx(32e-6 + 2 * 13e-6 + 40e-6 + 38 * 8e-6 + 100 / 299792458.0, abs=1e-12)
    dev = ChannelModel().evaluate_one((0, 0, 0), (100, 0, 0))["latency_s"]
    assert 1e-3 <= dev - lat <= 5e-3
    loaded = ChannelModel(processing_s=0.0, density_veh_per_m=0.12, msg_rate_hz=25)
    lats = loaded.evaluate(np.zeros(3), np.array([100.0, 0, 0]), seq=np.arange(5000)).latency_s
    assert lats.min() == pytest.approx(lat, abs=1e-9) and lats.mean() > lat + 20e-6
    assert np.mean(lats > lat + 1e-9) == pytest.approx(loaded.cbr, abs=0.03)


# ------------------------------------------------------------------- determinism
def test_same_seed_same_loss_pattern_other_seed_another():
    seq = np.arange(2000)
    rx = np.column_stack([150.0 + 0.1 * seq, np.full(2000, 40.0), np.zeros(2000)])  # driving away
    a = ChannelModel(seed=11).evaluate(np.zeros(3), rx, seq=seq)
    b = ChannelModel(seed=11).evaluate(np.zeros(3), rx, seq=seq)
    c = ChannelModel(seed=12).evaluate(np.zeros(3), rx, seq=seq)
    assert np.array_equal(a.delivered, b.delivered) and np.array_equal(a.latency_s, b.latency_s)
    assert not np.array_equal(a.delivered, c.delivered)
    assert 0.05 < a.delivered.mean() < 0.95


def test_a_link_does_not_depend_on_the_other_links():
    """One receiver evaluated alone, or among 1000 others, in any order: identical results."""
    m = ChannelModel(fading="nakagami", error_model="nist", density_veh_per_m=0.06)
    rng = np.random.default_rng(5)
    rx = np.column_stack([rng.uniform(-400, 400, (1000, 2)), np.zeros(1000)])
    ids = np.arange(1000)
    many = m.evaluate(np.zeros(3), rx, walls=ids % 3, inside_m=(ids % 3) * 4.0, seq=42, rx_id=ids)
    for i in (0, 517, 999):
        alone = m.evaluate(np.zeros(3), rx[i], walls=i % 3, inside_m=(i % 3) * 4.0, seq=42, rx_id=i)
        for field in ("delivered", "latency_s", "rx_power_dbm", "pdr", "per", "fading_db"):
            assert getattr(alone, field) == getattr(many, field)[i], (i, field)
    perm = rng.permutation(1000)
    shuffled = ChannelModel(m.p).evaluate(np.zeros(3), rx[perm], walls=perm % 3, inside_m=(perm % 3) * 4.0,
                                          seq=42, rx_id=perm)
    assert np.array_equal(shuffled.delivered, many.delivered[perm])


def test_scalar_path_matches_the_vectorised_model():
    """evaluate_one (the FMU's step) gives exactly what evaluate gives, for every configuration."""
    configs = [dict(), dict(density_veh_per_m=0.06), dict(technology="cv2x", density_veh_per_m=0.1),
               dict(fading="nakagami", error_model="nist"), dict(shadowing_sigma_db=0.0),
               dict(pathloss_model="tr37885_urban", obstacle_model="tr37885_nlos"),
               dict(pathloss_model="free_space", tx_gain_dbi=3.0, tx_antenna_height_m=5.0)]
    rng = np.random.default_rng(1)
    for cfg in configs:
        m = ChannelModel(seed=4, **cfg)
        for _ in range(25):
            tx, rx = rng.uniform(-300, 300, 3), rng.uniform(-300, 300, 3)
            tx[2], rx[2] = rng.uniform(0, 3, 2)
            args = (int(rng.integers(0, 3)), float(rng.uniform(0, 30)), int(rng.integers(1, 1500)),
                    int(rng.integers(0, 10**6)), int(rng.integers(-5, 5)), int(rng.integers(0, 99)))
            one = m.evaluate_one(tuple(tx), tuple(rx), *args)
            vec = m.evaluate(tx, rx, *args)
            for key, val in one.items():
                assert float(getattr(vec, key)) == pytest.approx(float(val), rel=1e-12, abs=1e-12), (cfg, key)


def test_shadowing_field_statistics():
    """Unit variance over space, correlation exp(-1) at one decorrelation distance (Gudmundson)."""
    rng = np.random.default_rng(0)
    p = rng.uniform(-5000, 5000, (3000, 3))
    tx = np.zeros((3000, 3))
    corr, var = [], []
    h = np.array([10.0, 0.0, 0.0])
    for seed in range(20):
        f = pathloss.ShadowingField(seed, 10.0)
        a, b = f(tx, p), f(tx, p + h)
        var.append(a.var())
        corr.append(np.corrcoef(a, b)[0, 1])
    assert np.mean(var) == pytest.approx(1.0, abs=0.05)
    assert np.mean(corr) == pytest.approx(math.exp(-1.0), abs=0.06)
    f = pathloss.ShadowingField(1, 10.0)
    step = np.abs(f(tx, p + [0.1, 0, 0]) - f(tx, p))
    assert np.median(step) < 0.1  # moving 1 % of d_corr changes little
    assert np.array_equal(f(tx, p), pathloss.ShadowingField(1, 10.0)(tx, p))
    assert np.array_equal(f(tx[17], p[17]), f(tx, p)[17])  # bit-identical alone or in a batch


def test_hash_scalar_and_vector_agree():
    keys = np.array([0, 1, -7, 2**40, 123456789])
    vec = access.hash_uniform(9, access.Stream.DECODE, keys, keys[::-1])
    one = [access.hash_uniform_scalar(9, access.Stream.DECODE, int(a), int(b)) for a, b in zip(keys, keys[::-1])]
    assert vec.tolist() == one
    u = access.hash_uniform(0, 1, np.arange(100000))
    assert 0.0 <= u.min() and u.max() < 1.0 and u.mean() == pytest.approx(0.5, abs=0.005)


# ------------------------------------------------------------------- bad input
def test_zero_distance_is_defined():
    m = ChannelModel(density_veh_per_m=0.06)
    st = m.evaluate_one((5.0, 5.0, 0.0), (5.0, 5.0, 0.0))
    assert st["distance_m"] == 0.0
    assert st["path_loss_db"] == pytest.approx(float(m.los_path_loss_db(3.0)))
    assert all(math.isfinite(float(v)) for v in st.values())
    assert st["pdr"] > 0.95


@pytest.mark.parametrize("kwargs, name", [
    (dict(tx=(float("nan"), 0, 0)), "tx position"),
    (dict(rx=(0, float("inf"), 0)), "rx position"),
    (dict(packet_bytes=-5), "packet_bytes"),
    (dict(packet_bytes=0), "packet_bytes"),
    (dict(walls=-1), "walls"),
    (dict(inside_m=float("nan")), "inside_m"),
    (dict(seq=-1), "seq"),
])
def test_bad_inputs_raise_naming_the_input(kwargs, name):
    m = ChannelModel()
    args = dict(tx=(0.0, 0.0, 0.0), rx=(100.0, 0.0, 0.0)) | kwargs
    with pytest.raises(ValueError, match=re.escape(name)):
        m.evaluate_one(**args)
    with pytest.raises(ValueError, match=re.escape(name)):
        m.evaluate(**args)


def test_bad_input_in_a_batch_names_the_index():
    rx = np.zeros((5, 3))
    rx[:, 0] = 100.0
    rx[3, 1] = np.nan
    with pytest.raises(ValueError, match=r"rx position.*index \(3, 1\)"):
        ChannelModel().evaluate(np.zeros(3), rx)


@pytest.mark.parametrize("kwargs, name", [
    (dict(technology="wifi"), "technology"), (dict(pathloss_model="okumura"), "pathloss_model"),
    (dict(tx_power_dbm=float("nan")), "tx_power_dbm"), (dict(freq_ghz=0.0), "freq_ghz"),
    (dict(data_rate_bps=5e6), "data_rate_bps"), (dict(technology="cv2x", cv2x_subchannels=3), "cv2x_subchannels"),
    (dict(technology="cv2x", error_model="nist"), "error_model"), (dict(density_veh_per_m=-0.1), "density_veh_per_m"),
    (dict(obstacle_model="tr37885_nlos"), "obstacle_model"), (dict(sps_t2_ms=10.0), "sps_t2_ms"),
    (dict(decorrelation_m=0.0), "decorrelation_m"), (dict(sensing_threshold_dbm=-10.0), "sensing_threshold_dbm"),
])
def test_bad_parameters_raise_naming_the_parameter(kwargs, name):
    with pytest.raises(ValueError, match=re.escape(name)):
        ChannelModel(**kwargs)
