"""Noise, airtime, fading and packet-error curves (802.11p and LTE-V2X sidelink).

Every packet-error curve is a `PwlCurve`: error probability as a piecewise-
linear function of SNR/SINR in dB, constant beyond its ends. That one shape
serves both the per-packet draw (interpolate at the current SNR) and the
expected PDR (its expectation over Gaussian shadowing has a closed form,
`PwlCurve.gauss_integral`).

Sources
  [kTB]  Thermal noise N = k T0 B, T0 = 290 K (-174 dBm/Hz), plus the noise figure.
  [OFDM] IEEE Std 802.11-2016, 17.4.3 (TXTIME of an OFDM PPDU) and Table 17-4
         (half-clocked 10 MHz: 8 us symbols, 32 us preamble, 8 us SIGNAL,
         16 service bits + 6 tail bits, N_DBPS = rate x 8 us).
  [NIST] G. Pei, T. Henderson, "Validation of OFDM error rate model in ns-3",
         Boeing, 2010 (the "NIST" model; Veins NistErrorRate): uncoded BER of
         BPSK/QPSK/16-QAM/64-QAM over AWGN, Viterbi union bound with the
         distance spectra of the 802.11 K=7 convolutional code (rates 1/2,
         2/3, 3/4, Frenger et al.), chunk success (1 - Pe)^nbits.
  [Gou]  O. Goubet et al., "Low-Complexity Scalable Iterative Algorithms for
         IEEE 802.11p Receivers", IEEE TVT 64(9), 2015, Fig. 14 (L = 1): FER
         versus Eb/N0 of a 6 Mb/s 802.11p frame over a vehicular channel, as
         tabulated in the Sepulcre et al. (IEEE TVT 2021) model code.
  [R1]   3GPP R1-160284 "DMRS enhancement of V2V" (Huawei), BLER versus SINR of
         a 190-byte LTE-V2X sidelink transport block at 280 km/h relative
         speed: QPSK r~0.7 over 10 RBs (4 subchannels) and QPSK r=0.5 over 12
         RBs (2 subchannels), as tabulated in the Gonzalez-Martin et al.
         (IEEE TVT 2019) model code.
  [Nak]  M. Nakagami, "The m-distribution", 1960: received power
         ~ Gamma(m, mean/m). Veins NakagamiFading: m = 1.5 below 80 m, 0.75 beyond.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property

import numpy as np
from scipy.special import erfc, gammainc, gammaincinv, ndtr

__all__ = [
    "BOLTZMANN", "thermal_noise_dbm", "ofdm_80211p_airtime_s", "RATES_80211P_10MHZ", "nist_per",
    "PwlCurve", "goubet_fer_curve", "cv2x_bler_curve", "nist_per_curve", "nakagami_m",
    "nakagami_outage", "nakagami_gain_db", "nakagami_log_gain_pdf",
]

BOLTZMANN = 1.380649e-23  # J/K


def thermal_noise_dbm(bandwidth_hz, noise_figure_db=0.0, temperature_k=290.0):
    """[kTB] noise power in dBm over `bandwidth_hz`, plus the receiver noise figure."""
    return 10.0 * np.log10(BOLTZMANN * temperature_k * np.asarray(bandwidth_hz, float) * 1e3) + noise_figure_db


# 802.11p rates at 10 MHz (half-clocked 802.11a) -> (modulation, code rate numerator index for [NIST]).
# Table 17-4 of [OFDM]: 3 BPSK 1/2, 4.5 BPSK 3/4, 6 QPSK 1/2, 9 QPSK 3/4, 12 16-QAM 1/2,
# 18 16-QAM 3/4, 24 64-QAM 2/3, 27 64-QAM 3/4 Mb/s.
RATES_80211P_10MHZ = {
    3e6: ("bpsk", 1), 4.5e6: ("bpsk", 3), 6e6: ("qpsk", 1), 9e6: ("qpsk", 3),
    12e6: ("qam16", 1), 18e6: ("qam16", 3), 24e6: ("qam64", 2), 27e6: ("qam64", 3),
}


def ofdm_80211p_airtime_s(psdu_bytes, rate_bps, bandwidth_hz=10e6):
    """[OFDM] TXTIME = preamble + SIGNAL + N_SYM x T_SYM, N_SYM = ceil((16 + 8 L + 6) / N_DBPS).

    At 10 MHz: preamble 32 us, SIGNAL 8 us, symbol 8 us (all halve at 20 MHz).
    """
    scale = 10e6 / bandwidth_hz  # 1 at 10 MHz, 0.5 at 20 MHz
    t_sym = 8e-6 * scale
    n_dbps = rate_bps * t_sym
    n_sym = np.ceil((16 + 8 * np.asarray(psdu_bytes, float) + 6) / n_dbps - 1e-9)
    return (32e-6 + 8e-6) * scale + n_sym * t_sym


# [NIST] distance spectra (c_d, starting at d_free) of the 802.11 K = 7 convolutional code.
_SPECTRA = {
    1: (10, 2, 0.5, (36, 211, 1404, 11633, 77433, 502690, 3322763, 21292910, 134365911)),
    2: (6, 1, 1 / 4, (3, 70, 285, 1276, 6160, 27128, 117019, 498860, 2103891, 8784123)),
    3: (5, 1, 1 / 6, (42, 201, 1492, 10469, 62935, 379644, 2253373, 13073811, 75152755, 428005675)),
}


def _uncoded_ber(snr_lin, modulation):
    """[NIST] uncoded BER over AWGN (SNR per symbol, linear)."""
    if modulation == "bpsk":
        return 0.5 * erfc(np.sqrt(snr_lin))
    if modulation == "qpsk":
        return 0.5 * erfc(np.sqrt(snr_lin / 2.0))
    if modulation == "qam16":
        return 0.75 * 0.5 * erfc(np.sqrt(snr_lin / 10.0))
    if modulation == "qam64":
        return 7.0 / 12.0 * 0.5 * erfc(np.sqrt(snr_lin / 42.0))
    raise ValueError(modulation)


def nist_per(snr_db, nbits, rate_bps):
    """[NIST] packet error rate of `nbits` bits at an 802.11p (10 MHz) rate over AWGN.

    Pe = (1/(2 b)) sum_d c_d D^d with D = sqrt(4 p (1 - p)) (Bhattacharyya bound of
    the Viterbi decoder, b = 1 for rate 1/2 -> factor 1/2); PER = 1 - (1 - min(Pe, 1))^nbits.
    """
    try:
        modulation, b = RATES_80211P_10MHZ[float(rate_bps)]
    except KeyError:
        raise ValueError(f"data_rate_bps must be an 802.11p 10 MHz rate {sorted(RATES_80211P_10MHZ)}, "
                         f"got {rate_bps!r}") from None
    p = _uncoded_ber(10.0 ** (np.asarray(snr_db, float) / 10.0), modulation)
    d_free, step, factor, coeffs = _SPECTRA[b]
    dd = np.sqrt(4.0 * p * (1.0 - p))
    pe = factor * sum(c * dd ** (d_free + step * i) for i, c in enumerate(coeffs))
    pe = np.minimum(pe, 1.0)
    with np.errstate(divide="ignore"):
        return -np.expm1(nbits * np.log1p(-pe))  # 1 - (1 - pe)^nbits without cancellation


@dataclass(frozen=True)
class PwlCurve:
    """Error probability versus SNR (dB): linear interpolation of (x, y), constant outside."""

    x: np.ndarray
    y: np.ndarray
    name: str = ""

    def __post_init__(self):
        x, y = np.asarray(self.x, float), np.asarray(self.y, float)
        if x.ndim != 1 or x.shape != y.shape or x.size < 2 or np.any(np.diff(x) <= 0):
            raise ValueError("PwlCurve needs strictly increasing x and y of the same length")
        object.__setattr__(self, "x", x)
        object.__setattr__(self, "y", y)

    def __call__(self, snr_db):
        return np.interp(snr_db, self.x, self.y)

    def shifted(self, db: float, name: str | None = None) -> "PwlCurve":
        """The same curve as a function of (snr + db): e.g. Eb/N0 = SNR + 10 log10(B / R)."""
        return PwlCurve(self.x - db, self.y, name or self.name)

    @cached_property
    def _segments(self):
        """Segments (-inf, x0], [x_k, x_k+1], [x_n, inf) as (a, b, c0, c1) with curve = c0 + c1 s on each."""
        x, y = self.x, self.y
        a = np.concatenate(([-np.inf], x))
        b = np.concatenate((x, [np.inf]))
        c1 = np.concatenate(([0.0], np.diff(y) / np.diff(x), [0.0]))
        c0 = np.concatenate(([y[0]], y[:-1] - c1[1:-1] * x[:-1], [y[-1]]))
        return a, b, c0, c1

    def gauss_integral(self, mu, sigma, lo):
        """Integral over s in [lo, inf) of N(s; mu, sigma) * curve(s) ds (closed form, broadcasts).

        The curve is linear on each segment [a, b]: f(s) = c0 + c1 s, and
        int_a^b phi((s - mu)/sigma)/sigma (c0 + c1 s) ds
           = (c0 + c1 mu)(Phi(B) - Phi(A)) - c1 sigma (phi(B) - phi(A)),  A = (a - mu)/sigma, B = (b - mu)/sigma.
        """
        mu, lo = np.asarray(mu, float), np.asarray(lo, float)
        sigma = np.maximum(np.asarray(sigma, float), 1e-9)
        _, _, c0, c1 = self._segments
        shape = np.broadcast_shapes(mu.shape, sigma.shape, lo.shape)
        mu_, sg_, lo_ = (np.broadcast_to(v, shape)[..., None] for v in (mu, sigma, lo))
        # segment ends clipped to [lo, inf): lo, max(x_0, lo), ..., max(x_n, lo), inf
        z = (np.maximum(self.x, lo_) - mu_) / sg_
        z = np.concatenate(((lo_ - mu_) / sg_, z), axis=-1)
        # Phi(B) - Phi(A) as Q(A) - Q(B) (Q = upper tail): exact in relative terms far above the
        # mean, where the wanted signal sits below the threshold and results are divided by a tiny
        # P(P >= P_sen); far below the mean the absolute error stays at 1e-16.
        sf = np.concatenate((ndtr(-z), np.zeros(shape + (1,))), axis=-1)
        pdf = np.concatenate((np.exp(-0.5 * z * z), np.zeros(shape + (1,))), axis=-1)
        inv_sqrt2pi = 1.0 / math.sqrt(2.0 * math.pi)
        terms = -(c0 + c1 * mu_) * np.diff(sf, axis=-1) - c1 * sg_ * inv_sqrt2pi * np.diff(pdf, axis=-1)
        return terms.sum(axis=-1)


# [Gou] FER of a 6 Mb/s 802.11p frame versus Eb/N0 (dB), as used by Sepulcre et al. 2021.
_GOUBET_EBN0 = (0.0, 5.0, 10.0, 15.0, 20.0, 25.0, 30.0, 35.0)
_GOUBET_FER = (1.0, 1.0, 0.4, 1.5e-2, 4e-3, 3e-3, 2e-3, 1e-3)


def goubet_fer_curve(rate_bps=6e6, bandwidth_hz=10e6) -> PwlCurve:
    """[Gou] FER versus SNR: Eb/N0 = SNR + 10 log10(B / R_d) (Sepulcre et al. 2021, eq. before (24))."""
    return PwlCurve(np.array(_GOUBET_EBN0), np.array(_GOUBET_FER), "goubet").shifted(
        10.0 * math.log10(bandwidth_hz / rate_bps), f"goubet@{rate_bps / 1e6:g}Mb/s")


# [R1] BLER versus SINR (dB) of a 190-byte LTE-V2X transport block; the 1e-3 -> 1e-4 step at
# 20 dB is in the published table.
_CV2X_BLER = {
    4: ((0.0, 2.0, 4.0, 6.0, 8.0, 10.0, 12.0, 14.0, 16.0, 18.0, 20.0, 20.0 + 1e-6),
        (1.0, 0.9, 0.7, 0.4, 0.13, 0.045, 0.017, 0.007, 1e-3, 1e-3, 1e-3, 1e-4)),
    2: ((-2.0, 0.0, 2.0, 4.0, 6.0, 8.0, 10.0, 12.0, 14.0, 16.0, 18.0, 20.0, 20.0 + 1e-6),
        (1.0, 0.9, 0.7, 0.3, 0.09, 0.02, 0.002, 1e-3, 1e-3, 1e-3, 1e-3, 1e-3, 1e-4)),
}
# Resource blocks of the 190-byte DATA field per configuration [R1] / Gonzalez-Martin et al. 2019.
CV2X_DATA_RBS = {4: 10, 2: 12}


def cv2x_bler_curve(subchannels: int) -> PwlCurve:
    """[R1] BLER vs SINR for 4 subchannels (QPSK r~0.7, 10 RBs) or 2 subchannels (QPSK r=0.5, 12 RBs)."""
    try:
        x, y = _CV2X_BLER[int(subchannels)]
    except KeyError:
        raise ValueError(f"cv2x_subchannels must be 2 or 4 (published BLER curves), got {subchannels!r}") from None
    return PwlCurve(np.array(x), np.array(y), f"cv2x-bler-S{subchannels}")


def nist_per_curve(nbits: int, rate_bps: float, lo_db=-10.0, hi_db=40.0, step_db=0.05) -> PwlCurve:
    """[NIST] PER tabulated on a 0.05 dB grid, kept only where it moves (1e-7 < PER < 1 - 1e-7).

    The curve falls from 1 to 1e-7 within a few dB; outside that band it is
    constant, which is what PwlCurve does beyond its ends. Linear
    interpolation error of the tabulation is below 0.0015 absolute (8 rates,
    30 to 4000 bytes).
    """
    x = np.arange(lo_db, hi_db + step_db / 2, step_db)
    y = nist_per(x, nbits, rate_bps)
    moving = np.flatnonzero((y > 1e-7) & (y < 1.0 - 1e-7))
    if moving.size == 0:
        raise ValueError(f"NIST PER of {nbits} bits is flat over [{lo_db}, {hi_db}] dB")
    keep = slice(max(moving[0] - 1, 0), min(moving[-1] + 2, x.size))
    return PwlCurve(x[keep], y[keep], f"nist@{rate_bps / 1e6:g}Mb/s,{nbits}b")


def nakagami_m(distance_m, m_near=1.5, m_far=0.75, switch_m=80.0):
    """[Nak] Veins NakagamiFading distance-dependent shape: 1.5 below 80 m, 0.75 beyond."""
    return np.where(np.asarray(distance_m, float) < switch_m, m_near, m_far)


def nakagami_outage(m, margin_db):
    """[Nak] P(power gain < 10^(-margin/10)) for unit-mean Gamma(m, 1/m) power: P(m, m g_th)."""
    g_th = 10.0 ** (-np.asarray(margin_db, float) / 10.0)
    return gammainc(m, m * g_th)


def nakagami_gain_db(m, u):
    """[Nak] power gain (dB) of a unit-mean Nakagami-m channel at quantile u (inverse CDF)."""
    u = np.clip(np.asarray(u, float), 1e-300, 1.0 - 1e-16)
    return 10.0 * np.log10(np.maximum(gammaincinv(m, u) / m, 1e-30))


def nakagami_log_gain_pdf(m, step_db=0.1, lo_db=-60.0, hi_db=15.0):
    """Grid (dB) and probability masses of the Nakagami-m power gain in dB (unit mean).

    Exact masses from the Gamma CDF between grid midpoints, so that the sum is 1
    up to the far tails (folded into the end cells).
    """
    y = np.arange(lo_db, hi_db + step_db / 2, step_db)
    edges = np.concatenate(([-np.inf], y[:-1] + step_db / 2, [np.inf]))
    g = 10.0 ** (edges / 10.0)
    cdf = np.where(np.isfinite(edges), gammainc(m, m * np.where(np.isfinite(g), g, 0.0)), 1.0)
    cdf[0] = 0.0
    return y, np.diff(cdf)
