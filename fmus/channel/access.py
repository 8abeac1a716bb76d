"""Per-packet randomness and channel-access latency (802.11p EDCA, LTE-V2X sensing-based SPS).

Randomness
  Every per-packet draw is a counter-based hash of (seed, stream, keys...):
  SplitMix64 finalisers (G. Steele, D. Lea, C. Flood, "Fast splittable
  pseudorandom number generators", OOPSLA 2014) chained over the keys. A
  draw therefore depends only on its keys -- never on the step size, the
  order of evaluation or how many other links are evaluated -- and a whole
  array of receivers is hashed in one vectorised call.

Latency
  802.11p [EDCA]: AIFS = SIFS + AIFSN x slot (10 MHz: SIFS 32 us, slot
  13 us; IEEE 1609.4 CCH AC_VO: AIFSN 2, CWmin 3). A frame that finds the
  medium idle is sent after AIFS; one that finds it busy (probability CBR)
  waits for the frame on air (residual uniform over its airtime), AIFS, and a
  backoff of U{0..CWmin} slots, each idle slot stretched by 1/(1 - CBR)
  because the counter freezes while the medium is busy (a mean-value
  approximation in the spirit of Bianchi, IEEE JSAC 18(3), 2000).
  IEEE Std 802.11-2016 10.22.2 (EDCA), 17.4.4 (OFDM timing); IEEE 1609.4-2016 Table 5.

  LTE-V2X mode 4 [SPS]: the transmitter reserves one subframe offset,
  uniform over the selection window [n + T1, n + T2] (T1 <= 4, 20 <= T2 <=
  100 ms), for C consecutive packets, C uniform in {5..15} scaled by 100 ms /
  RRI for shorter RRIs; at expiry it keeps the reservation with probability
  P_keep. A packet's access delay is its reservation's offset (periodic
  traffic at the RRI keeps the offset constant). Mean over the window 4..100 ms:
  52 ms. T2 is capped at the RRI (e.g. 50 ms at 20 Hz). 3GPP TS 36.213 V14 14.1.1.6, TS 36.321 V14 5.14.1.1.
"""
from __future__ import annotations

import math

import numpy as np

__all__ = ["hash_uniform", "hash_uniform_scalar", "Stream", "dsrc_access_delay_s", "SpsSchedule", "AIFS_SIFS_S",
           "SLOT_S"]

SLOT_S = 13e-6       # aSlotTime, 10 MHz OFDM PHY (IEEE 802.11-2016 Table 17-21)
AIFS_SIFS_S = 32e-6  # aSIFSTime, 10 MHz


class Stream:
    """Stream numbers: one independent draw per purpose."""

    DECODE = 1
    FADING = 2
    BUSY = 3
    RESIDUAL = 4
    BACKOFF = 5
    SPS_COUNTER = 6
    SPS_OFFSET = 7
    SPS_KEEP = 8


_GOLDEN = np.uint64(0x9E3779B97F4A7C15)
_M1 = np.uint64(0xBF58476D1CE4E5B9)
_M2 = np.uint64(0x94D049BB133111EB)


def _mix(z):
    """SplitMix64 finaliser (bijective avalanche on 64 bits)."""
    z = (z ^ (z >> np.uint64(30))) * _M1
    z = (z ^ (z >> np.uint64(27))) * _M2
    return z ^ (z >> np.uint64(31))


def _u64(v):
    return np.atleast_1d(np.asarray(v, dtype=np.int64)).astype(np.uint64)


_MASK = (1 << 64) - 1
_GOLDEN_INT, _M1_INT, _M2_INT = int(_GOLDEN), int(_M1), int(_M2)


def _mix_int(z: int) -> int:
    """`_mix` on a Python int (the scalar path: ~30x faster than numpy on 0-d arrays)."""
    z = ((z ^ (z >> 30)) * _M1_INT) & _MASK
    z = ((z ^ (z >> 27)) * _M2_INT) & _MASK
    return z ^ (z >> 31)


def hash_uniform_scalar(seed: int, stream: int, *keys: int) -> float:
    """`hash_uniform` for Python integers; bit-identical to the vectorised version."""
    h = _mix_int((int(seed) + _GOLDEN_INT) & _MASK)
    h = _mix_int(h ^ ((int(stream) * _GOLDEN_INT) & _MASK))
    for key in keys:
        h = _mix_int(((h + _GOLDEN_INT) & _MASK) ^ (int(key) & _MASK))
    return (h >> 11) * (1.0 / 9007199254740992.0)


def hash_uniform(seed, stream, *keys):
    """Uniform [0, 1) draws keyed by (seed, stream, keys...); keys broadcast (integers)."""
    with np.errstate(over="ignore"):
        h = _mix(_u64(seed) + _GOLDEN)
        h = _mix(h ^ (_u64(stream) * _GOLDEN))
        for key in keys:
            h = _mix((h + _GOLDEN) ^ _u64(key))
    return (h >> np.uint64(11)).astype(np.float64) * (1.0 / 9007199254740992.0)


def dsrc_access_delay_s(u_busy, u_residual, u_backoff, cbr, busy_frame_s, aifsn=2, cw_min=3):
    """[EDCA] AIFS (+ residual busy time + frozen backoff when the medium is busy), seconds."""
    aifs = AIFS_SIFS_S + aifsn * SLOT_S
    busy = np.asarray(u_busy) < cbr
    slots = np.floor(np.asarray(u_backoff) * (cw_min + 1))
    wait = np.asarray(u_residual) * busy_frame_s + slots * SLOT_S / max(1.0 - cbr, 1e-3)
    return aifs + np.where(busy, wait, 0.0)


class SpsSchedule:
    """[SPS] Reservation epochs of one seed; per-transmitter epoch tables grow on demand."""

    def __init__(self, seed: int, t1_ms: float = 4.0, t2_ms: float = 100.0, rri_ms: float = 100.0,
                 keep_prob: float = 0.0):
        self.seed, self.keep = int(seed), float(keep_prob)
        # the window cannot reach past the next reservation: T2 <= RRI (TS 36.213 14.1.1.6)
        self.t1, self.t2 = int(round(t1_ms)), int(min(round(t2_ms), math.floor(rri_ms)))
        scale = max(1, int(round(100.0 / rri_ms))) if rri_ms < 100.0 else 1
        self.c_min, self.c_max = 5 * scale, 15 * scale
        self._tables: dict[int, tuple[np.ndarray, np.ndarray]] = {}  # tx_id -> (epoch starts, offsets ms)

    def _table(self, tx_id: int, upto_seq: int):
        starts, offsets = self._tables.get(tx_id, (np.zeros(0, np.int64), np.zeros(0)))
        covered = starts[-1] if starts.size else -1
        if starts.size and covered > upto_seq:
            return starts, offsets
        n = max(2 * starts.size, int(upto_seq // self.c_min) + 2, 64)
        k = np.arange(n)
        counter = self.c_min + np.floor(hash_uniform(self.seed, Stream.SPS_COUNTER, tx_id, k)
                                        * (self.c_max - self.c_min + 1)).astype(np.int64)
        starts = np.concatenate(([0], np.cumsum(counter)[:-1]))
        fresh = self.t1 + np.floor(hash_uniform(self.seed, Stream.SPS_OFFSET, tx_id, k)
                                   * (self.t2 - self.t1 + 1))
        keep = hash_uniform(self.seed, Stream.SPS_KEEP, tx_id, k) < self.keep
        keep[0] = False
        source = np.maximum.accumulate(np.where(keep, 0, k))  # last epoch that reselected
        offsets = fresh[source]
        self._tables[tx_id] = (starts, offsets)
        return starts, offsets

    def access_delay_ms(self, tx_id, seq):
        """Subframe offset (ms) of packet `seq` of transmitter `tx_id`; both broadcast."""
        tx_id, seq = np.broadcast_arrays(np.asarray(tx_id, np.int64), np.asarray(seq, np.int64))
        out = np.empty(tx_id.shape)
        for tx in np.unique(tx_id):
            sel = tx_id == tx
            starts, offsets = self._table(int(tx), int(seq[sel].max()))
            out[sel] = offsets[np.searchsorted(starts, seq[sel], side="right") - 1]
        return out
