"""Best-fit rigid motion of a part and the paper's "desired position" (Section 5.2, docs/model.md, "Desired position").

The desired position of a particle is its original position carried by its part's current rigid
motion — the rotation R and translation t minimizing Σ‖p_i − (R o_i + t)‖² (Kabsch), taken from
``scipy.spatial.transform.Rotation.align_vectors``. A rigidly moving part has zero deformation.
"""
from __future__ import annotations

import warnings

import numpy as np
from scipy.spatial.transform import Rotation


def best_fit(o: np.ndarray, p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(R, t) with p ≈ o·Rᵀ + t in the least-squares sense (equal weights)."""
    co, cp = o.mean(axis=0), p.mean(axis=0)
    if len(o) < 2:
        return np.eye(3), cp - co
    with warnings.catch_warnings():  # collinear sets: any rotation about the line is optimal
        warnings.simplefilter("ignore", UserWarning)
        rot, _ = Rotation.align_vectors(p - cp, o - co)
    R = rot.as_matrix()
    return R, cp - co @ R.T


def desired_positions(o: np.ndarray, p: np.ndarray) -> np.ndarray:
    """The original positions carried by the best-fit rigid motion of o onto p."""
    R, t = best_fit(o, p)
    return o @ R.T + t


def deformation(o: np.ndarray, p: np.ndarray) -> np.ndarray:
    """Per-particle distance from the desired position: the paper's stress measure."""
    return np.linalg.norm(p - desired_positions(o, p), axis=1)


def max_deformation(o: np.ndarray, p: np.ndarray) -> float:
    """Largest distance of a particle from its desired position (0 for a rigid motion)."""
    return float(deformation(o, p).max())
