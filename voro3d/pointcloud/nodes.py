"""Each node of a grid over the fit frame's ``[-1, 1]^3`` and its nearest point, where it matters.

The IMLS band of :mod:`~voro3d.pointcloud.surface` is read within a few kernel widths of the points,
exactly, and the depth limit of :mod:`~voro3d.pointcloud.fields` within a shell's depth, blurred by a
node: the first needs the distance from a node to its nearest point within that point's reach, the
second only to within a fraction of a node, further out.
"""
from __future__ import annotations

import numpy as np

__all__ = ["node_distance"]

# node_distance queries the nodes within the reach of this share of the points first, then the rest
# near the points that reach further (speed only: the distances are the same).
COMMON_REACH_SHARE = 0.99
# Beyond the points' reach node_distance reads the distance to one point of each cell this many
# nodes wide: at most sqrt(3) / 4 of a node more than the nearest point's. Exact queries of a dense
# cloud get slower the further the node (more points lie near the rim of its ball): the IMLS target
# of a 1-view range scan of 265k points (the cow, 1600x1200 pixels) read the distance out to its
# shell's depth (9 nodes at 128^3) in 11.3 s; exact within its band and from the 60k cells' points
# beyond, 2.4 s, on average 0.009 of a node further (at most 0.25). Range scans of 30k points have
# about a point a cell: the same surfaces (bench_pointcloud.py --no-poisson, 1 / 3 / 6 views of the
# 28 meshes of pointcloud_range and _more: the same CDs to 0.1%); at ~300k points (the 12 meshes of
# pointcloud_dense_range) CD 277.16 -> 277.70, F1 0.414 -> 0.415, the surface stage 225 -> 144 s.
FAR_CELL_NODES = 0.25


def node_distance(tree, resolution: int, reach, *, far=None) -> tuple[np.ndarray, np.ndarray]:
    """Distance from each node of a ``resolution^3`` grid over ``[-1, 1]^3`` to the nearest point,
    where it is under that point's ``reach``; beyond, up to ``far``, within ``FAR_CELL_NODES``
    times sqrt(3) nodes of it.

    Only nodes near an occupied voxel are queried (all nodes of a 62^3 grid around a 9k-point range
    scan: 0.5 s, mostly far from all points); first within the reach of nearly all points
    (``COMMON_REACH_SHARE``), then, of the nodes left, those within reach of their nearest point of
    the few that reach further (every node left within the widest reach: 0.6 s of 0.8 s on a 30k-point
    range scan whose 300 widest kernels reach four times further than the rest).

    Parameters
    ----------
    tree : scipy.spatial.cKDTree
        Of the points, fit frame.
    resolution : int
    reach : float or (n,) float64
        Fit-frame units: one for all points, or each point's own.
    far : float, optional
        Fit-frame units.

    Returns
    -------
    distance : (r, r, r) float64
        Exact at every node within its nearest point's reach; beyond it, at the nodes within
        ``far`` of a point, the distance to a point at most ``FAR_CELL_NODES * sqrt(3)`` nodes
        further; elsewhere ``inf`` or one of those.
    nearest : (r, r, r) int64
        The index of the point the distance is to, ``tree.n`` where it is ``inf``.
    """
    from scipy.spatial import cKDTree

    from ..geometry import grid_voxel

    reach = np.broadcast_to(np.asarray(reach, np.float64), (tree.n,))
    common = float(np.quantile(reach, COMMON_REACH_SHARE))
    distance = np.full(resolution**3, np.inf)
    nearest = np.full(resolution**3, tree.n, np.int64)
    nodes, coordinates = _nodes_near(tree.data, resolution, common)
    distance[nodes], nearest[nodes] = tree.query(coordinates, distance_upper_bound=common, workers=-1)
    wide = np.flatnonzero(reach > common)
    if wide.size:
        # A node left is within its nearest point's reach only if that point is wide, the nearest wide one.
        widest = float(reach[wide].max())
        nodes, coordinates = _nodes_near(tree.data[wide], resolution, widest, np.isinf(distance))
        gap, which = cKDTree(tree.data[wide]).query(coordinates, distance_upper_bound=widest, workers=-1)
        kept = np.flatnonzero(gap <= np.append(reach[wide], -1.0)[which])
        distance[nodes[kept]], nearest[nodes[kept]] = tree.query(coordinates[kept], workers=-1)
    if far is not None:
        cells = np.floor((tree.data + 1.0) / (FAR_CELL_NODES * grid_voxel(resolution))).astype(np.int64)
        span = int(cells.max()) + 1
        _, first = np.unique((cells[:, 0] * span + cells[:, 1]) * span + cells[:, 2], return_index=True)
        nodes, coordinates = _nodes_near(tree.data[first], resolution, far, np.isinf(distance))
        gap, which = cKDTree(tree.data[first]).query(coordinates, distance_upper_bound=far, workers=-1)
        found = np.isfinite(gap)
        distance[nodes[found]], nearest[nodes[found]] = gap[found], first[which[found]]
    return distance.reshape((resolution,) * 3), nearest.reshape((resolution,) * 3)


def _nodes_near(points, resolution: int, reach: float, wanted=None):
    """``(nodes, coordinates)``: C-order indices and positions of the nodes within ``reach`` (and a
    node) of the voxels that hold ``points``, among the ``wanted`` ones (flat bool) where given."""
    from scipy import ndimage

    from ..geometry import grid_voxel
    from ..sampling import node_coordinates

    step = grid_voxel(resolution)
    voxel = np.clip(np.rint((points + 1.0) / step).astype(np.int64), 0, resolution - 1)
    occupied = np.zeros((resolution,) * 3, bool)
    occupied[tuple(voxel.T)] = True
    # A node within reach of a point is within this many nodes of the point's own node per axis.
    radius = int(np.ceil(reach / step)) + 1
    nodes = ndimage.maximum_filter(occupied, size=2 * radius + 1, mode="constant").ravel()
    nodes = np.flatnonzero(nodes if wanted is None else nodes & wanted)
    return nodes, node_coordinates(nodes, resolution)
