"""Surface accuracy as the VoroMesh paper reports it: Chamfer distance, F1 and normal consistency.

Conventions follow the paper's evaluation code (itself NDC's): both meshes are placed in the NDC
frame of the ground truth (bounding box centred, diagonal 1); 100,000 area-uniform samples are
drawn on each surface with the normals of their faces; distances are to the nearest sample of the
other surface. Watertightness is not measured here: see :func:`voro3d.watertight.check_watertight`.
"""
from __future__ import annotations

import numpy as np

from ._validate import positive_int
from .io import mesh_arrays, ndc_frame
from .sampling import sample_surface

__all__ = ["CHAMFER_FACTOR", "evaluate"]

# The paper's tables print CD multiplied by this factor.
CHAMFER_FACTOR = 1e5


def evaluate(pred, gt, *, n_samples: int = 100_000, seed: int = 0, delta: float = 0.003) -> dict:
    """Compare a predicted surface with the ground truth.

    Parameters
    ----------
    pred, gt : open3d.geometry.TriangleMesh or (vertices, triangles)
        Any units; both are mapped by the ground truth's NDC frame (:func:`voro3d.io.ndc_frame`).
    n_samples : int, keyword-only
        Surface samples per mesh.
    seed : int, keyword-only
        Seeds the two samplings (ground truth and prediction draw independent streams), so the
        result is reproducible.
    delta : float, keyword-only
        F1 distance threshold in NDC units (the paper: 0.003).

    Returns
    -------
    dict
        ``chamfer`` : float -- mean squared nearest distance pred->gt plus gt->pred (NDC units^2).
        ``chamfer_x1e5`` : float -- the same times 1e5, as in the paper's tables.
        ``chamfer_l1`` : float -- the same with unsquared distances (NDC units).
        ``precision``, ``recall``, ``f1`` : float -- fractions of pred (resp. gt) samples closer
        than ``delta`` to the other set, and their harmonic mean (0 when both are 0).
        ``nc`` : float -- normal consistency, mean over both directions of ``|n . n_nearest|``.
        ``n_vertices``, ``n_triangles`` : int -- size of ``pred``.

    Raises
    ------
    ValueError
        A mesh without triangles or with zero area, ``n_samples < 1``, ``delta`` not positive.
    """
    from scipy.spatial import cKDTree

    pred_vertices, pred_triangles = mesh_arrays(pred, "pred")
    gt_vertices, gt_triangles = mesh_arrays(gt, "gt")
    n_samples = positive_int(n_samples, "n_samples")
    if not np.isfinite(delta) or delta <= 0:
        raise ValueError(f"delta must be finite and > 0, got {delta}")

    frame = ndc_frame(gt_vertices[np.unique(gt_triangles)])
    gt_seed, pred_seed = np.random.SeedSequence(seed).generate_state(2)
    gt_points, gt_normals = sample_surface((frame.apply(gt_vertices), gt_triangles), n_samples, seed=int(gt_seed))
    pred_points, pred_normals = sample_surface((frame.apply(pred_vertices), pred_triangles), n_samples,
                                               seed=int(pred_seed))

    to_gt, nearest_gt = cKDTree(gt_points).query(pred_points, k=1, workers=-1)
    to_pred, nearest_pred = cKDTree(pred_points).query(gt_points, k=1, workers=-1)

    chamfer = float(np.mean(to_gt**2) + np.mean(to_pred**2))
    precision = float(np.mean(to_gt < delta))
    recall = float(np.mean(to_pred < delta))
    f1 = 2 * precision * recall / (precision + recall) if precision + recall > 0 else 0.0
    consistency = (np.abs(np.einsum("ij,ij->i", pred_normals, gt_normals[nearest_gt])).mean()
                   + np.abs(np.einsum("ij,ij->i", gt_normals, pred_normals[nearest_pred])).mean()) / 2
    return {
        "chamfer": chamfer,
        "chamfer_x1e5": chamfer * CHAMFER_FACTOR,
        "chamfer_l1": float(np.mean(to_gt) + np.mean(to_pred)),
        "precision": precision,
        "recall": recall,
        "f1": float(f1),
        "nc": float(consistency),
        "n_vertices": int(pred_vertices.shape[0]),
        "n_triangles": int(pred_triangles.shape[0]),
    }
