"""Analytical PDR of a V2X link: single link, and under load (802.11p and LTE-V2X mode 4).

Single link (no interference)
  A packet is received when its power exceeds the sensing threshold
  (preamble detection) and it is then decoded; with log-normal shadowing of
  mean m and std sigma (dB),
      PDR_link(m) = int_{P_sen}^{inf} N(p; m, sigma) (1 - PER(p - N0)) dp
                  = (1 - delta_SEN) (1 - delta_PRO)
  [Sep] eqs. (1), (3), (5), (12), (24) with delta_RXB = delta_COL = 0; the
  integral is evaluated in closed form for a piecewise-linear PER(SNR)
  (`PwlCurve.gauss_integral`) instead of the papers' 0.1 dB grid.

Under load (vehicles spaced 1/beta on a straight road, all sending lambda Hz)
  PDR = PDR_link * (1 - L), with the load loss L
    802.11p  [Sep]: L = 1 - (1 - delta_RXB') (1 - delta_COL') -- receiver busy
             with another packet (concurrent and hidden terminals, eqs. (14)-(22))
             and collisions (eqs. (26)-(32)); CBR from eqs. (34)-(35).
    C-V2X    [GM]: L = 1 - (1 - delta_HD) (1 - delta_COL') -- half duplex
             (eq. (7)) and SPS collisions mixing the Step-2 and Step-3 resource
             models by alpha(CBR) (eqs. (14)-(34)).
  Both papers write PDR = 1 - sum of the error types, each conditioned on
  the earlier ones not happening; that sum equals the product above.
  The per-interferer SINR error p_int (eqs. (18)/(31)) needs the PER of the
  wanted signal over the joint shadowing of signal and interference; here
  it is E_I[G(J)] with J = 10 log10(10^(I/10) + N0), I ~ N(m_i, sigma_i)
  integrated by Gauss-Hermite quadrature, and G(j) = E[PER(P - j) | P >= P_sen]
  evaluated in closed form on a 0.25 dB grid of j.

Sources
  [Sep] M. Sepulcre, M. Gonzalez-Martin, J. Gozalvez, R. Molina-Masegosa,
        B. Coll-Perales, "Analytical Models of the Performance of IEEE 802.11p
        Vehicle to Vehicle Communications", IEEE TVT 71(1), 2022 (online Nov.
        2021), DOI 10.1109/TVT.2021.3124708; model code github.com/msepulcre/IEEE802.11p-model.
  [GM]  M. Gonzalez-Martin, M. Sepulcre, R. Molina-Masegosa, J. Gozalvez,
        "Analytical Models of the Performance of C-V2X Mode 4 Vehicular
        Communications", IEEE TVT 68(2), 2019, DOI 10.1109/TVT.2018.2888704;
        model code github.com/msepulcre/C-V2X.
Equation numbers refer to those papers. The implementation is our own.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable

import numpy as np
from scipy.special import ndtr, roots_hermite

from fmus.channel.errors import PwlCurve

__all__ = ["RadioSetup", "link_success", "Dsrc80211pLoad", "Cv2xMode4Load"]

_GH_T, _GH_W = roots_hermite(24)  # Gauss-Hermite nodes for E over a Gaussian interferer power
_J_STEP_DB = 0.25                  # grid of the interference-plus-noise level J for G(j)
_ROAD_HALF_M = 1500                # PSR support, metres each side (both papers)
_INTERFERER_SPAN_M = 1000.0        # interferers up to 1000 m from the receiver (both papers)


@dataclass(frozen=True)
class RadioSetup:
    """What the analytical models need to know about the radio and the road.

    `rx_mean_dbm(d)`: mean received power (dBm) of a vehicle at distance d on the
    road, LOS, including transmit power and antenna gains; `sigma_db` the
    shadowing std; `curve` PER versus SNR/SINR (dB) of the wanted packet.
    """

    rx_mean_dbm: Callable[[np.ndarray], np.ndarray]
    sigma_db: float
    sensing_dbm: float
    noise_dbm: float
    curve: PwlCurve


def link_success(m_r, sigma, sensing_dbm, noise_dbm, curve: PwlCurve):
    """PDR of one link without interference: (1 - delta_SEN)(1 - delta_PRO), [Sep] (12), (24).

    P(P >= P_sen) - int_{P_sen}^inf N(p; m_r, sigma) PER(p - N0) dp, in closed form.
    """
    m_r = np.asarray(m_r, float)
    sigma = np.maximum(np.asarray(sigma, float), 1e-9)
    p_sensed = ndtr((m_r - sensing_dbm) / sigma)
    lost = curve.gauss_integral(m_r - noise_dbm, sigma, sensing_dbm - noise_dbm)
    return np.clip(p_sensed - lost, 0.0, 1.0)


def _psr_sum(setup: RadioSetup, sensing_dbm: float) -> float:
    """Sum of the packet sensing ratio over the road, 1 m steps, -1500..1500 m ([Sep] (34), [GM] (29.1))."""
    x = np.abs(np.arange(-_ROAD_HALF_M, _ROAD_HALF_M + 1, dtype=float))
    return float(ndtr((setup.rx_mean_dbm(x) - sensing_dbm) / max(setup.sigma_db, 1e-9)).sum())


class _Road:
    """Vehicles on a straight road around the receiver, and the PSR/autocorrelation tables."""

    def __init__(self, setup: RadioSetup, density: float, sensing_dbm: float):
        self.setup = setup
        self.beta = density
        x = np.arange(-_ROAD_HALF_M, _ROAD_HALF_M + 1, dtype=float)
        self.psr = self.psr_at(np.abs(x), sensing_dbm)  # [Sep] (13), [GM] (11)
        # autocorrelation of PSR, lags 0..2*_ROAD_HALF_M m ([Sep] (20), [GM] (30.2))
        n = self.psr.size
        spec = np.fft.rfft(self.psr, 2 * n)
        self.r_psr = np.fft.irfft(spec * np.conj(spec), 2 * n)[:n]
        self.r_psr = np.maximum(self.r_psr, 0.0)
        k = int(round(_INTERFERER_SPAN_M * density))  # Lint_max = round(1000 beta)/beta
        idx = np.concatenate((np.arange(-k, 0), np.arange(1, k + 1)))
        self.x_int = idx / density if k else np.zeros(0)  # interferer positions, receiver at 0, tx at -d

    def psr_at(self, dist, sensing_dbm):
        """Packet sensing ratio at distance: P(received power >= threshold)."""
        s = self.setup
        return ndtr((s.rx_mean_dbm(dist) - sensing_dbm) / max(s.sigma_db, 1e-9))

    def r_at(self, dist):
        """Autocorrelation at round(dist) metres (as the papers index it), zero beyond its support."""
        i = np.rint(np.abs(dist)).astype(np.int64)
        return np.where(i < self.r_psr.size, self.r_psr[np.minimum(i, self.r_psr.size - 1)], 0.0)


class _SinrError:
    """p_int: probability that one interferer turns a decodable packet into a lost one.

    p_int = (pSINR - delta_PRO') / (1 - delta_PRO')   [Sep] (31), [GM] (18)
    with pSINR = E[PER(SINR) | P >= P_sen] over the shadowing of signal and interferer.
    """

    def __init__(self, setup: RadioSetup, m_int):
        s = self.setup = setup
        sig = max(s.sigma_db, 1e-9)
        m_int = np.asarray(m_int, float)
        # Gauss-Hermite nodes of the interferer power, and J = I (+) N0 at each node
        i_nodes = m_int[:, None] + math.sqrt(2.0) * sig * _GH_T[None, :]
        j_nodes = 10.0 * np.log10(10.0 ** (i_nodes / 10.0) + 10.0 ** (s.noise_dbm / 10.0))
        hi = float(j_nodes.max()) if j_nodes.size else s.noise_dbm
        self.j_grid = s.noise_dbm + np.arange(0.0, hi - s.noise_dbm + 2 * _J_STEP_DB, _J_STEP_DB)
        # sparse linear-interpolation weights folded into one (n_j, n_int) matrix
        pos = np.clip((j_nodes - self.j_grid[0]) / _J_STEP_DB, 0.0, self.j_grid.size - 1.000001)
        lo = np.floor(pos).astype(np.int64)
        frac = pos - lo
        w = _GH_W[None, :] / math.sqrt(math.pi)
        mat = np.zeros((self.j_grid.size, m_int.size))
        cols = np.broadcast_to(np.arange(m_int.size)[:, None], lo.shape)
        np.add.at(mat, (lo, cols), w * (1.0 - frac))
        np.add.at(mat, (lo + 1, cols), w * frac)
        self.mat = mat

    M_STEP_DB = 0.25  # grid of the wanted mean power when many values are asked at once

    def p_int(self, m_r):
        """p_int for wanted mean powers m_r (any shape) -> shape m_r.shape + (n_int,).

        When more values are asked than a 0.25 dB grid over their range holds (the FMU's
        load table), p_int is computed on that grid and interpolated linearly: it is a
        smooth function of m_r (Gaussian-smoothed with sigma >= 1 dB in practice).
        """
        m_r = np.asarray(m_r, float)
        lo, hi = (float(m_r.min()), float(m_r.max())) if m_r.size else (0.0, 0.0)
        n_grid = int(math.ceil((hi - lo) / self.M_STEP_DB)) + 2
        if m_r.size <= n_grid or self.setup.sigma_db < 1.0:
            return self._p_int(m_r)
        grid = lo + self.M_STEP_DB * np.arange(n_grid)
        table = self._p_int(grid)
        pos = np.clip((m_r - lo) / self.M_STEP_DB, 0.0, n_grid - 1.000001)
        i = np.floor(pos).astype(np.int64)
        w = (pos - i)[..., None]
        return (1.0 - w) * table[i] + w * table[i + 1]

    def _p_int(self, m_r, chunk=32):
        """p_int computed directly, `chunk` wanted powers at a time (bounded memory)."""
        flat = m_r.reshape(-1)
        out = np.empty((flat.size, self.mat.shape[1]))
        for i in range(0, flat.size, chunk):
            out[i:i + chunk] = self._p_int_rows(flat[i:i + chunk])
        return out.reshape(m_r.shape + (self.mat.shape[1],))

    def _p_int_rows(self, m_r):
        s = self.setup
        sig = max(s.sigma_db, 1e-9)
        q = ndtr((m_r - s.sensing_dbm) / sig)[..., None]
        # G(j) = E[PER(P - j); P >= P_sen] / P(P >= P_sen)
        g = s.curve.gauss_integral(m_r[..., None] - self.j_grid, sig, s.sensing_dbm - self.j_grid)
        g = np.where(q > 1e-300, g / np.maximum(q, 1e-300), 1.0)
        g = np.clip(g, 0.0, 1.0)
        p_pro = g[..., :1]                 # J = N0: no interference
        p_sinr = g @ self.mat              # E over the interferer's shadowing
        with np.errstate(invalid="ignore", divide="ignore"):
            p = (p_sinr - p_pro) / (1.0 - p_pro)
        return np.where(p_pro >= 1.0 - 1e-12, 0.0, np.clip(p, 0.0, 1.0))


def _combine(p):
    """1 - prod_i (1 - p_i) over the last axis ([Sep] (14), (26); [GM] (14))."""
    return -np.expm1(np.sum(np.log1p(-np.clip(p, 0.0, 1.0 - 1e-15)), axis=-1))


class Dsrc80211pLoad:
    """[Sep] 802.11p under load: receiver-busy and collision losses, CBR.

    density (veh/m), rate_hz (packets/s per vehicle), packet_bytes of the
    other vehicles' packets, data_rate_bps; header_bytes = 30 and the
    802.11p slot 13 us as in [Sep].
    """

    SLOT_S = 13e-6  # aSlotTime at 10 MHz (IEEE 802.11-2012)
    _CBR_FIT = (-0.2481, 0.913, 0.003844)  # [Sep] (35): CBR = a u^2 + b u + c of the unfitted CBR u

    @classmethod
    def max_cbr(cls) -> float:
        a, b, c = cls._CBR_FIT
        return c - b * b / (4.0 * a)

    @classmethod
    def density_for_cbr(cls, setup: RadioSetup, cbr: float, rate_hz: float, packet_bytes: float,
                        data_rate_bps: float, header_bytes: float = 30.0) -> float:
        """The density whose CBR ([Sep] (34)-(35)) is `cbr`: the rising root of the fit, then (34) inverted."""
        a, b, c = cls._CBR_FIT
        if not c < cbr <= cls.max_cbr():
            raise ValueError(f"parameter cbr_target must be in ({c}, {cls.max_cbr():.3f}] for 802.11p "
                             f"(the range of Sepulcre et al. eq. (35)), got {cbr!r}")
        u = (-b + math.sqrt(b * b - 4.0 * a * (c - cbr))) / (2.0 * a)
        t_tr = 40e-6 + (packet_bytes + header_bytes) * 8.0 / data_rate_bps
        return u / (rate_hz * t_tr * _psr_sum(setup, setup.sensing_dbm))

    def __init__(self, setup: RadioSetup, density: float, rate_hz: float, packet_bytes: float,
                 data_rate_bps: float, header_bytes: float = 30.0):
        if not density > 0:
            raise ValueError("density must be > 0 for a load model")
        self.setup, self.rate = setup, rate_hz
        self.t_tr = 40e-6 + (packet_bytes + header_bytes) * 8.0 / data_rate_bps  # [Sep] T_tr (page 1588)
        road = self.road = _Road(setup, density, setup.sensing_dbm)
        cbr_u = density * rate_hz * self.t_tr * road.psr.sum()                  # [Sep] (34)
        self.cbr = float(np.clip(-0.2481 * cbr_u**2 + 0.913 * cbr_u + 0.003844, 0.0, 0.999))  # [Sep] (35)
        self.r_norm = road.r_psr / road.r_psr.max()                             # [Sep] (20), normalised
        x = road.x_int
        self.p_det_rx = road.psr_at(np.abs(x), setup.sensing_dbm)
        self.sinr = _SinrError(setup, setup.rx_mean_dbm(np.abs(x)))

    def components(self, d, excess_db=0.0):
        """(delta_RXB', delta_COL') at distances d (shape (n,)) and excess losses (shape (m,)) -> (n,), (n, m)."""
        d = np.atleast_1d(np.asarray(d, float))
        excess = np.atleast_1d(np.asarray(excess_db, float))
        road, lam, x = self.road, self.rate, self.road.x_int
        if x.size == 0:
            return np.zeros(d.shape), np.zeros(d.shape + excess.shape)
        dtx = np.abs(x[None, :] + d[:, None])                     # interferer -> transmitter (tx at -d)
        p_det_tx = road.psr_at(dtx, self.setup.sensing_dbm)
        denom = 1.0 - self.cbr * np.interp(np.rint(dtx), np.arange(self.r_norm.size), self.r_norm, right=0.0)
        closer = np.abs(x)[None, :] < d[:, None]
        p_sim_ct = self.SLOT_S * lam * p_det_tx / denom           # [Sep] (22)
        p_rxb_ct = np.where(closer, p_sim_ct * self.p_det_rx, 0.0)  # [Sep] (21)
        p_rxb_ht = self.t_tr * lam * self.p_det_rx * (1.0 - p_det_tx) / denom  # [Sep] (16)
        rxb = _combine(p_rxb_ct + p_rxb_ht)                       # [Sep] (14)
        p_sim_ht = self.t_tr * lam * (1.0 - p_det_tx) / denom     # [Sep] (18)
        exposure = np.where(closer, 0.0, p_sim_ct) + p_sim_ht * (2.0 - self.p_det_rx)  # [Sep] (32), (28)
        m_r = self.setup.rx_mean_dbm(d)[:, None] - excess[None, :]
        p_int = self.sinr.p_int(m_r)                              # (n, m, n_int)
        col = _combine(p_int * exposure[:, None, :])              # [Sep] (26)
        return rxb, col

    def loss(self, d, excess_db=0.0):
        """Load loss L = 1 - (1 - delta_RXB')(1 - delta_COL'), shape (n, m)."""
        rxb, col = self.components(d, excess_db)
        return 1.0 - (1.0 - rxb[:, None]) * (1.0 - col)


class Cv2xMode4Load:
    """[GM] LTE-V2X mode 4 (sensing-based SPS) under load: half-duplex and collision losses, CBR.

    subchannels S per 100 ms... N = S * 1000 / lambda resources in the
    selection window ([GM] (28)), 20 % of them candidates (3GPP TS 36.213 14.1.1.6).
    """

    STEP3_DB = 0.1  # threshold increment of the Step-3 model ([GM], step_dB)

    @staticmethod
    def _excluded_of(s, n_res):
        """[GM] (29)/(33): N_e = S/2 + sum_{k=1}^{floor(S/2)} max(1 - k/(N - S/2), 0)."""
        half = s / 2.0
        k = np.arange(1, int(math.floor(half)) + 1)
        return half + np.maximum(1.0 - k / (n_res - half), 0.0).sum()

    @classmethod
    def density_for_cbr(cls, setup: RadioSetup, cbr: float, rate_hz: float, subchannels: int) -> float:
        """The density whose CBR = N_e / N ([GM] (29), (34)) is `cbr` (bisection; N_e grows with density)."""
        n_res = subchannels * 1000.0 / rate_hz
        psr = _psr_sum(setup, setup.sensing_dbm)
        lo, hi = 0.0, 2.0 * n_res / psr  # S/2 = N at hi
        if not 0.0 < cbr < cls._excluded_of(hi * psr * (1 - 1e-9), n_res) / n_res:
            raise ValueError(f"parameter cbr_target {cbr!r} is outside the C-V2X load model's range")
        for _ in range(60):
            mid = 0.5 * (lo + hi)
            lo, hi = (mid, hi) if cls._excluded_of(mid * psr, n_res) / n_res < cbr else (lo, mid)
        return 0.5 * (lo + hi)

    def __init__(self, setup: RadioSetup, density: float, rate_hz: float, subchannels: int):
        if not density > 0:
            raise ValueError("density must be > 0 for a load model")
        self.setup, self.rate, self.beta = setup, rate_hz, density
        n_res = self.n_res = subchannels * 1000.0 / rate_hz      # [GM] (28)
        self.n_cand = 0.2 * n_res
        road = self.road = _Road(setup, density, setup.sensing_dbm)
        s_psr = density * road.psr.sum()                         # [GM] (29.1)
        ne = self._excluded(s_psr)                               # [GM] (29)
        self.cbr = float(ne / n_res)                             # [GM] (34)
        self.alpha = float(np.clip(2.0 * self.cbr - 0.4, 0.0, 1.0))  # [GM] (22)
        self.cc2 = self._common_candidates(ne, s_psr)
        # Step 3: raise the threshold until 20 % of the resources are available ([GM] (32), (33))
        psen3 = setup.sensing_dbm
        while True:
            ne3 = self._excluded(2.0 * density * road.psr_at(np.abs(np.arange(-_ROAD_HALF_M, _ROAD_HALF_M + 1.0)),
                                                             psen3).sum())
            if n_res - ne3 >= self.n_cand:
                break
            psen3 += self.STEP3_DB
        self.psen3, self.cc3 = psen3, self._common_candidates(ne3, s_psr)
        self.hd = rate_hz / 1000.0                               # [GM] (7)
        self.sinr = _SinrError(setup, setup.rx_mean_dbm(np.abs(road.x_int)))

    def _excluded(self, s):
        return self._excluded_of(s, self.n_res)

    def _common_candidates(self, ne, s_psr):
        """[GM] (26), (27), (30): candidate resources shared by two vehicles, by their distance (1 m lags)."""
        r = self.road.r_psr
        n = self.n_res
        ce = (r / r[0]) * (self.beta * ne * r[0] / s_psr - ne * ne / n) + ne * ne / n
        ca = n - 2.0 * ne + ce
        return ca * (self.n_cand / (n - ne)) ** 2

    def _p_sim(self, cc, dtx, psen):
        """[GM] (23)/(31) with (24): probability that interferer and transmitter pick the same resource."""
        p_s = 1.0 - (1.0 - 1.0 / self.rate) * self.road.psr_at(dtx, psen)
        i = np.minimum(np.rint(dtx).astype(np.int64), cc.size - 1)
        return p_s * cc[i] / self.n_cand**2

    def components(self, d, excess_db=0.0):
        """(delta_HD, delta_COL') at distances d (n,) and excess losses (m,) -> scalar, (n, m)."""
        d = np.atleast_1d(np.asarray(d, float))
        excess = np.atleast_1d(np.asarray(excess_db, float))
        x = self.road.x_int
        if x.size == 0:
            return self.hd, np.zeros(d.shape + excess.shape)
        dtx = np.abs(x[None, :] + d[:, None])
        m_r = self.setup.rx_mean_dbm(d)[:, None] - excess[None, :]
        p_int = self.sinr.p_int(m_r)                                           # (n, m, n_int)
        col2 = _combine(p_int * self._p_sim(self.cc2, dtx, self.setup.sensing_dbm)[:, None, :])  # [GM] (14), (15)
        col3 = _combine(p_int * self._p_sim(self.cc3, dtx, self.psen3)[:, None, :]) if self.alpha < 1 else 0.0
        return self.hd, self.alpha * col2 + (1.0 - self.alpha) * col3          # [GM] (21)

    def loss(self, d, excess_db=0.0):
        """Load loss L = 1 - (1 - delta_HD)(1 - delta_COL'), shape (n, m)."""
        hd, col = self.components(d, excess_db)
        return 1.0 - (1.0 - hd) * (1.0 - col)
