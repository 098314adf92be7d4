"""Fast quaternion kernels for the hot loop, on component-first arrays (4, ...) / (3, ...).

Same conventions as ``svains.geometry.rotation`` (Hamilton, scalar first), which stays the
reference implementation; these avoid ``np.stack``/``np.cross`` overheads and strided access,
which dominate at sigma-point sizes. Tests check both agree.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

F64 = NDArray[np.float64]

_SMALL = 1e-6


def qmul(p: F64, q: F64) -> F64:
    """Hamilton product ``p ⊗ q`` of component-first arrays (4, ...)."""
    pw, px, py, pz = p
    qw, qx, qy, qz = q
    return np.array(
        [
            pw * qw - px * qx - py * qy - pz * qz,
            pw * qx + px * qw + py * qz - pz * qy,
            pw * qy - px * qz + py * qw + pz * qx,
            pw * qz + px * qy - py * qx + pz * qw,
        ]
    )


def left_matrix(p: F64 | tuple[float, float, float, float]) -> F64:
    """4x4 matrix ``L(p)`` with ``p ⊗ q = L(p) q`` for one quaternion ``p`` (4,)."""
    # Python floats: building the array from NumPy scalars costs several times more.
    w, x, y, z = p.tolist() if isinstance(p, np.ndarray) else p
    return np.array([[w, -x, -y, -z], [x, w, -z, y], [y, z, w, -x], [z, -y, x, w]])


def qexp(r: F64) -> F64:
    """``Exp`` of rotation vectors (3, ...) -> unit quaternions (4, ...)."""
    a2 = r[0] * r[0] + r[1] * r[1] + r[2] * r[2]
    a = np.sqrt(a2)
    small = a < _SMALL
    k = np.where(small, 0.5 - a2 / 48.0, np.sin(0.5 * a) / np.where(small, 1.0, a))
    return np.array([np.cos(0.5 * a), k * r[0], k * r[1], k * r[2]])


def qlog(q: F64) -> F64:
    """``Log`` of unit quaternions (4, ...) -> rotation vectors (3, ...), angle in [0, π]."""
    w = q[0]
    sign = np.where(w < 0.0, -1.0, 1.0)
    w = w * sign
    v = q[1:] * sign
    s = np.sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2])
    small = s < _SMALL
    k = np.where(
        small,
        # (both branches are evaluated: w is 0 at a half turn, where ``small`` is False)
        (2.0 / np.where(small, w, 1.0)) * (1.0 - s * s / (3.0 * np.where(small, w * w, 1.0))),
        2.0 * np.arctan2(s, w) / np.where(small, 1.0, s),
    )
    return k * v


def qrot(q: F64, v: F64) -> F64:
    """``R(q) v`` for (4, ...) and (3, ...) arrays (broadcasting)."""
    w, ux, uy, uz = q
    tx = 2.0 * (uy * v[2] - uz * v[1])
    ty = 2.0 * (uz * v[0] - ux * v[2])
    tz = 2.0 * (ux * v[1] - uy * v[0])
    return np.array(
        [
            v[0] + w * tx + (uy * tz - uz * ty),
            v[1] + w * ty + (uz * tx - ux * tz),
            v[2] + w * tz + (ux * ty - uy * tx),
        ]
    )


def cross(a: F64, b: F64) -> F64:
    """``a × b`` for component-first (3, ...) arrays (broadcasting)."""
    return np.array(
        [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]
    )


# ---- row-major kernels (N, 4) / (N, 3): few NumPy calls each (gathers + one matmul) ----------
# p ⊗ q = L(p) q with L(p)[a, b] = sign[a, b] * p[idx[a, b]].
_L_IDX = np.array([[0, 1, 2, 3], [1, 0, 3, 2], [2, 3, 0, 1], [3, 2, 1, 0]])
_L_SGN = np.array([[1, -1, -1, -1], [1, 1, -1, 1], [1, 1, 1, -1], [1, -1, 1, 1]], dtype=float)
# R(q) (row-major 9) = (q_i q_j for the 10 pairs i <= j) @ _R_COEF.
_PAIRS_I, _PAIRS_J = np.triu_indices(4)
_R_COEF = np.zeros((10, 9))
for _k, (_i, _j) in enumerate(zip(_PAIRS_I, _PAIRS_J, strict=True)):
    _name = "wxyz"[_i] + "wxyz"[_j]
    for _entry, _c in {
        "ww": {0: 1, 4: 1, 8: 1}, "xx": {0: 1, 4: -1, 8: -1}, "yy": {0: -1, 4: 1, 8: -1},
        "zz": {0: -1, 4: -1, 8: 1}, "xy": {1: 2, 3: 2}, "xz": {2: 2, 6: 2}, "yz": {5: 2, 7: 2},
        "wx": {5: -2, 7: 2}, "wy": {2: 2, 6: -2}, "wz": {1: -2, 3: 2},
    }[_name].items():  # fmt: skip
        _R_COEF[_k, _entry] = _c
_SKEW_IDX = np.array([[0, 2, 1], [2, 0, 0], [1, 0, 0]])
_SKEW_SGN = np.array([[0, -1, 1], [1, 0, -1], [-1, 1, 0]], dtype=float)


def left_matrices(p: F64) -> F64:
    """``L(p)`` (N, 4, 4) for quaternions (N, 4): ``p ⊗ q = L(p) @ q``."""
    return p[:, _L_IDX] * _L_SGN


def qmul_rows(p: F64, q: F64) -> F64:
    """Hamilton products of rows (N, 4) x (N, 4) -> (N, 4)."""
    return np.matmul(left_matrices(p), q[:, :, None])[:, :, 0]


def rotmat_rows(q: F64) -> F64:
    """Rotation matrices (N, 3, 3) of unit quaternions (N, 4)."""
    return ((q[:, _PAIRS_I] * q[:, _PAIRS_J]) @ _R_COEF).reshape(-1, 3, 3)


def skew_rows(v: F64) -> F64:
    """Skew matrices (N, 3, 3) of vectors (N, 3)."""
    return v[:, _SKEW_IDX] * _SKEW_SGN
