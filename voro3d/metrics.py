"""Surface accuracy as the VoroMesh paper reports it (Chamfer distance, F1, normal consistency),
and how the triangles look (:func:`triangle_quality`).

Conventions follow the paper's evaluation code (itself NDC's): both meshes are placed in the NDC
frame of the ground truth (bounding box centred, diagonal 1); 100,000 area-uniform samples are
drawn on each surface with the normals of their faces; distances are to the nearest sample of the
other surface. Watertightness is not measured here: see :func:`voro3d.watertight.check_watertight`.
"""
from __future__ import annotations

import numpy as np

from ._validate import positive_int
from .frames import ndc_frame
from .geometry import centred_scene, face_area_vectors, face_normals, smallest_angles
from .io import mesh_arrays
from .sampling import sample_surface

__all__ = ["CHAMFER_FACTOR", "evaluate", "triangle_quality"]

# The paper's tables print CD multiplied by this factor.
CHAMFER_FACTOR = 1e5


def evaluate(pred, gt, *, n_samples: int = 100_000, seed: int = 0, delta: float = 0.003) -> dict:
    """Compare a predicted surface with the ground truth.

    Parameters
    ----------
    pred, gt : open3d.geometry.TriangleMesh or (vertices, triangles)
        Any units; both are mapped by the ground truth's NDC frame (:func:`voro3d.frames.ndc_frame`).
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


def triangle_quality(pred, gt, *, max_angle: float = 30.0, sliver_angle: float = 5.0) -> dict:
    """How a surface's triangles look: turned away from the true surface, or thin.

    Parameters
    ----------
    pred, gt : open3d.geometry.TriangleMesh or (vertices, triangles)
        The surface to judge and the true surface, in the same units.
    max_angle : float, keyword-only
        A triangle is off-normal when its normal is more than this (degrees) from the normal of
        ``gt`` at the point of ``gt`` nearest its centroid, unsigned as NC (a triangle of zero
        area has no normal and counts as off-normal).
    sliver_angle : float, keyword-only
        A triangle is a sliver when its smallest angle is under this (degrees).

    Returns
    -------
    dict
        ``off_normal_share``, ``sliver_share`` : float -- fractions of ``pred``'s triangles.
        ``off_normal_area_share`` : float -- fraction of ``pred``'s area that is off-normal: what
        the eye sees, where a count favours surfaces with many small triangles where they are right
        (Poisson's octree is fine near the points and coarse across a filled hole).

    Raises
    ------
    ValueError
        A mesh without triangles, ``max_angle`` outside (0, 90] or ``sliver_angle`` outside (0, 60].
    """
    import open3d as o3d

    vertices, triangles = mesh_arrays(pred, "pred")
    gt_vertices, gt_triangles = mesh_arrays(gt, "gt")
    if not 0 < max_angle <= 90:
        raise ValueError(f"max_angle must be in (0, 90] degrees, got {max_angle}")
    if not 0 < sliver_angle <= 60:
        raise ValueError(f"sliver_angle must be in (0, 60] degrees, got {sliver_angle}")
    corners = vertices[triangles]
    normals = face_area_vectors(vertices, triangles)
    length = np.linalg.norm(normals, axis=1)
    gt_normals = face_normals(gt_vertices, gt_triangles)
    scene, origin = centred_scene(gt_vertices, gt_triangles)
    nearest = scene.compute_closest_points(o3d.core.Tensor((corners.mean(axis=1) - origin).astype(np.float32)))
    truth = gt_normals[nearest["primitive_ids"].numpy().astype(np.int64)]
    cosine = np.abs(np.einsum("ij,ij->i", normals, truth)) / np.maximum(length, 1e-300)
    off = (length == 0) | (cosine < np.cos(np.radians(max_angle)))
    smallest = smallest_angles(vertices, triangles)
    return {"off_normal_share": float(off.mean()), "sliver_share": float((smallest < sliver_angle).mean()),
            "off_normal_area_share": float(length[off].sum() / length.sum()) if length.sum() > 0 else 1.0}
