"""Fields on a grid over the fit frame's ``[-1, 1]^3`` and their closed meshes.

The plumbing the target surfaces of :mod:`~voro3d.pointcloud.surface` share: a signed field on a
grid (:class:`GridSurface`: trilinear values, distance to its mesh), its Marching Cubes mesh
without the pieces the points do not support (:func:`supported_pieces`), and the distance-to-points
field that holds a solid near the points (:func:`depth_limit`, :func:`within`), and the blur where
two fields meet in a jump (:func:`smooth_band_edge`).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["GridSurface", "bridge", "closing", "depth_limit", "limit_reach", "mesh_field", "smooth_band_edge", "smooth_maximum", "supported_pieces", "supported_regions", "within"]

# A piece of surface nearest to fewer points than this share of the best-supported piece's is
# debris: a blob made by stray points or a noisy patch.
SUPPORT_SHARE = 0.01
MIN_SUPPORT = 20
# The radius of a rod that bridges two pieces (bridge), as a share of the gap it spans (a thin rod
# over what was not seen; not ablated: bridges are rare, tuning.MAX_BRIDGE_GAP).
BRIDGE_WIDTH = 0.15


@dataclass
class GridSurface:
    """A signed field on a grid over ``[-1, 1]^3`` (the fit frame) and its Marching Cubes mesh."""

    field: np.ndarray
    vertices: np.ndarray
    triangles: np.ndarray

    @property
    def resolution(self) -> int:
        return self.field.shape[0]

    def _field_at(self, queries: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Trilinear field at (q, 3) fit-frame points, and their grid indices (q, 3)."""
        from scipy.ndimage import map_coordinates

        index = (np.asarray(queries, np.float64) + 1.0) * (0.5 * (self.resolution - 1))
        # Outside the grid is outside: the cval keeps queries beyond [-1, 1]^3 positive.
        return map_coordinates(self.field, index.T, order=1, mode="constant", cval=1.0), index

    def distance(self, queries: np.ndarray) -> np.ndarray:
        """(q, 3) fit-frame points -> (q,) float64 distance to the mesh (Open3D, float32)."""
        import open3d as o3d

        from ..geometry import raycasting_scene

        scene = raycasting_scene(self.vertices, self.triangles)
        return scene.compute_distance(o3d.core.Tensor(np.asarray(queries, np.float32))).numpy().astype(np.float64)


def limit_reach(resolution: int, depth):
    """How far :func:`depth_limit` reads the distance to the points: ``depth`` (one, or each
    point's) and the blur's reach of four nodes, beyond which only the side matters (fit-frame units)."""
    from ..geometry import grid_voxel

    return np.asarray(depth) + 4.0 * grid_voxel(resolution)


def depth_limit(distance, resolution: int, depth, *, nearest=None) -> np.ndarray:
    """Distance to the nearest point (:func:`~voro3d.pointcloud.nodes.node_distance`, reaching at least
    :func:`limit_reach`) minus ``depth``, blurred by a Gaussian of one node so that the union of
    balls does not show on the far side of the shell.

    ``depth`` is one for all points, or each point's (then ``nearest``, from ``node_distance``,
    says whose depth a node reads)."""
    from scipy import ndimage

    depth = np.asarray(depth, np.float64)
    if depth.ndim:
        # Nodes out of every point's reach (nearest == n, distance inf) read the limit's cap whatever
        # the depth: any will do.
        depth = np.append(depth, depth.max())[nearest]
    return ndimage.gaussian_filter(np.minimum(distance, limit_reach(resolution, depth)) - depth, 1.0, mode="nearest")


def _neighbours():
    """Per axis, the slices ``(low, high)`` of a 3D grid whose nodes are neighbours along it."""
    return [tuple(tuple(slice(*ends) if a == axis else slice(None) for a in range(3))
                  for ends in ((None, -1), (1, None))) for axis in range(3)]


def bridge(field, points, max_gap: float, *, min_support: int = MIN_SUPPORT) -> np.ndarray:
    """``field`` with the pieces of its solid that the points support joined across gaps of up to
    ``max_gap``: what a one-sided scan sees apart (a cow's head, body and a leg, seen from behind)
    is one object.

    The pieces are the connected negative regions; a point supports the region of the inside
    corner of its grid cell and, as in :func:`supported_pieces`, a piece with fewer than
    ``min_support`` points or ``SUPPORT_SHARE`` of the best-supported one's is left alone. They
    are joined along the minimum spanning tree of their gaps, each by a round rod between the
    nearest nodes of the two pieces (found with one distance transform: pieces whose nearest-node
    regions touch are neighbours), ``BRIDGE_WIDTH`` times the gap thick and at least three nodes
    in radius, so that the VoroMesh grid (half as fine) keeps it.

    Parameters
    ----------
    field : (r, r, r) float64
        Signed, negative inside, in fit-frame units near its zero set.
    points : (n, 3) float64
        Fit frame.
    max_gap : float
        Fit-frame units; pieces further apart stay apart (separate objects).

    Returns
    -------
    (r, r, r) float64
        ``field`` itself when nothing is joined.
    """
    from scipy import ndimage
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import minimum_spanning_tree

    original = field
    resolution = field.shape[0]
    labels, supported = supported_regions(field < 0, points, min_support=min_support)
    if supported.sum() <= 1:
        return field
    count = len(supported) - 1
    step = 2.0 / (resolution - 1)
    gap, nearest = ndimage.distance_transform_edt(~supported[labels], return_indices=True)
    nearest = np.ravel_multi_index(tuple(nearest), labels.shape)
    owner = labels.ravel()[nearest]
    gap *= step
    # Neighbouring nodes nearest to different pieces: a path between the pieces' nearest nodes.
    ends = []
    for axis, (low, high) in enumerate(_neighbours()):
        index = np.nonzero(owner[low] != owner[high])
        shifted = tuple(k + (a == axis) for a, k in enumerate(index))
        ends.append(np.stack([np.ravel_multi_index(index, labels.shape), np.ravel_multi_index(shifted, labels.shape)], 1))
    ends = np.concatenate(ends)
    if not len(ends):
        return field
    length = gap.ravel()[ends].sum(axis=1) + step
    pair = np.sort(owner.ravel()[ends], axis=1)
    # The shortest path of each pair of pieces: the first of the pair once sorted by length.
    order = np.argsort(length, kind="stable")
    _, first = np.unique(pair[order, 0] * (count + 1) + pair[order, 1], return_index=True)
    best = order[first]
    tree = minimum_spanning_tree(coo_matrix((length[best], tuple(pair[best].T)), shape=(count + 1,) * 2)).tocoo()
    path = dict(zip(map(tuple, pair[best]), best))
    for a, b, span in zip(tree.row, tree.col, tree.data):
        if span > max_gap:
            continue
        k = path[(min(a, b), max(a, b))]
        start, end = (np.array(np.unravel_index(nearest.ravel()[n], labels.shape)) for n in ends[k])
        radius = max(BRIDGE_WIDTH * span, 3.0 * step) / step  # in nodes
        low = np.maximum(np.floor(np.minimum(start, end) - radius - 1).astype(int), 0)
        high = np.minimum(np.ceil(np.maximum(start, end) + radius + 2).astype(int), resolution)
        box = tuple(slice(l, h) for l, h in zip(low, high))
        nodes = np.stack(np.meshgrid(*(np.arange(l, h) for l, h in zip(low, high)), indexing="ij"), -1) - start
        axis = (end - start).astype(np.float64)
        along = np.clip(nodes @ axis / max(float(axis @ axis), 1e-12), 0.0, 1.0)
        rod = (np.linalg.norm(nodes - along[..., None] * axis, axis=-1) - radius) * step
        field = field.copy() if field is original else field
        field[box] = np.minimum(field[box], rod)
    return field


def supported_regions(solid, points, *, min_support: int = MIN_SUPPORT):
    """The connected regions of a solid on a grid over ``[-1, 1]^3`` and which the points support.

    A point supports the region of the inside corner of its grid cell; as in
    :func:`supported_pieces`, a region with fewer than ``min_support`` points or ``SUPPORT_SHARE``
    of the best-supported one's is not supported.

    Parameters
    ----------
    solid : (r, r, r) bool
    points : (n, 3) float64
        Fit frame.

    Returns
    -------
    labels : (r, r, r) int32
        ``scipy.ndimage.label``'s, 0 outside the solid.
    supported : (regions + 1,) bool
        By label; the background's (0) False.
    """
    from scipy import ndimage

    resolution = solid.shape[0]
    labels, count = ndimage.label(solid)
    corner = np.clip(np.floor((points + 1.0) * (0.5 * (resolution - 1))).astype(np.int64), 0, resolution - 2)
    label = np.zeros(len(points), np.int64)
    for offset in np.ndindex(2, 2, 2):
        label = np.maximum(label, labels[tuple((corner + offset).T)])
    support = np.bincount(label, minlength=count + 1)
    support[0] = 0
    return labels, support >= max(min_support, SUPPORT_SHARE * support.max())


def closing(field, offset: float, *, hug: float, half_thickness: float) -> np.ndarray:
    """The solid of an offset shell (``field``: negative within ``offset`` of the points) eroded
    back towards them, to ``hug`` off them where it can (a morphological closing).

    Dilating the points by ``offset`` bridges the gaps between them and joins the two sides of a
    wall thinner than that; the erosion by ``offset - hug`` keeps what was bridged and brings the
    surface back to the points, instead of leaving it ``offset`` out on both sides. Where the
    points are one-sided (a scan of an open sheet) the eroded solid would be ``2 hug`` thin, under
    the grid's reach: there it keeps a half thickness of ``half_thickness``, and where the balls
    barely meet (the ridge under ``offset``) it is eroded by less, so that no gap between the
    points opens into a hole. How thick the solid is at a node is read from the ridge of the
    distance to the shell within reach of it: a one-sided sheet's ridge stands ``offset`` deep, a
    wall's by its half thickness more.

    Parameters
    ----------
    field : (r, r, r) float64
        Signed, negative inside, in fit-frame units near its zero set (over ``[-1, 1]^3``).
    offset, hug, half_thickness : float
        Fit-frame units, ``hug <= half_thickness <= offset``.

    Returns
    -------
    (r, r, r) float64
        The closed solid's field, negative inside, in fit-frame units near its zero set.
    """
    import open3d as o3d
    from scipy import ndimage

    from ..geometry import raycasting_scene

    step = 2.0 / (field.shape[0] - 1)
    shell, faces = _marching_cubes(_outside_at_border(field.astype(np.float32), step))  # a copy: field stays
    inside = field < 0
    # Only nodes within reach of the shell can be eroded: those a cube of that reach around them
    # finds outside (a cube holds the ball).
    reach = int(np.ceil(offset / step)) + 2
    near = inside & ndimage.maximum_filter(~inside, size=2 * reach + 1, mode="nearest")
    depth = np.where(inside, 2.0 * offset, 0.0)  # deeper than any erosion reaches
    nodes = o3d.core.Tensor((np.argwhere(near) * step - 1.0).astype(np.float32))
    depth[near] = raycasting_scene(shell * step - 1.0, faces).compute_distance(nodes).numpy()
    across = int(np.ceil((offset + half_thickness) / step))
    ridge = ndimage.maximum_filter(depth, size=2 * across + 1, mode="nearest")
    keep = np.clip(half_thickness - (ridge - offset), hug, offset)
    return np.where(inside, offset - keep - depth, offset - keep + field)


def _outside_at_border(field, step: float) -> np.ndarray:
    """``field`` with its outermost nodes set outside (in place): a solid that reaches the box is
    closed a node inside it."""
    for axis in range(3):
        ends = [slice(None)] * 3
        ends[axis] = [0, -1]
        field[tuple(ends)] = np.maximum(field[tuple(ends)], step)
    return field


def smooth_maximum(a, b, width: float):
    """``max(a, b)`` with its crease rounded over ``width``: the solids where each is negative,
    intersected, their edge rounded where the two surfaces meet or nearly coincide (a quadratic
    smooth maximum: at most ``width / 4`` over the maximum, equal to it where ``a`` and ``b``
    differ by more than ``width``)."""
    if width <= 0.0:
        return np.maximum(a, b)
    blend = np.maximum(width - np.abs(a - b), 0.0) / width
    return np.maximum(a, b) + 0.25 * width * blend * blend


def smooth_band_edge(field, band, distance, step: float, *, width: float, reach: int, clearance: float):
    """``field`` blurred where the edge of the band it was computed in crosses its zero level.

    Past the rim of a seen patch the IMLS field, extrapolated, reads inside out to the band's edge,
    where the far field reads outside: the zero set follows that edge (a union of balls) and
    Marching Cubes turns the jump between the two fields into crust. There the field is replaced
    by its Gaussian blur of ``width``, on the nodes within ``reach`` nodes of a crossing: the jump
    becomes a slope over a few nodes and the zero set moves by about a node; where that would cut
    the solid in two, the old values stay (:func:`_restore_cuts`).

    Parameters
    ----------
    field : (r, r, r) float64
        Signed, negative inside (changed in place).
    band : (r, r, r) bool
        Nodes whose value is the IMLS field's.
    distance : (r, r, r) float64
        Of each node to its nearest point (inf out of reach).
    step : float
        Grid step (fit-frame units).
    width, clearance : float
        Fit-frame units. Crossings where either node is within ``clearance`` of the points are
        not smoothed, nor are nodes within a step of them: a band thinner than that (sparse
        points) meets the far field at the surface itself, which must stay where the points say.
    reach : int

    Returns
    -------
    field : (r, r, r) float64
    seam : (r, r, r) bool
        The nodes smoothed.
    """
    from scipy import ndimage

    inside = field < 0
    clear = distance > clearance
    crossing = np.zeros(field.shape, bool)
    for low, high in _neighbours():
        pair = (band[low] != band[high]) & (inside[low] != inside[high]) & clear[low] & clear[high]
        crossing[low] |= pair
        crossing[high] |= pair
    if not crossing.any():
        return field, crossing
    seam = ndimage.binary_dilation(crossing, iterations=reach) & (distance > step)
    original = field[seam]
    field[seam] = ndimage.gaussian_filter(field, width / step)[seam]
    _restore_cuts(field, seam, original)
    return field, seam


def _restore_cuts(field, seam, original) -> None:
    """Put ``original`` (the values at ``seam`` before the blur) back, in place, on each connected
    group of nodes the blur turned outside that touches two pieces of the solid: the blur rounds a
    rim, but a neck only the band held (an object where it stands on a table seen from above) stays."""
    from scipy import ndimage

    opened = np.zeros(field.shape, bool)
    opened[seam] = (original < 0) & (field[seam] >= 0)
    if not opened.any():
        return
    pieces, _ = ndimage.label(field < 0)
    groups, count = ndimage.label(opened)
    touching = []
    for low, high in _neighbours():
        for group, piece in ((groups[low], pieces[high]), (groups[high], pieces[low])):
            hit = (group > 0) & (piece > 0)
            touching.append(np.stack([group[hit], piece[hit]], axis=1))
    touching = np.unique(np.concatenate(touching), axis=0)
    cuts = np.flatnonzero(np.bincount(touching[:, 0], minlength=count + 1) >= 2)
    if cuts.size:
        values = field[seam]
        back = np.isin(groups[seam], cuts)
        values[back] = original[back]
        field[seam] = values


def within(field, limit, step: float, *, rounding: float = 0.0) -> np.ndarray:
    """``field``'s solid cut to where ``limit`` is negative (the crease rounded over ``rounding``,
    :func:`smooth_maximum`), with the cavities this leaves (outside regions that do not reach the
    grid's border: the inside of a closed part) filled; ``limit`` is set inside there too (in
    place), so that it never cuts a filled cavity."""
    from scipy import ndimage

    field = smooth_maximum(field, limit, rounding)
    outside, _ = ndimage.label(field >= 0)
    open_space = np.unique(np.concatenate([np.ravel(np.take(outside, [0, -1], axis=a)) for a in range(3)]))
    cavity = (outside > 0) & ~np.isin(outside, open_space)
    field[cavity] = -step
    limit[cavity] = -step
    return field


def supported_pieces(vertices, triangles, points, *, min_support: int = MIN_SUPPORT):
    """Which connected pieces of a mesh the points support.

    Each piece is supported by the points nearer to one of its vertices than to any other
    piece's. A piece with fewer than ``min_support`` of them, or fewer than ``SUPPORT_SHARE`` of
    the best-supported piece's, is debris (the blob that stray points or a noisy patch make);
    the best-supported piece is always kept, and a cloud of several real objects keeps them all.

    Parameters
    ----------
    vertices : (v, 3) float64
    triangles : (t, 3) int64
    points : (n, 3) float64
        In the vertices' coordinates.
    min_support : int

    Returns
    -------
    piece : (v,) int
        Piece of each vertex.
    kept : (pieces,) bool
    """
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components
    from scipy.spatial import cKDTree

    n = vertices.shape[0]
    edges = triangles[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2)
    pieces, piece = connected_components(coo_matrix((np.ones(len(edges)), (edges[:, 0], edges[:, 1])), shape=(n, n)),
                                         directed=False)
    if pieces <= 1:
        return piece, np.ones(pieces, bool)
    _, nearest = cKDTree(vertices).query(points, workers=-1)
    support = np.bincount(piece[nearest], minlength=pieces)
    kept = support >= max(min_support, SUPPORT_SHARE * support.max())
    kept[np.argmax(support)] = True
    return piece, kept


def mesh_field(field, points, min_support):
    """The closed mesh of a target field, without the pieces the points do not support.

    The outermost nodes are set outside (in place): a solid that reaches the box (behind a
    one-sided scan) is closed a node inside it, where the fit's generators (kept in the box) can
    straddle it. Then Marching Cubes, and :func:`_drop_unsupported`.

    Returns
    -------
    supported : (r, r, r) float64
        ``field``, or a copy with the unsupported pieces' regions flipped.
    vertices : (v, 3) float64
        Fit frame.
    triangles : (t, 3) int64
    """
    step = 2.0 / (field.shape[0] - 1)
    vertices, triangles = _marching_cubes(_outside_at_border(field, step).astype(np.float32))
    supported = _drop_unsupported(field, vertices, triangles, points, min_support)
    if supported is not field:
        vertices, triangles = _marching_cubes(supported.astype(np.float32))
    return supported, vertices * step - 1.0, triangles


def _drop_unsupported(field, vertices, triangles, points, min_support):
    """The field with unsupported pieces of surface removed (``field`` itself when none is).

    ``vertices, triangles`` are the Marching Cubes mesh of ``field`` in grid-index coordinates.

    The connected pieces of the zero set (Marching Cubes) that the points do not support
    (:func:`supported_pieces`) are debris: the solid region such a piece encloses is flipped to
    outside (or the cavity to inside) unless a kept piece also bounds it.
    """
    from scipy import ndimage

    piece, kept = supported_pieces(vertices, triangles, (points + 1.0) * (0.5 * (field.shape[0] - 1)),
                                   min_support=min_support)
    if kept.all():
        return field
    # A Marching Cubes vertex lies on a grid edge; the edge's two nodes are the regions it bounds.
    ends = np.stack([np.floor(vertices), np.ceil(vertices)], axis=1).astype(np.int64)
    ends = np.minimum(ends, field.shape[0] - 1)
    kept_vertex = np.repeat(kept[piece], 2)
    nodes = tuple(ends.reshape(-1, 3).T)
    for inside in (True, False):
        labels, count = ndimage.label(field < 0 if inside else field >= 0)
        touched = labels[nodes]
        keep = np.zeros(count + 1, bool)
        keep[touched[kept_vertex]] = True
        if not inside:  # the outside reaching the border of the grid always stays
            keep[labels[0, 0, 0]] = True
        keep[0] = True
        flip = ~keep[labels]
        field = np.where(flip, -field, field)
        if not inside:
            field[flip & (field == 0)] = -1e-6
    return field


def _marching_cubes(field):
    """Closed, outward Marching Cubes mesh of the zero set, in grid-index coordinates (the
    outermost nodes are outside, so the surface closes)."""
    from skimage.measure import marching_cubes

    vertices, triangles, _, _ = marching_cubes(field, level=0.0)
    triangles = triangles.astype(np.int64)
    # skimage orients faces towards increasing values (outward here) by the gradient; check.
    a, b, c = (vertices[triangles[:, i]] for i in range(3))
    if np.einsum("ij,ij->i", a, np.cross(b, c)).sum() < 0:
        triangles = triangles[:, ::-1]
    return vertices.astype(np.float64), np.ascontiguousarray(triangles)
