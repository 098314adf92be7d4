"""Pairing left and right frames by time, within a tolerance (``Dataset.stereo_tol_ns``).

Hardware-triggered stereo pairs carry equal or nearly equal stamps: EuRoC's are equal, the KITTI
raw right camera's own stamps differ from the left's by -5.6 to +4.0 ms. The default tolerance,
``DEFAULT_STEREO_TOL_NS`` (10 ms), covers those; a data set may set its own in ``body.yaml``
(``stereo_pair_tolerance_ns``).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

I64 = NDArray[np.int64]


def match_stereo(tl_ns: I64, tr_ns: I64, tol_ns: int) -> tuple[I64, I64]:
    """Each left frame with its nearest right frame within ``tol_ns``: (index into left, index
    into right), both (P,) int64, in left order. Times must be sorted."""
    tl = np.asarray(tl_ns, np.int64)
    tr = np.asarray(tr_ns, np.int64)
    if tr.size == 0 or tl.size == 0:
        e = np.zeros(0, np.int64)
        return e, e
    j = np.clip(np.searchsorted(tr, tl), 1, max(tr.size - 1, 1))
    j_lo = np.clip(j - 1, 0, tr.size - 1)
    j_hi = np.clip(j, 0, tr.size - 1)
    pick = np.where(np.abs(tr[j_lo] - tl) <= np.abs(tr[j_hi] - tl), j_lo, j_hi)
    ok = np.abs(tr[pick] - tl) <= tol_ns
    return np.flatnonzero(ok).astype(np.int64), pick[ok].astype(np.int64)


def nearest_offsets_ns(tl_ns: I64, tr_ns: I64) -> I64:
    """|t_right - t_left| (ns) to the nearest right frame, per left frame (for messages)."""
    idx_l, idx_r = match_stereo(tl_ns, tr_ns, np.iinfo(np.int64).max // 2)
    return np.abs(np.asarray(tr_ns)[idx_r] - np.asarray(tl_ns)[idx_l])
