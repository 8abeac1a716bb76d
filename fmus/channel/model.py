"""V2X link model behind the V2XChannel FMU: one transmitter, any number of receivers.

`ChannelModel(params).evaluate(tx, rx, walls, inside_m, packet_bytes, seq, ...)`
takes numpy arrays (positions (..., 3)) and returns a `LinkState` of arrays,
so the FMU (one link) and a radio bridge (thousands of receivers) share one
code path.

For each link and packet:
  distance   3-D distance between the antennas (position + antenna height);
             path-loss formulas use max(d, min_distance_m) (3 m, as the
             Sepulcre / Gonzalez-Martin model code) so d = 0 stays finite.
  path loss  winner_b1 | tr37885_urban | free_space (pathloss.py) plus the
             building loss: `sommer` (9 dB per wall + 0.4 dB/m inside),
             `tr37885_nlos` (TR 37.885 NLOS formula when walls > 0, tr37885_urban
             only) or `none`.
  shadowing  sigma x a spatially correlated unit field of (tx, rx) positions
             (pathloss.ShadowingField, decorrelation distance d_corr).
  fading     none | nakagami: per-packet Gamma power gain, Veins' m(d).
  reception  the packet is lost if its power is below the sensing
             threshold (preamble detection), otherwise decoded with probability
             1 - PER(SNR) (errors.py: Goubet LUT or NIST for 802.11p, R1-160284
             LUT for C-V2X), and lost to load with probability L(d) (analytic.py:
             Sepulcre et al. for 802.11p, Gonzalez-Martin et al. for C-V2X).
             A further loss_prob (default 0) drops that share of the
             remaining frames whatever the radio conditions: a lossy link
             stated directly (what-if sweeps over packet loss).
             delivered = u < (1 - PER) (1 - L) (1 - loss_prob), u a uniform
             keyed by (seed, tx_id, rx_id, seq): raising loss_prob only ever
             removes deliveries, never adds one.
  pdr        E[(1 - PER)(1 - L)] (1 - loss_prob) over shadowing and fading at this distance and
             obstruction: the analytical PDR of the link (no draw).
  latency    802.11p: EDCA access (AIFS, backoff under load) + airtime +
             propagation + processing; C-V2X: SPS access delay + 1 ms subframe +
             propagation + processing (access.py).

Load: with `density_veh_per_m` > 0 (or `cbr_target` > 0, converted to a
density) the load loss L(d, excess) is tabulated once per parameter set
(shared by every model of that set in the process) over distance (geometric
3..100 m, then 10 m steps) and the excess loss over the LOS road (2.5 dB
steps, 0..50 dB); `expected_pdr` uses the exact model. The analytical load
models assume vehicles on a straight LOS road; a wall between our two ends
lowers the wanted signal (the excess) but not the interferers'.

Determinism: shadowing is a function of positions and seed, per-packet draws
of (seed, tx_id, rx_id, seq), SPS reservations of (seed, tx_id): nothing
depends on the step size, the order of calls or the other links evaluated.

Sources: see pathloss.py, errors.py, analytic.py and access.py; [Sep] and [GM]
below are Sepulcre et al., IEEE TVT 2021 and Gonzalez-Martin et al., IEEE TVT 2019.
"""
from __future__ import annotations

import math
import numbers
from dataclasses import dataclass, fields

import numpy as np

from fmus.channel import access, analytic, errors, pathloss
from fmus.channel.analytic import RadioSetup

__all__ = ["ChannelParams", "ChannelModel", "LinkState", "TECHNOLOGIES", "ERROR_MODELS", "FADING_MODELS",
           "OBSTACLE_MODELS"]

TECHNOLOGIES = ("dsrc", "cv2x")
ERROR_MODELS = ("lut", "nist")
FADING_MODELS = ("none", "nakagami")
OBSTACLE_MODELS = ("sommer", "tr37885_nlos", "none")
SENSING_DEFAULT_DBM = {"dsrc": -85.0, "cv2x": -90.5}  # [Sep] CCA/preamble detection; [GM] sensing threshold
CV2X_TOTAL_RBS = 50                                     # RBs in 10 MHz (TS 36.101)
SUBFRAME_S = 1e-3                                       # LTE TTI

_LOAD_D_STEP = 10.0  # beyond 100 m; below, a geometric grid (the wanted power changes fastest there)
_LOAD_EXCESS_STEP = 2.5
_LOAD_EXCESS = np.arange(0.0, 50.0 + _LOAD_EXCESS_STEP / 2, _LOAD_EXCESS_STEP)


@dataclass(frozen=True)
class ChannelParams:
    """Parameters of one link (FMU parameters of the same names). Defaults: 802.11p, 6 Mb/s, 23 dBm."""

    technology: str = "dsrc"
    pathloss_model: str = "winner_b1"
    freq_ghz: float = 5.9
    tx_power_dbm: float = 23.0
    tx_gain_dbi: float = 0.0
    rx_gain_dbi: float = 0.0
    tx_antenna_height_m: float = 1.5
    rx_antenna_height_m: float = 1.5
    env_height_m: float = 0.5
    noise_figure_db: float = 9.0
    bandwidth_hz: float = 10e6
    data_rate_bps: float = 6e6
    cv2x_subchannels: int = 4
    error_model: str = "lut"
    sensing_threshold_dbm: float = 0.0  # 0: technology default
    shadowing_sigma_db: float = -1.0    # < 0: the path-loss model's own
    decorrelation_m: float = 10.0
    fading: str = "none"
    obstacle_model: str = "sommer"
    wall_loss_db: float = 9.0
    inside_loss_db_per_m: float = 0.4
    min_distance_m: float = 3.0
    density_veh_per_m: float = 0.0
    cbr_target: float = 0.0
    msg_rate_hz: float = 10.0
    load_packet_bytes: int = 190
    mac_header_bytes: int = 30
    aifsn: int = 2
    cw_min: int = 3
    processing_s: float = 0.002
    sps_t1_ms: float = 4.0
    sps_t2_ms: float = 100.0
    sps_keep_prob: float = 0.0
    loss_prob: float = 0.0              # extra loss, independent of the radio (what-if sweeps)
    seed: int = 0

    def validate(self) -> None:
        """Raise ValueError naming the first bad parameter."""
        choices = {"technology": TECHNOLOGIES, "pathloss_model": pathloss.PATHLOSS_MODELS,
                   "error_model": ERROR_MODELS, "fading": FADING_MODELS, "obstacle_model": OBSTACLE_MODELS}
        for f in fields(self):
            val = getattr(self, f.name)
            if f.name in choices:
                if val not in choices[f.name]:
                    raise ValueError(f"parameter {f.name} must be one of {', '.join(choices[f.name])}; got {val!r}")
                continue
            if isinstance(val, bool) or not isinstance(val, numbers.Real) or not math.isfinite(val):
                raise ValueError(f"parameter {f.name} must be a finite number, got {val!r}")
        positive = ("freq_ghz", "tx_antenna_height_m", "rx_antenna_height_m", "bandwidth_hz", "data_rate_bps",
                    "decorrelation_m", "min_distance_m", "msg_rate_hz", "load_packet_bytes", "sps_t2_ms")
        for name in positive:
            if getattr(self, name) <= 0:
                raise ValueError(f"parameter {name} must be > 0, got {getattr(self, name)!r}")
        non_negative = ("noise_figure_db", "wall_loss_db", "inside_loss_db_per_m", "density_veh_per_m",
                        "mac_header_bytes", "aifsn", "cw_min", "processing_s", "sps_t1_ms", "env_height_m")
        for name in non_negative:
            if getattr(self, name) < 0:
                raise ValueError(f"parameter {name} must be >= 0, got {getattr(self, name)!r}")
        if not 0.0 <= self.cbr_target < 0.95:
            raise ValueError(f"parameter cbr_target must be in [0, 0.95) (0: use density), got {self.cbr_target!r}")
        if not 0.0 <= self.loss_prob < 1.0:
            raise ValueError(f"parameter loss_prob must be in [0, 1), got {self.loss_prob!r}")
        if not 0.0 <= self.sps_keep_prob <= 0.8:
            raise ValueError(f"parameter sps_keep_prob must be in [0, 0.8] (TS 36.331), got {self.sps_keep_prob!r}")
        if not self.sps_t1_ms <= 4 or not 20 <= self.sps_t2_ms <= 100:
            raise ValueError(f"parameters sps_t1_ms <= 4 and 20 <= sps_t2_ms <= 100 (TS 36.213), "
                             f"got {self.sps_t1_ms!r}, {self.sps_t2_ms!r}")
        if self.sensing_threshold_dbm != 0.0 and not -130.0 <= self.sensing_threshold_dbm <= -30.0:
            raise ValueError(f"parameter sensing_threshold_dbm must be in [-130, -30] dBm (or 0 for the "
                             f"technology default), got {self.sensing_threshold_dbm!r}")
        if self.technology == "dsrc" and float(self.data_rate_bps) not in errors.RATES_80211P_10MHZ:
            raise ValueError(f"parameter data_rate_bps must be an 802.11p rate at 10 MHz "
                             f"{[r / 1e6 for r in sorted(errors.RATES_80211P_10MHZ)]} Mb/s, got {self.data_rate_bps!r}")
        if self.technology == "cv2x":
            if self.cv2x_subchannels not in (2, 4):
                raise ValueError(f"parameter cv2x_subchannels must be 2 or 4, got {self.cv2x_subchannels!r}")
            if self.error_model != "lut":
                raise ValueError("parameter error_model must be 'lut' for cv2x (the NIST model is 802.11p's)")
        if self.obstacle_model == "tr37885_nlos" and self.pathloss_model != "tr37885_urban":
            raise ValueError("parameter obstacle_model 'tr37885_nlos' needs pathloss_model 'tr37885_urban'")
        if self.msg_rate_hz > 100:
            raise ValueError(f"parameter msg_rate_hz must be <= 100 Hz, got {self.msg_rate_hz!r}")

    # -- derived values ------------------------------------------------------------
    @property
    def sensing_dbm(self) -> float:
        return self.sensing_threshold_dbm or SENSING_DEFAULT_DBM[self.technology]

    @property
    def noise_dbm(self) -> float:
        """[kTB] + NF over the channel (C9); C-V2X: over the data RBs (Gonzalez-Martin: N0 + 10 log10(RBs/50))."""
        n = float(errors.thermal_noise_dbm(self.bandwidth_hz, self.noise_figure_db))
        if self.technology == "cv2x":
            n += 10.0 * math.log10(errors.CV2X_DATA_RBS[self.cv2x_subchannels] / CV2X_TOTAL_RBS)
        return n


@dataclass
class LinkState:
    """Everything the model says about a batch of links (arrays of one shape)."""

    distance_m: np.ndarray
    path_loss_db: np.ndarray
    obstacle_loss_db: np.ndarray
    shadowing_db: np.ndarray
    fading_db: np.ndarray
    rx_power_dbm: np.ndarray
    snr_db: np.ndarray
    per: np.ndarray
    pdr: np.ndarray
    delivered: np.ndarray
    latency_s: np.ndarray


def _check(name, arr, lo=None, integer=False):
    """Raise a ValueError naming the input (and the first bad index) if it is not finite / in range."""
    bad = ~np.isfinite(arr) if arr.dtype.kind == "f" else np.zeros(arr.shape, bool)
    if lo is not None:
        bad |= arr < lo
    if integer and arr.dtype.kind == "f":
        bad |= arr != np.round(arr)
    if bad.any():
        where = tuple(int(i) for i in np.argwhere(bad)[0])
        what = f"finite and >= {lo}" if lo is not None else "finite"
        raise ValueError(f"input {name} must be {what}; got {arr[where] if where else arr[()]!r}"
                         + (f" at index {where}" if where else ""))


class ChannelModel:
    """One transmitter's radio (one technology and parameter set); evaluates any number of receivers."""

    def __init__(self, params: ChannelParams | None = None, **overrides):
        p = params or ChannelParams()
        if overrides:
            p = ChannelParams(**{**{f.name: getattr(p, f.name) for f in fields(p)}, **overrides})
        p.validate()
        self.p = p
        self.shadow_field = pathloss.ShadowingField(p.seed, p.decorrelation_m)
        self.sps = access.SpsSchedule(p.seed, p.sps_t1_ms, p.sps_t2_ms, 1000.0 / p.msg_rate_hz, p.sps_keep_prob)
        # Deterministic tables (PER curves, success tables, load model and table) depend on the
        # parameters but not on the seed: models with equal parameters in one process share them
        # (100 FMU instances of one configuration build them once).
        shared = _shared_tables(p)
        self._curves: dict[int, errors.PwlCurve] = shared["curves"]
        self._tables: dict[tuple, tuple[np.ndarray, np.ndarray]] = shared["tables"]
        self._shared = shared
        if "load" not in shared:
            density = self._density()
            shared["density"] = density
            shared["load"] = self._load_model(density) if density > 0 else None
        self.density, self.load = shared["density"], shared["load"]
        self.cbr = self.load.cbr if self.load else 0.0

    @property
    def _load_table(self):
        return self._shared.get("load_table")

    def prepare(self) -> "ChannelModel":
        """Build the lazily built tables now (the FMU calls it at initialisation)."""
        if self.load is not None and "load_table" not in self._shared:
            self._shared["load_table"] = self._tabulate_load()
        return self

    # -- propagation ------------------------------------------------------------
    def los_path_loss_db(self, d, h_tx=None, h_rx=None):
        """Path loss of the configured model, LOS, at distance d (clamped to min_distance_m)."""
        p = self.p
        d = np.maximum(np.asarray(d, float), p.min_distance_m)
        h_tx = p.tx_antenna_height_m if h_tx is None else h_tx
        h_rx = p.rx_antenna_height_m if h_rx is None else h_rx
        if p.pathloss_model == "winner_b1":
            return pathloss.winner_b1_los_db(d, p.freq_ghz, h_tx, h_rx, p.env_height_m)
        if p.pathloss_model == "tr37885_urban":
            return pathloss.tr37885_urban_db(d, p.freq_ghz, True)
        return pathloss.free_space_db(d, p.freq_ghz)

    @property
    def eirp_gain_dbm(self) -> float:
        p = self.p
        return p.tx_power_dbm + p.tx_gain_dbi + p.rx_gain_dbi

    def curve(self, packet_bytes: int) -> errors.PwlCurve:
        """PER versus SNR for a packet of `packet_bytes` application bytes (cached)."""
        p = self.p
        key = int(packet_bytes) if p.error_model == "nist" else 0
        if key not in self._curves:
            if p.technology == "cv2x":
                c = errors.cv2x_bler_curve(p.cv2x_subchannels)
            elif p.error_model == "lut":
                c = errors.goubet_fer_curve(p.data_rate_bps, p.bandwidth_hz)
            else:
                c = errors.nist_per_curve(8 * (key + p.mac_header_bytes), p.data_rate_bps)
            self._curves[key] = c
        return self._curves[key]

    def road_setup(self, packet_bytes=None) -> RadioSetup:
        """The analytical models' view: LOS road, this radio's power, shadowing, threshold, noise and PER."""
        p = self.p
        sigma = float(pathloss.default_shadowing_sigma_db(p.pathloss_model)) if p.shadowing_sigma_db < 0 \
            else p.shadowing_sigma_db
        eirp = self.eirp_gain_dbm
        return RadioSetup(lambda d: eirp - self.los_path_loss_db(d), sigma, p.sensing_dbm, p.noise_dbm,
                          self.curve(p.load_packet_bytes if packet_bytes is None else packet_bytes))

    # -- expected link success (over shadowing and fading) -----------------------
    def link_success(self, mean_rx_dbm, sigma_db, distance_m=None, packet_bytes=None):
        """(1 - delta_SEN)(1 - delta_PRO) averaged over shadowing (and Nakagami fading if on).

        Evaluated by interpolation in a per-(sigma, m, curve) table over the mean
        received power (0.02 dB grid without fading: interpolation error < 1e-5
        for sigma >= 1 dB); below 1 dB of shadowing and without fading the
        function is too steep for a table and the closed form is used.
        """
        p = self.p
        curve = self.curve(p.load_packet_bytes if packet_bytes is None else packet_bytes)
        mean_rx_dbm = np.asarray(mean_rx_dbm, float)
        m = None if p.fading == "none" else errors.nakagami_m(0.0 if distance_m is None else distance_m)
        if np.ndim(sigma_db) == 0 and (m is None or np.ndim(m) == 0):  # one table (the FMU's case)
            return self._success(mean_rx_dbm, float(sigma_db), None if m is None else float(m), curve)
        mr, sg, mm = np.broadcast_arrays(mean_rx_dbm, sigma_db, -1.0 if m is None else m)  # -1: no fading
        out = np.empty(mr.shape)
        for key in set(zip(sg.ravel().tolist(), mm.ravel().tolist())):
            sel = (sg == key[0]) & (mm == key[1])
            out[sel] = self._success(mr[sel], key[0], None if key[1] < 0 else key[1], curve)
        return out

    def _success(self, mean_rx_dbm, sigma, m, curve):
        p = self.p
        if m is None and sigma < 1.0:
            return analytic.link_success(mean_rx_dbm, sigma, p.sensing_dbm, p.noise_dbm, curve)
        grid, table = self._success_table(sigma, m, curve)
        return np.interp(mean_rx_dbm, grid, table)

    def _success_table(self, sigma, m, curve):
        """Success versus mean received power on a fine grid; with fading, convolved with the
        Nakagami-m log-gain distribution (0.1 dB grid)."""
        key = (sigma, m, curve.name)
        if key not in self._tables:
            p = self.p
            if m is None:
                step = 0.02
                grid = np.arange(p.sensing_dbm - 10.0 * sigma - 1.0, p.sensing_dbm + 100.0, step)
                table = analytic.link_success(grid, sigma, p.sensing_dbm, p.noise_dbm, curve)
            else:
                y, w = errors.nakagami_log_gain_pdf(m)
                step = 0.1
                grid = np.arange(p.sensing_dbm - 40.0 - 10.0 * sigma, p.sensing_dbm + 100.0, step)
                # success at mean power P + y for every fading level y: a convolution on the common grid
                ext = np.arange(grid[0] + y[0], grid[-1] + y[-1] + step / 2, step)
                ls = analytic.link_success(ext, sigma, p.sensing_dbm, p.noise_dbm, curve)
                table = np.convolve(ls, w[::-1], mode="valid")[: grid.size]
            self._tables[key] = (grid, table)
        return self._tables[key]

    # -- load --------------------------------------------------------------------------
    def _load_model(self, density):
        p = self.p
        setup = self.road_setup()
        if p.technology == "dsrc":
            return analytic.Dsrc80211pLoad(setup, density, p.msg_rate_hz, p.load_packet_bytes, p.data_rate_bps,
                                           p.mac_header_bytes)
        return analytic.Cv2xMode4Load(setup, density, p.msg_rate_hz, p.cv2x_subchannels)

    def _density(self) -> float:
        """density_veh_per_m, or the density whose modelled CBR is cbr_target."""
        p = self.p
        if p.density_veh_per_m > 0 or p.cbr_target == 0:
            return float(p.density_veh_per_m)
        setup = self.road_setup()
        if p.technology == "dsrc":
            return analytic.Dsrc80211pLoad.density_for_cbr(setup, p.cbr_target, p.msg_rate_hz, p.load_packet_bytes,
                                                           p.data_rate_bps, p.mac_header_bytes)
        return analytic.Cv2xMode4Load.density_for_cbr(setup, p.cbr_target, p.msg_rate_hz, p.cv2x_subchannels)

    def _tabulate_load(self):
        """L(d, excess): d on 0, 3..100 m geometric (40 points), then 10 m steps up to where the
        LOS link success has vanished; excess 0..50 dB in 2.5 dB steps."""
        setup = self.road_setup()
        d_far = np.arange(100.0 + _LOAD_D_STEP, 3000.0 + _LOAD_D_STEP, _LOAD_D_STEP)
        ls = analytic.link_success(setup.rx_mean_dbm(d_far), setup.sigma_db, setup.sensing_dbm, setup.noise_dbm,
                                   setup.curve)
        alive = np.flatnonzero(ls > 1e-7)
        d_far = d_far[: min(int(alive[-1]) + 3 if alive.size else 3, d_far.size)]
        d = np.concatenate(([0.0], np.geomspace(self.p.min_distance_m, 100.0, 40), d_far))
        d = np.unique(d)
        table = self.load.loss(d, _LOAD_EXCESS)
        return d, table

    def load_loss(self, d, excess_db):
        """Bilinear interpolation of the tabulated load loss (0 without load), constant beyond the grid."""
        if self.load is None:
            return np.zeros(np.broadcast_shapes(np.shape(d), np.shape(excess_db)))
        grid_d, table = self.prepare()._load_table
        d = np.clip(np.asarray(d, float), 0.0, grid_d[-1])
        i0 = np.clip(np.searchsorted(grid_d, d, side="right") - 1, 0, grid_d.size - 2)
        a = (d - grid_d[i0]) / (grid_d[i0 + 1] - grid_d[i0])
        fe = np.clip(np.asarray(excess_db, float) / _LOAD_EXCESS_STEP, 0.0, _LOAD_EXCESS.size - 1.0)
        j0 = np.minimum(np.floor(fe).astype(np.int64), _LOAD_EXCESS.size - 2)
        b = fe - j0
        return ((1 - a) * (1 - b) * table[i0, j0] + a * (1 - b) * table[i0 + 1, j0]
                + (1 - a) * b * table[i0, j0 + 1] + a * b * table[i0 + 1, j0 + 1])

    # -- curves (no draws) ---------------------------------------------------------------
    def expected_pdr(self, distance_m, walls=0, inside_m=0.0, packet_bytes=None):
        """Analytical PDR versus distance on the LOS road geometry (antennas at their heights, z = 0)."""
        d = np.asarray(distance_m, float)
        pl, extra, sigma = self._losses(d, np.asarray(walls), np.asarray(inside_m, float),
                                        self.p.tx_antenna_height_m, self.p.rx_antenna_height_m)
        mean = self.eirp_gain_dbm - pl
        excess = np.broadcast_to(pl - self.los_path_loss_db(d), np.shape(pl))
        if self.load is None:
            load = 0.0
        elif excess.size and np.all(excess == excess.flat[0]):  # one obstruction: the exact model, no table
            flat_d = np.ravel(np.broadcast_to(d, excess.shape))
            load = self.load.loss(flat_d, excess.flat[0])[:, 0].reshape(excess.shape)
        else:
            load = self.load_loss(d, excess)
        return self.link_success(mean, sigma, d, packet_bytes) * (1.0 - load) * (1.0 - self.p.loss_prob)

    def _losses(self, d, walls, inside, h_tx, h_rx):
        """(path loss incl. building loss, building loss, shadowing sigma) for these links."""
        p = self.p
        los_pl = self.los_path_loss_db(d, h_tx, h_rx)
        blocked = walls > 0
        if p.obstacle_model == "sommer":
            extra = pathloss.obstacle_loss_db(walls, inside, p.wall_loss_db, p.inside_loss_db_per_m)
            pl = los_pl + extra
        elif p.obstacle_model == "tr37885_nlos":
            pl = np.where(blocked, pathloss.tr37885_urban_db(np.maximum(d, p.min_distance_m), p.freq_ghz, False),
                          los_pl)
            extra = pl - los_pl
        else:
            pl, extra = los_pl, np.zeros(np.broadcast_shapes(np.shape(d), np.shape(walls)))
        if p.shadowing_sigma_db >= 0:
            sigma = np.full(np.shape(pl), float(p.shadowing_sigma_db))
        else:
            nlos = blocked & (p.obstacle_model == "tr37885_nlos")
            sigma = pathloss.default_shadowing_sigma_db(p.pathloss_model, np.broadcast_to(nlos, np.shape(pl)))
        return pl, extra, sigma

    # -- the per-packet evaluation ------------------------------------------------------
    def evaluate(self, tx, rx, walls=0, inside_m=0.0, packet_bytes=190, seq=0, tx_id=0, rx_id=0) -> LinkState:
        """One packet per link. tx, rx: (..., 3) world positions of the stations (antenna
        heights are added to z); the other inputs broadcast against the links' shape."""
        p = self.p
        tx = np.asarray(tx, float)
        rx = np.asarray(rx, float)
        _check("tx position", tx)
        _check("rx position", rx)
        shape = np.broadcast_shapes(tx.shape[:-1], rx.shape[:-1], np.shape(walls), np.shape(inside_m),
                                    np.shape(packet_bytes), np.shape(seq), np.shape(tx_id), np.shape(rx_id))
        walls = np.broadcast_to(np.asarray(walls), shape)
        inside = np.broadcast_to(np.asarray(inside_m, float), shape)
        size = np.broadcast_to(np.asarray(packet_bytes), shape)
        seq = np.broadcast_to(np.asarray(seq), shape)
        _check("walls", walls, 0, integer=True)
        _check("inside_m", inside, 0.0)
        _check("packet_bytes", size, 1, integer=True)
        _check("seq", seq, 0, integer=True)

        tx_ant = tx + np.array([0.0, 0.0, p.tx_antenna_height_m])
        rx_ant = rx + np.array([0.0, 0.0, p.rx_antenna_height_m])
        d = np.broadcast_to(np.linalg.norm(rx_ant - tx_ant, axis=-1), shape)
        pl, extra, sigma = self._losses(d, walls, inside, tx_ant[..., 2], rx_ant[..., 2])
        shadow = sigma * self.shadow_field(tx, rx)
        shadow = np.broadcast_to(shadow, shape)

        keys = (np.broadcast_to(np.asarray(tx_id), shape), np.broadcast_to(np.asarray(rx_id), shape), seq)
        if p.fading == "nakagami":
            fade = errors.nakagami_gain_db(errors.nakagami_m(d), hash_u(p.seed, access.Stream.FADING, keys))
        else:
            fade = np.zeros(shape)
        mean = self.eirp_gain_dbm - pl
        rx_power = mean + shadow + fade
        snr = rx_power - p.noise_dbm

        sizes = np.unique(size)
        per_link = np.empty(shape)
        for s in sizes:  # usually one packet size per call
            sel = size == s
            per_link[sel] = self.curve(int(s))(snr[sel])
        per_link = np.where(rx_power < p.sensing_dbm, 1.0, per_link)
        excess = pl - self.los_path_loss_db(d)
        load = self.load_loss(d, excess)
        success = (1.0 - per_link) * (1.0 - load) * (1.0 - p.loss_prob)
        delivered = hash_u(p.seed, access.Stream.DECODE, keys) < success

        pdr = np.empty(shape)
        for s in sizes:
            sel = size == s
            pdr[sel] = self.link_success(mean[sel], sigma[sel], d[sel], int(s))
        pdr = pdr * (1.0 - load) * (1.0 - p.loss_prob)

        latency = self._latency(keys[0], seq, size, d)
        return LinkState(d.copy(), pl, np.broadcast_to(extra, shape).copy(), shadow.copy(), fade, rx_power, snr,
                         1.0 - success, pdr, delivered, latency)

    def evaluate_one(self, tx, rx, walls=0, inside_m=0.0, packet_bytes=190, seq=0, tx_id=0, rx_id=0) -> dict:
        """`evaluate` for one link with Python scalars (the FMU's step): same results, ~5x less overhead.

        Returns a dict with the fields of LinkState as floats (delivered: bool).
        tests/test_channel_model.py checks it against `evaluate` field by field.
        """
        p = self.p
        tx = [float(v) for v in tx]
        rx = [float(v) for v in rx]
        for name, pos in (("tx position", tx), ("rx position", rx)):
            if len(pos) != 3 or not all(math.isfinite(v) for v in pos):
                raise ValueError(f"input {name} must be finite (x, y, z); got {tuple(pos)!r}")
        walls_f, inside, size_f, seq_f = float(walls), float(inside_m), float(packet_bytes), float(seq)
        for name, val, lo, integer in (("walls", walls_f, 0, True), ("inside_m", inside, 0.0, False),
                                       ("packet_bytes", size_f, 1, True), ("seq", seq_f, 0, True)):
            if not math.isfinite(val) or val < lo or (integer and val != round(val)):
                raise ValueError(f"input {name} must be finite and >= {lo}; got {val!r}")
        walls, size, seq, tx_id, rx_id = int(walls_f), int(size_f), int(seq_f), int(tx_id), int(rx_id)

        h_tx, h_rx = tx[2] + p.tx_antenna_height_m, rx[2] + p.rx_antenna_height_m
        d = math.dist((tx[0], tx[1], h_tx), (rx[0], rx[1], h_rx))
        los = float(self.los_path_loss_db(d, h_tx, h_rx))
        nlos = False
        if p.obstacle_model == "sommer":
            extra = p.wall_loss_db * walls + p.inside_loss_db_per_m * inside
        elif p.obstacle_model == "tr37885_nlos" and walls > 0:
            extra = float(pathloss.tr37885_urban_db(max(d, p.min_distance_m), p.freq_ghz, False)) - los
            nlos = True
        else:
            extra = 0.0
        pl = los + extra
        sigma = p.shadowing_sigma_db if p.shadowing_sigma_db >= 0 else \
            float(pathloss.default_shadowing_sigma_db(p.pathloss_model, nlos))
        shadow = sigma * float(self.shadow_field(tx, rx))
        if p.fading == "nakagami":
            m = float(errors.nakagami_m(d))
            fade = float(errors.nakagami_gain_db(m, access.hash_uniform_scalar(
                p.seed, access.Stream.FADING, tx_id, rx_id, seq)))
        else:
            m, fade = None, 0.0
        mean = self.eirp_gain_dbm - pl
        rx_power = mean + shadow + fade
        snr = rx_power - p.noise_dbm
        curve = self.curve(size)
        per_link = 1.0 if rx_power < p.sensing_dbm else float(curve(snr))
        if self.load is not None:
            road = los if (h_tx, h_rx) == (p.tx_antenna_height_m, p.rx_antenna_height_m) \
                else float(self.los_path_loss_db(d))
            load = float(self.load_loss(d, pl - road))
        else:
            load = 0.0
        success = (1.0 - per_link) * (1.0 - load) * (1.0 - p.loss_prob)
        delivered = access.hash_uniform_scalar(p.seed, access.Stream.DECODE, tx_id, rx_id, seq) < success
        pdr = float(self._success(mean, sigma, m, curve)) * (1.0 - load) * (1.0 - p.loss_prob)
        latency = float(self._latency(tx_id, seq, size, d))
        return {"distance_m": d, "path_loss_db": pl, "obstacle_loss_db": extra, "shadowing_db": shadow,
                "fading_db": fade, "rx_power_dbm": rx_power, "snr_db": snr, "per": 1.0 - success, "pdr": pdr,
                "delivered": bool(delivered), "latency_s": latency}

    def _latency(self, tx_id, seq, size, d):
        p = self.p
        prop = d / pathloss.SPEED_OF_LIGHT
        if p.technology == "dsrc":
            airtime = errors.ofdm_80211p_airtime_s(size + p.mac_header_bytes, p.data_rate_bps, p.bandwidth_hz)
            busy_frame = errors.ofdm_80211p_airtime_s(p.load_packet_bytes + p.mac_header_bytes, p.data_rate_bps,
                                                      p.bandwidth_hz)
            u = [hash_u(p.seed, st, (tx_id, seq)) for st in
                 (access.Stream.BUSY, access.Stream.RESIDUAL, access.Stream.BACKOFF)]
            wait = access.dsrc_access_delay_s(*u, self.cbr, busy_frame, p.aifsn, p.cw_min)
            return wait + airtime + prop + p.processing_s
        offset = self.sps.access_delay_ms(tx_id, seq) * 1e-3
        return offset + SUBFRAME_S + prop + p.processing_s


_SHARED: dict[ChannelParams, dict] = {}


def _shared_tables(p: ChannelParams) -> dict:
    """The table store of every model with these parameters (the seed aside); at most 32 kept."""
    key = ChannelParams(**{**{f.name: getattr(p, f.name) for f in fields(p)}, "seed": 0})
    if key not in _SHARED:
        if len(_SHARED) >= 32:
            _SHARED.pop(next(iter(_SHARED)))
        _SHARED[key] = {"curves": {}, "tables": {}}
    return _SHARED[key]


def hash_u(seed, stream, keys):
    """Uniforms keyed by (seed, stream, *keys) in the keys' common shape."""
    shape = np.broadcast_shapes(*(np.shape(k) for k in keys))
    if shape == ():
        return np.float64(access.hash_uniform_scalar(seed, stream, *(int(k) for k in keys)))
    flat = [np.broadcast_to(k, shape).ravel() for k in keys]
    return access.hash_uniform(seed, stream, *flat).reshape(shape)
