"""Checks of an estimated egomotion before it becomes a measurement: plausibility limits and
agreement with an external motion prior (``frontend.pipeline``)."""

from __future__ import annotations

import numpy as np

from svains.frontend.options import FrontendOptions
from svains.frontend.types import Egomotion
from svains.geometry.rotation import so3_log


def agrees_with_prior(ego: Egomotion, prior: Egomotion, gate_chi2: float) -> bool:
    """Mahalanobis test of the estimate against an external motion prior (6 dof, summed
    covariances, ``gate_chi2``)."""
    d = np.concatenate([
        so3_log(prior.R_Ck_Ckm1.T @ ego.R_Ck_Ckm1), ego.p_Ck_Ckm1 - prior.p_Ck_Ckm1
    ])
    S = ego.cov + prior.cov
    try:
        m2 = float(d @ np.linalg.solve(S, d))
    except np.linalg.LinAlgError:
        return False
    return bool(np.isfinite(m2) and m2 <= gate_chi2)


def plausible(ego: Egomotion, o: FrontendOptions) -> bool:
    """Finite, and within ``max_translation_m`` / ``max_rotation_deg`` (None: no limit)."""
    if not (np.all(np.isfinite(ego.R_Ck_Ckm1)) and np.all(np.isfinite(ego.p_Ck_Ckm1))):
        return False
    if o.max_translation_m is not None and np.linalg.norm(ego.p_Ck_Ckm1) > o.max_translation_m:
        return False
    if o.max_rotation_deg is None:
        return True
    # Rotation angle from the trace (no full matrix logarithm needed for a threshold).
    c = np.clip((np.trace(ego.R_Ck_Ckm1) - 1.0) / 2.0, -1.0, 1.0)
    return bool(np.degrees(np.arccos(c)) <= o.max_rotation_deg)
