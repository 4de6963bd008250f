from __future__ import annotations

import math

import numpy as np
from jaxtyping import ArrayLike, Float

from ._stats import json_number


def gain_stats(K: Float[ArrayLike, "N n n"]) -> dict:
    r"""Symmetry and definiteness of a gain over a run, JSON-ready.

    ``max_rel_asymmetry`` $= \max_k \|K_k - K_k^\top\|_F / \|K_k\|_F$, ``min_eigenvalue`` $= \min_k
    \lambda_{\min}((K_k + K_k^\top)/2)$ and ``final_diagonal`` (diag of the last K). Only finite gains enter
    the statistics; ``non_finite_steps`` counts the others (a diverged run), and a statistic without any
    finite gain is None.
    """
    K = np.asarray(K, dtype=np.float64)
    ok = np.all(np.isfinite(K), axis=(-2, -1))
    Kf = K[ok]
    if Kf.shape[0]:
        KT = np.swapaxes(Kf, -1, -2)
        norm = np.linalg.norm(Kf, axis=(-2, -1))
        asym = np.linalg.norm(Kf - KT, axis=(-2, -1)) / np.where(norm > 0, norm, 1.0)
        eig = np.linalg.eigvalsh(0.5 * (Kf + KT))
        max_asym, min_eig = float(asym.max()), float(eig.min())
    else:
        max_asym = min_eig = math.nan
    return {"max_rel_asymmetry": json_number(max_asym), "min_eigenvalue": json_number(min_eig),
            "final_diagonal": [json_number(v) for v in np.diagonal(K[-1])],
            "non_finite_steps": int((~ok).sum())}
