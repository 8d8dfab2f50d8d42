"""A smooth target surface from an oriented point cloud: the field the VoroLoss fit follows.

Near the points the field is an implicit moving-least-squares (IMLS) signed distance
(Kolluri 2008; robust weights as in RIMLS, Oztireli et al. 2009): a Gaussian-weighted mean of
the distances to the points' tangent planes, with each point's kernel width set from its local
spacing and the cloud's noise. Away from the points (holes, the far field) only the side is
needed, and the generalized winding number of the oriented points (Barill et al. 2018) gives it,
closing holes smoothly (at a level that also suits open, one-sided scans: :func:`~voro3d.pointcloud.sides.winding_level`).
The field is sampled on a grid finer than the VoroMesh grid; Marching Cubes of it gives a dense
closed proxy surface whose vertices are then projected onto the IMLS zero set, and the same
grid answers inside/outside. Past the rim of a seen patch, where the band ends inside and the far
field reads outside, the jump between the two is blurred over a node or two
(:func:`~voro3d.pointcloud.fields.smooth_band_edge`).
"""
from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np

from .fields import (MIN_SUPPORT, GridSurface, bridge, depth_limit, limit_reach, mesh_field,
                     smooth_band_edge, smooth_maximum, within)
from .nodes import node_distance
from .sides import winding_level
from .tuning import MAX_BRIDGE_GAP, SHELL_ROUNDING_NODES

__all__ = ["TargetSurface", "imls", "shell_depths", "target_surface"]

# Neighbours that enter one IMLS evaluation. Gaussian weights beyond ~3 kernel widths vanish;
# 32 neighbours cover that for the widths used (0.75-1.5 spacings, more on noisy clouds).
IMLS_NEIGHBOURS = 32
# RIMLS refitting passes: the residual weights stop points across a sharp edge from rounding it.
ROBUST_PASSES = 2
# The IMLS field is used within this many kernel widths of the points.
IMLS_BAND = 3.0
# Where the band's edge crosses the zero level (past the rim of a seen patch), the field is blurred
# by a Gaussian of BAND_EDGE_BLUR_NODES grid steps within BAND_EDGE_REACH_NODES of the crossing, and
# only where both nodes lie over BAND_EDGE_CLEARANCE_NODES from the points (fields.smooth_band_edge).
# Off -> on, 2026-12-06, no normals, grid 64: range scans of the 12 benchmark meshes from 1 view CD
# 210.3 -> 211.5, NC 0.738 -> 0.747, F1 0.373 -> 0.384; 3 views 45.34 -> 45.24, 0.896 -> 0.904, 0.681
# -> 0.691; range_more's 16 from 1 view 446.6 -> 447.8, 0.764 -> 0.775, 0.348 -> 0.360, from 3 views
# 68.93 -> 68.83, 0.917 -> 0.921, 0.653 -> 0.656; on a table 132.5 / 83.5 -> 134.7 / 84.6, NC 0.820 /
# 0.904 -> 0.826 / 0.912, F1 0.334 / 0.464 -> 0.333 / 0.473; 6 views unchanged; all closed, one
# piece. Rendered, the crust along the bunny's ears and feet (1 view) is gone. Blurs of 0.5 / 1 / 2
# nodes, 12 meshes: 1 view NC 0.744 / 0.747 / 0.741, F1 0.379 / 0.384 / 0.382 (CD 210.8 / 211.5 /
# 211.1); 3 views NC 0.900 / 0.904 / 0.900, F1 0.686 / 0.691 / 0.682 (45.28 / 45.24 / 45.40), all one
# piece. Reach and clearance were not varied. Without the clearance a band under two nodes thick
# (sparse points) meets the far field at the surface itself: abc_00000001 from 3 views F1 0.377 ->
# 0.077. Blurred before the bridges, or without fields._restore_cuts, an ear (cheburashka, 1 view)
# and a rocker arm on its table (3 views) came off.
BAND_EDGE_BLUR_NODES = 1.0
BAND_EDGE_REACH_NODES = 2
BAND_EDGE_CLEARANCE_NODES = 2.0
# The far field is (level - w) / |grad w|, a first-order distance to the winding number's level set,
# the slope never under this (winding number per fit-frame unit): a guard against dividing by
# nothing only (floors of 0.03, 0.1 and 0.3 gave the same benchmark figures to four digits). Scaled by
# two median kernel widths instead (a slope that holds at the points only), it crossed zero behind an
# open scan at a slope of 0.02-0.04 and the shell's back came out in terraces (12 benchmark meshes, no
# normals, grid 64, 2026-12-06: 1 view CD 209.8 -> 209.2, NC 0.7277 -> 0.7313, F1 0.3668 -> 0.3673;
# 3 views 45.85 -> 45.78, 0.8913 -> 0.8953, 0.6753 -> 0.6808).
FAR_FIELD_MIN_SLOPE = 0.1
# Neighbours over which shell_depths reads a point's curvature.
CURVATURE_NEIGHBOURS = 32
# shell_depths spreads the depths over this share of the thinnest shell (_spread_depths: the least
# within a cell this wide and its neighbours, then a Gaussian this wide; 2 nodes of the field's grid).
# Off -> on, 2026-12-06, no normals, grid 64, --no-poisson runs: objects on a table (bench_scenes.py)
# from 1 view CD 134.7 -> 122.8, NC 0.826 -> 0.829, F1 0.333 -> 0.339, from 3 views 84.6 -> 74.0, 0.912
# -> 0.914, 0.473 -> 0.481 (the plate's rim no longer hangs in drips); range scans of the 12 benchmark
# meshes from 1 view 211.5 -> 210.7, NC 0.7474 -> 0.7467, F1 0.3841 -> 0.3856; range_more's 16 from 1
# view 447.8 -> 446.7, 0.7753 -> 0.7758, 0.3602 -> 0.3614, from 3 views 68.8 -> 66.8, 0.9209 -> 0.9218,
# 0.6556 -> 0.6562; all closed, one piece. Averaged without the least first, the rims deepened and
# bulged past the seen edge: on a table from 3 views CD 84.6 -> 85.0 / 96.0 / 105.0 at 0.25 / 0.5 / 1
# (at 0.25 the drips stay), harmonic mean at 0.5 91.7.
DEPTH_SPREAD = 0.5


@dataclass
class TargetSurface(GridSurface):
    """The target surface on a grid over ``[-1, 1]^3`` (the fit frame).

    Attributes
    ----------
    field : (r, r, r) float64
        Signed field at the grid nodes, negative inside; IMLS distance in the band around the
        points, further away a first-order distance to the winding number's level set.
    vertices : (v, 3) float64
    triangles : (t, 3) int64
        Marching Cubes of ``field``: closed, outward.
    points, normals : (n, 3) float64
        The oriented points the IMLS field is made of.
    widths : (n,) float64
        Kernel width of each point.
    held : (r, r, r) bool
        Nodes whose grid value stands near the zero set (``inside`` does not re-test them against
        the IMLS field, nor ``project`` move them onto it): where unsupported pieces were removed
        (their side flipped), and where the band's edge was smoothed (``fields.smooth_band_edge``).
    areas : (n,) float64
        Area each point stands for (winding number weights).
    level : float
        Winding number that separates inside from outside (:func:`~voro3d.pointcloud.sides.winding_level`).
    dense : bool
        Near the surface, decide inside by the winding number instead of IMLS (see ``inside``).
    limit : (r, r, r) float64 or None
        Where the solid is held within a depth of the points (``target_surface(depth=...)``): the
        blurred distance to the points minus that depth, negative within it; the inside is where
        the two's smooth maximum (``SHELL_ROUNDING_NODES``) is negative (outside the cavities it closes).
    """

    points: np.ndarray
    normals: np.ndarray
    widths: np.ndarray
    held: np.ndarray
    areas: np.ndarray
    level: float
    dense: bool = False
    limit: np.ndarray | None = None

    def inside(self, queries: np.ndarray) -> np.ndarray:
        """(q, 3) fit-frame points -> (q,) bool, True inside.

        The grid field (trilinear) decides, except within a grid step of its zero set, where the
        query itself is tested: a wall thinner than the grid step, which the grid cannot hold,
        is still inside there. The test is the IMLS field, or, for ``dense`` points (several per
        grid step: their winding number is smooth and exact at walls a few points thick), the
        winding number. At ``held`` nodes (debris removed, rims smoothed) the grid decides.
        """
        queries = np.asarray(queries, np.float64)
        step = 2.0 / (self.resolution - 1)
        value, index = self._field_at(queries)
        close = (np.abs(value) < step) & ~self._held_at(index)
        tested = np.flatnonzero(close)
        if tested.size and self.dense:
            from ..queries import point_winding_number

            value[tested] = self.level - point_winding_number(self.points, self.normals, queries[tested],
                                                              areas=self.areas)
        elif tested.size:
            tested, tree = self._in_band(queries, tested)
            value[tested], _, _ = imls(self.points, self.normals, self.widths, queries[tested], tree=tree)
        if self.limit is not None and tested.size:
            from scipy.ndimage import map_coordinates

            # The grid's values hold the limit already; the tested ones meet it as the grid's did.
            value[tested] = smooth_maximum(value[tested], map_coordinates(self.limit, index[tested].T, order=1,
                                                                          mode="nearest"), SHELL_ROUNDING_NODES * step)
        return value < 0

    def project(self, queries: np.ndarray) -> np.ndarray:
        """Points of the proxy mesh moved onto the IMLS zero set: one Newton step along the
        field's mean normal, taken only where it moves the point less than a grid step, off ``held``
        nodes and within the IMLS band (over filled holes, past rims, beyond the band, the proxy mesh
        is the surface). Beyond the band the step led onto the nearest point's plane extended 4-14
        steps off, scales along the rims of cut scans; taken there too -> within the band only
        (2026-12-06, the 12 benchmark meshes, grid 64): 1 / 3 views CD 138.72 / 39.10 -> 138.61 /
        39.16, NC 0.8130 / 0.9159 -> 0.8146 / 0.9167; their dense one-view frames 139.1 -> 139.6, NC
        0.823 -> 0.828."""
        queries = np.array(queries, np.float64)
        free = np.flatnonzero(~self._held_at((queries + 1.0) * (0.5 * (self.resolution - 1))))
        free, tree = self._in_band(queries, free)
        value, gradient, _ = imls(self.points, self.normals, self.widths, queries[free], tree=tree)
        move = -value[:, None] * gradient
        small = np.linalg.norm(move, axis=1) < 2.0 / (self.resolution - 1)
        queries[free[small]] += move[small]
        return queries

    @cached_property
    def _tree(self):
        """A kd-tree of ``points``, built once for every ``inside`` and ``project`` call."""
        from scipy.spatial import cKDTree

        return cKDTree(self.points)

    def _in_band(self, queries, rows):
        """``(rows, tree)``: the ``rows`` of ``queries`` within ``IMLS_BAND`` kernel widths of their
        nearest point, and a kd-tree of the points. The search is bounded by the widest band: a query
        deep in a solid that fills a hull, far from every point, is slow to resolve exactly (the
        dense frame of fandisk from one view: 31 of 69 s) and outside the band either way."""
        # A hair past the band: scipy's bound is strict, the band's edge is not.
        bound = np.nextafter(IMLS_BAND * self.widths.max(), np.inf)
        distance, nearest = self._tree.query(queries[rows], distance_upper_bound=bound, workers=-1)
        found = np.isfinite(distance)
        rows, distance, nearest = rows[found], distance[found], nearest[found]
        return rows[distance <= IMLS_BAND * self.widths[nearest]], self._tree

    def _held_at(self, index: np.ndarray) -> np.ndarray:
        """(q, 3) grid indices -> (q,) bool: whether the nearest node is ``held``."""
        return self.held[tuple(np.clip(np.rint(index), 0, self.resolution - 1).astype(np.int64).T)]


def imls(points, normals, widths, queries, *, tree=None, k: int = IMLS_NEIGHBOURS, block: int = 65536):
    """Robust IMLS signed distance and its direction at ``queries``.

    f(x) = sum_i w_i(x) n_i . (x - p_i) / sum_i w_i(x), with w_i = exp(-|x - p_i|^2 / h_i^2)
    times, after a first pass, a residual weight exp(-(f(x) - n_i . (x - p_i))^2 / h_i^2) that
    discounts planes from across a sharp edge (RIMLS). The gradient is approximated by the
    weighted mean normal, the usual IMLS choice, exact for a plane.

    Parameters
    ----------
    points, normals : (n, 3) float64
        Oriented points (unit outward normals).
    widths : (n,) float64
        Gaussian kernel width per point.
    queries : (q, 3) float64
    tree : scipy.spatial.cKDTree of ``points``, optional

    Returns
    -------
    value : (q,) float64
        Positive outside. Queries whose neighbours all lie beyond ~6 widths get the plain
        distance to the nearest tangent plane.
    gradient : (q, 3) float64
    agreement : (q,) float64
        The length of the weighted mean normal: 1 where the neighbours' normals agree, near 0
        where they cancel (the two sides of a thin wall). Always returned (it costs nothing),
        so that the three values unpack the same way on every call.
    """
    from scipy.spatial import cKDTree

    from .. import _fitkernel
    from .._system import available_cpus
    from ..queries import spatial_order

    points, normals, widths = (np.ascontiguousarray(a, np.float64) for a in (points, normals, widths))
    tree = cKDTree(points) if tree is None else tree
    k = min(k, points.shape[0])
    value = np.empty(queries.shape[0])
    gradient = np.empty((queries.shape[0], 3))
    length = np.empty(queries.shape[0])
    # Blocks of nearby queries share kd-tree nodes (spatial_order); the field itself is compiled.
    order = spatial_order(queries)
    for start in range(0, queries.shape[0], block):
        rows = order[start:start + block]
        x = queries[rows]
        distance, neighbour = (found.reshape(len(rows), k) for found in tree.query(x, k=k, workers=-1))
        value[rows], gradient[rows], length[rows] = _fitkernel.imls_field(
            points, normals, widths, x, neighbour, distance, robust_passes=ROBUST_PASSES, threads=available_cpus())
    return value, gradient, length


def target_surface(points, normals, widths, resolution: int, *, dense: bool = False,
                   min_support: int = MIN_SUPPORT, level: float | None = None,
                   hole_level: float | None = None, depth: float | None = None) -> TargetSurface:
    """Sample the field on a ``resolution^3`` grid over ``[-1, 1]^3`` and mesh it.

    Parameters
    ----------
    points, normals : (n, 3) float64
        Fit frame, outward unit normals.
    widths : (n,) float64
        Kernel width per point (fit-frame units); at least a third of a node is used.
    resolution : int
        Grid nodes per axis.
    dense : bool
        See :attr:`TargetSurface.dense`.
    min_support : int
        Pieces of surface nearest to fewer points (or to fewer than ``fields.SUPPORT_SHARE`` of the
        best-supported piece's) are debris and are removed (:func:`~voro3d.pointcloud.fields.mesh_field`).
    level : float, optional
        The cloud's :func:`~voro3d.pointcloud.sides.winding_level`, when the caller has it already.
    hole_level : float, optional
        The winding number at which the far field (holes, unseen parts) is closed; default ``level``.
        Between the two bounds: 1/2 spans a hole's rim without bulging (the cap over a round hole
        in a sphere is the flat disk) but cuts into parts seen from one side only, whose winding
        number stays under 1/2; a partial cloud's own, lower level keeps those and balloons its caps.
    depth : float or (n,) float64, optional
        Fit-frame units, one or each point's (:func:`shell_depths`). The solid reaches no further
        than this from the points, except where it encloses what lies further (the inside of a
        surface seen all round, or closed but for holes narrower than twice the depth): behind a
        one-sided scan it is then a shell this thick under the seen side, instead of a block out
        to the box (:func:`~voro3d.pointcloud.fields.depth_limit`).

    Returns
    -------
    TargetSurface
    """
    from scipy.spatial import cKDTree

    from ..geometry import grid_voxel
    from ..queries import point_areas, point_winding_number
    from ..sampling import grid_nodes, node_coordinates

    step = grid_voxel(resolution)
    tree = cKDTree(points)
    # The band reaches a node past the points, so that both ends of an edge the surface crosses read
    # the IMLS field: with the kernels of a dense scan (a tenth of a node, the bunny from 1 view at
    # 10^6 points) the nodes beside the points read the far field, the points lay 0.17 nodes off the
    # surface and the offset shell won; floored, 0.05 nodes. Wider kernels are left:
    # 1 / 3 / 6-view range scans at 30k points, a third missing and clean 100k clouds of the 12
    # benchmark meshes keep their CDs (--no-poisson, 2026-12-06).
    widths = np.maximum(widths, step / IMLS_BAND)
    # The distances for the band (nodes within IMLS_BAND kernel widths of their nearest point),
    # exact, and for the depth limit, within a fraction of the node its blur spans.
    reach = IMLS_BAND * widths + step
    far = None if depth is None else float(np.max(limit_reach(resolution, depth))) + step
    distance, nearest = (a.ravel() for a in node_distance(tree, resolution, reach, far=far))
    near = np.isfinite(distance)
    near[near] = distance[near] <= IMLS_BAND * widths[nearest[near]]
    field = np.empty(resolution**3)
    field[near], _, _ = imls(points, normals, widths, node_coordinates(np.flatnonzero(near), resolution), tree=tree)
    # Far field: winding number on a grid half as fine, trilinear, as a first-order distance to
    # the level it is closed at (FAR_FIELD_MIN_SLOPE), so that its crossings (hole fillings, the
    # back of an open scan's shell) meet the IMLS band and the depth limit on one scale.
    coarse_resolution = (resolution + 1) // 2
    areas = point_areas(points)
    coarse = point_winding_number(points, normals, grid_nodes(coarse_resolution),
                                  areas=areas).reshape((coarse_resolution,) * 3)
    # Not blurred: a Gaussian of 1.5 coarse nodes, meant to smooth hole fillings against the
    # Barnes-Hut error, moved each filling off the rim it closes, and the IMLS band met it in a
    # step (a bust cut flat underneath, seen from 3 views, got a dome set back behind a ledge).
    # 2026-12-06, no normals, grid 64, blurred -> not: range scans of the 12 benchmark meshes from
    # 1 view CD 208.4 -> 209.8, NC 0.721 -> 0.728, F1 0.366 -> 0.367; from 3 views (7 IMLS targets)
    # 31.6 -> 31.7, NC 0.875 -> 0.899, F1 0.644 -> 0.671 (0.75 nodes: 31.7, 0.891, 0.666; the far
    # field at full resolution, blurred 1.5 of its nodes: 31.8, 0.894, 0.668, 0.3 s more a cloud);
    # the 16 meshes of pointcloud_range_more from 1 view 444.2 -> 444.3, NC 0.741 -> 0.753, from 3
    # views 65.7 -> 68.1 (the lid abc_00000007 345 -> 377), NC 0.904 -> 0.914, F1 0.643 -> 0.650.
    far = ~near
    winding = _resample(coarse, resolution).ravel()[far]
    if level is None:
        level = float(np.clip(winding_level(points, normals, areas, float(np.median(widths))), 0.0, 0.5))
    coarse_slope = np.linalg.norm(np.stack(np.gradient(coarse, 2.0 / (coarse_resolution - 1))), axis=0)
    slope = _resample(coarse_slope, resolution).ravel()[far]
    field[far] = ((level if hole_level is None else hole_level) - winding) / np.maximum(slope, FAR_FIELD_MIN_SLOPE)
    field = field.reshape((resolution,) * 3)
    distance = distance.reshape(field.shape)
    limit = None
    if depth is not None:
        limit = depth_limit(distance, resolution, depth, nearest=nearest.reshape(field.shape))
        field = within(field, limit, step, rounding=SHELL_ROUNDING_NODES * step)
    if hole_level is None:
        # An open cloud's patches one viewpoint sees apart are one object (a closed cloud's, two objects
        # side by side, stay two); the limit must not cut the bridges.
        field = bridge(field, points, MAX_BRIDGE_GAP, min_support=min_support)
    if limit is not None:
        limit = np.minimum(limit, field)
    # After the bridges: smoothed first, the tips of two patches drew back and one gap grew past
    # MAX_BRIDGE_GAP (cheburashka from 1 view, 0.241 -> 0.256: an ear cut off).
    field, seam = smooth_band_edge(field, near.reshape(field.shape), distance, step, width=BAND_EDGE_BLUR_NODES * step,
                                   reach=BAND_EDGE_REACH_NODES, clearance=BAND_EDGE_CLEARANCE_NODES * step)
    supported, vertices, triangles = mesh_field(field, points, min_support)
    return TargetSurface(supported, vertices, triangles, points, normals, widths,
                         held=(np.sign(supported) != np.sign(field)) | seam, areas=areas, level=level, dense=dense,
                         limit=limit)


def _resample(values, resolution: int) -> np.ndarray:
    """``(r, r, r)`` trilinear interpolation of a cubic grid over ``[-1, 1]^3`` at the nodes of a
    ``resolution^3`` one: one linear pass per axis (``map_coordinates`` at every node took 0.16 s
    for two 64^3 fields at 128^3)."""
    position = np.linspace(0.0, values.shape[0] - 1.0, resolution)
    low = np.minimum(position.astype(np.int64), values.shape[0] - 2)
    weight = position - low
    for axis in range(3):
        shape = [1, 1, 1]
        shape[axis] = resolution
        values = (np.take(values, low, axis=axis) * (1.0 - weight).reshape(shape)
                  + np.take(values, low + 1, axis=axis) * weight.reshape(shape))
    return values


def shell_depths(points, normals, most: float, least: float, *, k: int = CURVATURE_NEIGHBOURS) -> np.ndarray:
    """How deep the solid behind each point of an open scan reaches: the radius of the seen surface's
    mean curvature, between ``least`` and ``most`` (fit-frame units).

    What was not seen is guessed to continue what was: behind a round patch (the front of a limb,
    a head) the object goes on about as deep as the patch is curved; behind a flat or hollow one,
    ``most``. One depth for every point made whatever is smaller than it a blob: an object
    scanned on a table, in a room.

    The curvature is :func:`~voro3d.pointcloud.normals.mean_curvature` over the ``k`` nearest
    neighbours, averaged over them twice, then spread in space (:func:`_spread_depths`): a depth that
    varies smoothly, as a radius does, and never from one point to the next.
    """
    from scipy.spatial import cKDTree

    from ..queries import neighbour_table
    from .normals import mean_curvature

    neighbour = neighbour_table(cKDTree(points), min(k + 1, len(points)))[1][:, 1:]
    curvature = mean_curvature(points, normals, neighbour)
    for _ in range(2):
        curvature = 0.5 * (curvature + curvature[neighbour].mean(axis=1))
    depth = np.clip(1.0 / np.maximum(curvature, 1.0 / most), min(least, most), most)
    return _spread_depths(points, depth, DEPTH_SPREAD * min(least, most))


def _spread_depths(points, depth, width: float) -> np.ndarray:
    """Each point's depth made the least within about ``width`` of it, then averaged with Gaussian
    weights of ``width`` (fit-frame units): a shallow spot stays shallow and the depth varies smoothly.

    Each node of the depth limit reads its nearest point's depth. Along an edge (a plate's rim seen
    from above and around) the curvature, read over neighbourhoods that straddle the edge, gave depths
    that alternated from one point to the next, and the shell's rim came out scalloped, hanging in
    drips. Averaged alone (without the least first), the rims deepened past the seen edge, where the
    far field bulges out (DEPTH_SPREAD's measurements). On a grid of step ``width``: the least per
    cell and its 26 neighbours, then a normalised Gaussian convolution read back trilinearly.
    """
    from scipy import ndimage

    resolution = max(int(np.ceil(2.0 / width)) + 1, 2)
    index = (points + 1.0) * (0.5 * (resolution - 1))
    cell = tuple(np.clip(np.rint(index), 0, resolution - 1).astype(np.int64).T)
    least = np.full((resolution,) * 3, np.inf)
    np.minimum.at(least, cell, depth)
    depth = ndimage.minimum_filter(least, size=3, mode="constant", cval=np.inf)[cell]
    node = np.ravel_multi_index(cell, least.shape)
    sums = [ndimage.gaussian_filter(np.bincount(node, weights=weights, minlength=least.size).reshape(least.shape), 1.0,
                                    mode="constant") for weights in (depth, np.ones_like(depth))]
    total, count = (ndimage.map_coordinates(grid, index.T, order=1, mode="nearest") for grid in sums)
    # Within the depths' own range (a constant stays itself), whatever the rounding.
    return np.clip(total / np.maximum(count, np.finfo(np.float64).tiny), depth.min(), depth.max())
