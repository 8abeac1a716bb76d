"""Large-scale propagation at 5.9 GHz: path loss, LOS probability, building loss, shadowing.

All functions take numpy arrays (or scalars) and broadcast, so that one call
can evaluate many receivers. Distances are in metres, frequencies in GHz,
losses in dB.

Sources
  [W+]   WINNER+ D5.3 "WINNER+ final channel models" (2010), scenario B1
         (urban micro-cell, LOS), as adopted for V2V by 3GPP TR 36.885
         V14.0.0 Table A.1.4-1 and used by the analytical models of
         Sepulcre et al. (IEEE TVT 2021) and Gonzalez-Martin et al.
         (IEEE TVT 2019).
  [W2]   WINNER II D1.1.2 (2007) Table 4-4: free-space loss
         PL = 20 log10(d) + 46.4 + 20 log10(fc/5), fc in GHz.
  [37885] 3GPP TR 37.885 V15.3.0, Table 6.2.1-1 (V2V path loss, urban and
         highway) and Table 6.2.1-2 (V2V LOS probability).
  [Som]  C. Sommer et al., "A Computationally Inexpensive Empirical Model of
         IEEE 802.11p Radio Shadowing in Urban Environments", WONS 2011;
         Veins SimpleObstacleShadowing defaults (9 dB per wall, 0.4 dB/m).
  [Gud]  M. Gudmundson, "Correlation model for shadow fading in mobile radio
         systems", Electronics Letters 27(23), 1991: exponential spatial
         autocorrelation exp(-|dx|/d_corr). TR 37.885 Table 6.2.3-1 gives
         d_corr = 10 m for V2V urban (25 m highway).
"""
from __future__ import annotations

import numpy as np

__all__ = [
    "SPEED_OF_LIGHT", "PATHLOSS_MODELS", "free_space_db", "winner_free_space_db", "winner_b1_breakpoint_m",
    "winner_b1_los_db", "tr37885_urban_db", "los_probability_tr37885", "obstacle_loss_db",
    "default_shadowing_sigma_db", "ShadowingField",
]

SPEED_OF_LIGHT = 299_792_458.0  # m/s
PATHLOSS_MODELS = ("winner_b1", "tr37885_urban", "free_space")


def free_space_db(d, freq_ghz):
    """Friis free-space loss 20 log10(4 pi d f / c)."""
    d = np.asarray(d, dtype=float)
    return 20.0 * np.log10(4.0 * np.pi * d * freq_ghz * 1e9 / SPEED_OF_LIGHT)


def winner_free_space_db(d, freq_ghz):
    """[W2] WINNER free-space loss 20 log10(d) + 46.4 + 20 log10(fc/5) (the B1 model's floor)."""
    d = np.asarray(d, dtype=float)
    return 20.0 * np.log10(d) + 46.4 + 20.0 * np.log10(freq_ghz / 5.0)


def winner_b1_breakpoint_m(freq_ghz, h_tx, h_rx, h_env):
    """[W+] B1 breakpoint d'_BP = 4 h'_tx h'_rx f_c / c with effective heights h' = h - h_env."""
    return 4.0 * (np.asarray(h_tx) - h_env) * (np.asarray(h_rx) - h_env) * freq_ghz * 1e9 / SPEED_OF_LIGHT


def winner_b1_los_db(d, freq_ghz, h_tx=1.5, h_rx=1.5, h_env=0.5):
    """[W+] WINNER+ B1 LOS path loss, never below the WINNER free-space loss [W2].

    d < d'_BP : PL = 22.7 log10(d) + 27.0 + 20 log10(fc)
    d >= d'_BP: PL = 40 log10(d) + 7.56 - 17.3 log10(h'_tx) - 17.3 log10(h'_rx) + 2.7 log10(fc)
    The max with free space is what TR 36.885 prescribes for B1 (and what
    the Sepulcre / Gonzalez-Martin model code does). Effective heights are
    clamped to >= 0.1 m so that an antenna at or below the environment height
    still gives a finite loss.
    """
    d = np.asarray(d, dtype=float)
    htx = np.maximum(np.asarray(h_tx, dtype=float) - h_env, 0.1)
    hrx = np.maximum(np.asarray(h_rx, dtype=float) - h_env, 0.1)
    d_bp = 4.0 * htx * hrx * freq_ghz * 1e9 / SPEED_OF_LIGHT
    near = 22.7 * np.log10(d) + 27.0 + 20.0 * np.log10(freq_ghz)
    far = 40.0 * np.log10(d) + 7.56 - 17.3 * np.log10(htx) - 17.3 * np.log10(hrx) + 2.7 * np.log10(freq_ghz)
    return np.maximum(np.where(d < d_bp, near, far), winner_free_space_db(d, freq_ghz))


def tr37885_urban_db(d, freq_ghz, los=True):
    """[37885] Table 6.2.1-1, V2V urban: LOS 38.77 + 16.7 log10(d) + 18.2 log10(fc) (sigma 3 dB);
    NLOS (building blockage, UMi street canyon) 36.85 + 30 log10(d) + 18.9 log10(fc) (sigma 4 dB)."""
    d = np.asarray(d, dtype=float)
    los_pl = 38.77 + 16.7 * np.log10(d) + 18.2 * np.log10(freq_ghz)
    nlos_pl = 36.85 + 30.0 * np.log10(d) + 18.9 * np.log10(freq_ghz)
    return np.where(np.asarray(los, dtype=bool), los_pl, nlos_pl)


def los_probability_tr37885(d, scenario="urban"):
    """[37885] Table 6.2.1-2, V2V LOS probability (LOS vs NLOSv, vehicle blockage).

    urban:   min(1, 1.05 exp(-0.0114 d))
    highway: d <= 475 m: min(1, 2.1013e-6 d^2 - 0.002 d + 1.0193); beyond: max(0, 0.54 - 0.001 (d - 475))
    Offered for worlds without geometry; the FMU takes LOS/NLOS from the walls input.
    """
    d = np.asarray(d, dtype=float)
    if scenario == "urban":
        return np.minimum(1.0, 1.05 * np.exp(-0.0114 * d))
    if scenario == "highway":
        near = np.minimum(1.0, 2.1013e-6 * d**2 - 0.002 * d + 1.0193)
        far = np.maximum(0.0, 0.54 - 0.001 * (d - 475.0))
        return np.where(d <= 475.0, near, far)
    raise ValueError(f"scenario must be 'urban' or 'highway', got {scenario!r}")


def obstacle_loss_db(walls, inside_m, per_wall_db=9.0, per_m_db=0.4):
    """[Som] Building shadowing: beta per wall crossed + gamma per metre inside (Veins: 9 dB, 0.4 dB/m)."""
    return per_wall_db * np.asarray(walls, dtype=float) + per_m_db * np.asarray(inside_m, dtype=float)


def default_shadowing_sigma_db(model: str, nlos=False):
    """Shadowing std of each path-loss model: B1 LOS 3 dB [W+ as used by TR 36.885 and Sepulcre];
    TR 37.885 urban 3 dB LOS / 4 dB NLOS [37885]; free space none."""
    nlos = np.asarray(nlos, dtype=bool)
    if model == "winner_b1":
        return np.where(nlos, 3.0, 3.0)
    if model == "tr37885_urban":
        return np.where(nlos, 4.0, 3.0)
    if model == "free_space":
        return np.where(nlos, 0.0, 0.0)
    raise ValueError(f"pathloss_model must be one of {PATHLOSS_MODELS}, got {model!r}")


class ShadowingField:
    """Spatially correlated, unit-variance shadowing field over (tx position, rx position).

    The field is a deterministic function of the six coordinates and the seed,
    so the shadowing of a link depends only on where its ends are: it is the
    same whatever the communication step, the order of evaluation or the
    number of other links, and two receivers at the same place see the same
    shadowing from the same transmitter (as they physically would).

    Construction (spectral "sum of sinusoids" method, e.g. Shinozuka &
    Deodatis, Appl. Mech. Rev. 44(4), 1991): F(p) = sqrt(2/K) sum_k cos(w_k . p + phi_k)
    with phases uniform in [0, 2 pi) and wave vectors w_k drawn from the
    spectral density of the target covariance. The Gudmundson [Gud]
    exponential covariance exp(-|h|/d_corr) in R^n has as spectral density a
    multivariate Cauchy law of scale 1/d_corr, i.e. w = z / (d_corr |g|) with
    z ~ N(0, I_n), g ~ N(0, 1). Over the ensemble of seeds the covariance is
    exactly exp(-|h|/d_corr), where |h| is the joint displacement
    sqrt(|dtx|^2 + |drx|^2): moving either end by d_corr decorrelates by 1/e.
    With K = 128 terms the marginal is Gaussian to within the CLT error of a
    128-term sum and bounded by +-16 sigma. What it is not: reciprocal
    (F(a, b) != F(b, a)); this FMU models a directed link.
    """

    N_TERMS = 128

    def __init__(self, seed: int, decorrelation_m: float, n_terms: int = N_TERMS):
        if not decorrelation_m > 0:
            raise ValueError(f"decorrelation_m must be > 0, got {decorrelation_m!r}")
        rng = np.random.default_rng([int(seed) & 0xFFFFFFFF, 0x5348_4144])  # "SHAD": own stream of the seed
        z = rng.standard_normal((n_terms, 6))
        g = np.abs(rng.standard_normal((n_terms, 1)))
        self.wave = z / (decorrelation_m * np.maximum(g, 1e-12))  # rad/m, shape (K, 6)
        self.phase = rng.uniform(0.0, 2.0 * np.pi, n_terms)
        self.amp = np.sqrt(2.0 / n_terms)

    def __call__(self, tx, rx):
        """Unit-variance field at tx, rx (arrays (..., 3)); returns shape (...)."""
        p = np.concatenate(np.broadcast_arrays(np.asarray(tx, float), np.asarray(rx, float)), axis=-1)
        # w . p accumulated coordinate by coordinate (element-wise, fixed order) rather than by a
        # matrix product, whose BLAS kernel and rounding depend on the batch shape: a link's
        # shadowing must be bit-identical whether it is evaluated alone or among 10 000.
        phase = self.phase + p[..., 0:1] * self.wave[:, 0]
        for i in range(1, 6):
            phase = phase + p[..., i:i + 1] * self.wave[:, i]
        return self.amp * np.cos(phase).sum(axis=-1)
