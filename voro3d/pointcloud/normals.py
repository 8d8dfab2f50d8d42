"""Normals of a point cloud: local plane fits, oriented consistently and outward; repairs."""
from __future__ import annotations

import numpy as np

from ..rowblocks import map_rows
from .preprocess import NOISE_NEIGHBOURS, SPACING_NEIGHBOURS, plane_normals, wall_points
from .tuning import MAX_TIE_WEIGHT, SIGN_SAMPLE, UNDECIDED_SIGMAS

__all__ = ["estimate_normals", "mean_curvature", "orient_normals", "sign_disagreement", "repair_normals", "unusable_normals"]

# Neighbours for normal estimation and orientation.
NEIGHBOURS = 16
# Share of unusable (zero-length, NaN) given normals that is repaired from the neighbours; beyond it
# the reconstruction estimates its own instead (repair_normals refuses them). Set where repaired
# normals stop beating our own estimate: bunny, fandisk, armadillo at 20k points with their true
# normals, a share made NaN at random, grid 64, CD clean / 0.5% noise (2026-12-05): none 0.620 /
# 1.030, 0.710 / 1.082, 0.527 / 1.175; 5% 0.623 / 1.026, 0.714 / 1.089, 0.528 / 1.184; 20% 0.624 /
# 1.049, 0.718 / 1.110, 0.538 / 1.216; 50% 0.638 / 1.091, 0.749 / 1.184, 0.570 / 1.283; our estimate
# 0.639 / 1.231, 0.742 / 1.292, 0.570 / 1.492 (NC alike: at 50% within 0.0018 of intact normals). It
# was 1%, unmeasured.
REPAIRABLE_SHARE = 0.5
# Graph edges whose weights are computed at a time: their (block, 3) float64 temporaries, not the
# whole graph's (16 edges a point), are alive.
EDGE_BLOCK = 2**20
# Clouds of more points are oriented on an evenly spread subset of about this many, each other point
# then signed like the nearest of its CARRY_CANDIDATES nearest subset points whose plane passes
# nearest it (the one on its own side of a thin wall). 10^6 points of 7 dev meshes (2026-12-07,
# Open3D's plane fits, wrongly signed against the true normals, all points / this): bunny, armadillo,
# fandisk, the cup abc_00000009 0 / 0; the lid abc_00000007 0 / 0.03%, thingi32_252119 0.05% / 0.15%,
# camel_b 0.07% / 0.08%; the orientation 15-17 s -> 3.1-5.2 s. 8 candidates: the same within 0.004%, 1-2 s
# more; the nearest subset point alone: a slab 5 spacings thick 0.06% -> 1.1% (the test beside it).
ORIENT_POINTS = 250_000
CARRY_CANDIDATES = 4


def unusable_normals(normals: np.ndarray) -> np.ndarray:
    """(n,) bool: the normals of zero length, NaN or inf, which :func:`repair_normals` replaces."""
    length = np.linalg.norm(np.asarray(normals, np.float64), axis=1)
    return ~np.isfinite(length) | (length < 1e-12)


def repair_normals(points: np.ndarray, normals: np.ndarray) -> np.ndarray:
    """Unit normals with the unusable ones (zero-length, NaN, inf) taken from their neighbours.

    Scanners write a zero normal where they could not fit one; such a point gets the mean of
    the usable normals of its ``NEIGHBOURS`` nearest points that point the way its nearest one
    does: across a wall thinner than their reach the two sides' normals are opposite, and their
    plain mean cancelled (the cup abc_00000009 and the lid abc_00000007 at 3k points, 2% zero).

    Parameters
    ----------
    points : (n, 3) float64
    normals : (n, 3) float

    Returns
    -------
    (n, 3) float64
        Unit length.

    Raises
    ------
    ValueError
        More than ``REPAIRABLE_SHARE`` of the normals are unusable.
    """
    from scipy.spatial import cKDTree

    normals = np.asarray(normals, np.float64)
    length = np.linalg.norm(normals, axis=1)
    bad = unusable_normals(normals)
    if bad.mean() > REPAIRABLE_SHARE:
        raise ValueError(f"{int(bad.sum())} of {len(normals)} normals are zero, NaN or inf: the cloud's normals "
                         "are not usable (drop them to have normals estimated)")
    unit = np.where(bad[:, None], 0.0, normals / np.where(bad, 1.0, length)[:, None])
    if bad.any():
        good = np.flatnonzero(~bad)
        _, neighbour = cKDTree(points[good]).query(points[bad], k=min(NEIGHBOURS, good.size), workers=-1)
        near = unit[good][neighbour.reshape(bad.sum(), -1)]
        # The nearest one's side only: a sum of vectors within 90 degrees of it, never zero.
        same = np.einsum("bkd,bd->bk", near, near[:, 0]) > 0
        mean = np.einsum("bkd,bk->bd", near, same.astype(np.float64))
        unit[bad] = mean / np.linalg.norm(mean, axis=1)[:, None]
    return unit


def estimate_normals(points: np.ndarray, *, k: int = NEIGHBOURS, graph_k: int | None = None,
                     walls: np.ndarray | None = None, neighbours=None) -> np.ndarray:
    """Unit normals from local PCA (Open3D's plane fits over ``k`` neighbours), oriented
    consistently and outward by :func:`orient_normals`.

    Parameters
    ----------
    points : (n, 3) float64
    k : int
        Neighbours for the plane fits.
    graph_k : int, optional
        Neighbours joined in the orientation graph, at most ``k``; default ``k``. Fewer than the
        plane fits keep the graph on one side of walls thinner than a plane fit's reach.
    walls : (n,) bool, optional
        The points whose plane fit spans both sides of a thin wall
        (:func:`~voro3d.pointcloud.preprocess.wall_points`, found here when not given): their
        axis is the plane of their ``SPACING_NEIGHBOURS`` nearest (bench_thin_walls: the cup
        abc_00000009 at 20k points, 27.8 -> 1.2 degrees off the true normals).
    neighbours : (distance, neighbour), optional
        A :func:`~voro3d.queries.neighbour_table` of ``points`` to reuse, when it has the columns
        needed (``k + 1``, and ``NOISE_NEIGHBOURS + 1`` without ``walls``); queried otherwise.

    Returns
    -------
    (n, 3) float64

    Raises
    ------
    ValueError
        When the plane fits give no usable normals (degenerate neighbourhoods).
    """
    import open3d as o3d
    from scipy.spatial import cKDTree

    from ..queries import neighbour_table

    n = points.shape[0]
    k = min(k, n - 1)
    # The wall test reads wider neighbourhoods than the plane fits: one query serves both.
    columns = k + 1 if walls is not None else min(max(k, NOISE_NEIGHBOURS), n - 1) + 1
    if neighbours is not None and neighbours[0].shape[0] == n and neighbours[0].shape[1] >= columns:
        distances, neighbours = (table[:, :columns] for table in neighbours)
    else:
        distances, neighbours = neighbour_table(cKDTree(points), columns)
    extent = np.linalg.norm(points.max(axis=0) - points.min(axis=0))
    stacked = int((distances[:, k] <= 1e-9 * extent).sum())
    if stacked > 0.01 * n:
        raise ValueError(f"normals cannot be estimated: {stacked} of {n} points have all {k} neighbours at "
                         "their own position (duplicated points), so no plane fits them")
    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points))
    cloud.estimate_normals(o3d.geometry.KDTreeSearchParamKNN(k))
    normals = np.asarray(cloud.normals).copy()
    if not np.isfinite(normals).all() or (np.linalg.norm(normals, axis=1) < 0.5).mean() > 0.01:
        raise ValueError("normals could not be estimated (degenerate neighbourhoods)")
    across = np.flatnonzero(wall_points(points, neighbours) if walls is None else walls)
    distances, neighbours = distances[:, :k + 1], neighbours[:, :k + 1]
    if across.size:
        normals[across] = map_rows(lambda rows: plane_normals(points[rows]), neighbours[across, :min(SPACING_NEIGHBOURS, k) + 1])
    graph_k = k if graph_k is None else min(graph_k, k)
    return orient_normals(points, normals, neighbours=(distances[:, :graph_k + 1], neighbours[:, :graph_k + 1]))


def sign_disagreement(points: np.ndarray, normals: np.ndarray, *, tree=None, k: int = NEIGHBOURS,
                      sample: int | None = SIGN_SAMPLE) -> float:
    """Share of neighbouring points on one sheet whose normals point opposite ways.

    Pairs among the ``k`` nearest neighbours count when their normals are nearly parallel
    (``|n_i . n_j| > 0.9``) and the step between them lies in both tangent planes (under 0.3 of
    its length along either normal), so a neighbour across a sharp edge or a thin wall does not.
    Consistent normals read about 0, signs drawn at random 0.5 (see :data:`MAX_SIGN_DISAGREEMENT`).

    Parameters
    ----------
    points, normals : (n, 3) float64
        ``normals`` unit length.
    sample : int or None
        The pairs of up to this many random points count (None: all; ``SIGN_SAMPLE``, where it is measured).

    Returns
    -------
    float
        In [0, 1]; 0 when no pair counts.
    """
    from scipy.spatial import cKDTree

    from ..queries import knn_blocks

    tree = cKDTree(points) if tree is None else tree
    n = points.shape[0]
    sheet_pairs = opposite = 0
    for block, _, neighbours in knn_blocks(tree, min(k, n - 1) + 1, sample=sample):
        rows = np.repeat(block, neighbours.shape[1] - 1)
        cols = neighbours[:, 1:].reshape(-1)
        keep = cols < n
        rows, cols = rows[keep], cols[keep]
        step = points[cols] - points[rows]
        step /= np.maximum(np.linalg.norm(step, axis=1), 1e-300)[:, None]
        dot = np.einsum("ij,ij->i", normals[rows], normals[cols])
        sheet = ((np.abs(dot) > 0.9) & (np.abs(np.einsum("ij,ij->i", step, normals[rows])) < 0.3)
                 & (np.abs(np.einsum("ij,ij->i", step, normals[cols])) < 0.3))
        sheet_pairs += int(sheet.sum())
        opposite += int((dot[sheet] < 0).sum())
    return opposite / sheet_pairs if sheet_pairs else 0.0


def orient_normals(points: np.ndarray, normals: np.ndarray, *, neighbours=None, k: int = NEIGHBOURS) -> np.ndarray:
    """Signs of unit normal axes made consistent between neighbours and outward.

    As in Hoppe et al. (1992): over the k-nearest-neighbour graph weighted by
    ``1 - |n_i . n_j| + |d . n_i| + |d . n_j|`` (``d`` the unit edge direction), a minimum
    spanning tree (scipy) carries each point's sign to its neighbours along the flattest
    paths that stay on one side of thin walls. That is Open3D's
    ``orient_normals_consistent_tangent_plane`` in spirit, but vectorised: about 2 s instead of
    10 s to 9 minutes for 10^5 points here. The tree is then cut into smooth patches (where
    normals turn or an edge leaves the tangent plane), joined again into parts that each point
    outward on balance: a surface bends away from its outside, closed or open, so a part whose
    :func:`mean_curvature` sums negative is flipped; a flat part faces the rest of the cloud
    (:func:`_part_flips`: an object and the table it stands on are decided apart). Finally a
    patch flips when its points clearly see open space behind them and enclosed space in front
    (:func:`_outside_votes`): a flat face that the tree reached across a sharp edge with the
    wrong sign (the base of a bust) is caught there.

    Parameters
    ----------
    points : (n, 3) float64
    normals : (n, 3) float64
        Unit axes; their signs are ignored.
    neighbours : tuple of ((n, j) float64, (n, j) int), optional
        The graph: distances to and indices of each point's ``j - 1`` nearest neighbours, itself
        first (a cKDTree query); default the ``k`` nearest. Over ``ORIENT_POINTS`` points the
        orientation runs on a subset, over ``j - 1`` neighbours of its own, and the rest follow it.

    Returns
    -------
    (n, 3) float64
    """
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components, minimum_spanning_tree
    from scipy.spatial import cKDTree

    from ..queries import neighbour_table

    n = points.shape[0]
    if n > ORIENT_POINTS:
        return _oriented_from_subset(points, normals, k if neighbours is None else neighbours[1].shape[1] - 1)
    if neighbours is None:
        neighbours = neighbour_table(cKDTree(points), min(k, n - 1) + 1)
    distances, neighbours = neighbours
    graph_k = neighbours.shape[1] - 1
    normals = np.array(normals, np.float64)
    rows = np.repeat(np.arange(n, dtype=np.int32), graph_k)
    cols = neighbours[:, 1:].reshape(-1)
    keep = cols < n  # duplicate points can leave a row short
    rows, cols = rows[keep], cols[keep]
    weights = np.empty(len(rows))
    for start in range(0, len(rows), EDGE_BLOCK):
        weights[start:start + EDGE_BLOCK] = _edge_weights(points, normals, rows[start:start + EDGE_BLOCK],
                                                         cols[start:start + EDGE_BLOCK])
    tree = minimum_spanning_tree(coo_matrix((weights, (rows, cols)), shape=(n, n)).tocsr()).tocoo()
    agree = np.einsum("ij,ij->i", normals[tree.row], normals[tree.col]) >= 0
    normals *= _forest_signs(n, tree.row, tree.col, agree)[:, None]
    # Smooth patches: the tree cut where normals turn or an edge leaves the tangent plane.
    step = points[tree.col] - points[tree.row]
    step /= np.maximum(np.linalg.norm(step, axis=1), 1e-300)[:, None]
    smooth = ((np.einsum("ij,ij->i", normals[tree.row], normals[tree.col]) > 0.95)
              & (np.abs(np.einsum("ij,ij->i", step, normals[tree.row])) < 0.3)
              & (np.abs(np.einsum("ij,ij->i", step, normals[tree.col])) < 0.3))
    patches, patch = connected_components(coo_matrix((np.ones(int(smooth.sum())), (tree.row[smooth], tree.col[smooth])),
                                                     shape=(n, n)), directed=False)
    # Each part outward by its bending (mean curvature, not the volume about the centroid, which
    # turned a table down under the object on it), the object and its table decided apart.
    tie = weights < MAX_TIE_WEIGHT
    flip = _part_flips(points, normals, mean_curvature(points, normals, neighbours[:, 1:]) * distances[:, graph_k],
                       patch, patches, rows[tie], cols[tie])
    normals[flip[patch]] *= -1.0
    # A sharp edge or a wall thinner than the plane fits can still flip a whole face: each smooth
    # patch votes on which side of it is open space.
    vote = _outside_votes(points, normals, float(np.median(distances[:, graph_k])))
    _flip_patches(normals, vote, patch)
    # A patch can still reach across a thin wedge (the base of a bust meeting its chest at a
    # shallow angle) and carry a wrong face in with a right one: the points no probe calls right
    # are grouped again along the same smooth edges, and such a group votes on its own.
    # On the 38 dev meshes (30k / 5k clean points, 20k at 0.5% noise) wrongly signed normals went
    # from 2.71% / 5.88% / 3.43% to 1.70% / 5.55% / 3.39% on average: the bust thingi32_75655
    # 20.2% -> 1.5%, thingi32_75656 21.1% -> 0.7%, at most +1.9 points elsewhere (abc_00000006
    # noisy); grouping the points that vote against only (not the undecided) gained less (1.73% /
    # 5.66% / 3.32%).
    doubtful = vote <= 0
    inner = smooth & doubtful[tree.row] & doubtful[tree.col]
    groups, group = connected_components(coo_matrix((np.ones(int(inner.sum())), (tree.row[inner], tree.col[inner])),
                                                    shape=(n, n)), directed=False)
    _flip_patches(normals, vote, np.where(doubtful, group, groups))  # the rest, all +1, never flips
    return normals


def _part_flips(points, normals, bending, patch, patches: int, rows, cols) -> np.ndarray:
    """Which smooth patches to flip so that each part of the surface points outward.

    Patches are joined into parts along their ties (Borůvka's rounds: each part takes its strongest
    tie, then the ties are summed again between the joined parts). The tie between two parts is the
    sum of ``n_i . n_j`` over the graph edges ``rows -> cols`` between them: whether they agree as
    they are (> 0) or one is flipped (< 0). A tie that would make two parts disagree with what their
    own bending says is refused while it is weaker than both (an object and the table it stands on
    meet in a few edges whose plane fits mix both surfaces; a cup's inside meets its outside along
    the whole rim). A part then points outward when its bending sums positive; one whose sum is
    within ``UNDECIDED_SIGMAS`` of its spread (flat, or noise) and that is not the whole cloud faces
    the rest of the points instead (a table with its edge out of view faces what stands on it).

    Parameters
    ----------
    points, normals : (n, 3) float64
        Normals consistent along the orientation tree.
    bending : (n,) float64
        Mean curvature times local spacing: the outward evidence of each point.
    patch : (n,) int
        Each point's smooth patch, of ``patches``.
    rows, cols : (e,) int
        The graph edges that may tie patches (edges across thin walls left out).

    Returns
    -------
    (patches,) bool
    """
    n = points.shape[0]
    across = patch[rows] != patch[cols]
    first, second = patch[rows[across]], patch[cols[across]]
    vote = np.einsum("ij,ij->i", normals[rows[across]], normals[cols[across]])
    part = np.arange(patches)  # each patch's part (a patch's index) and its sign relative to it
    sign = np.ones(patches)
    total = np.bincount(patch, weights=bending, minlength=patches)
    spread = np.bincount(patch, weights=bending**2, minlength=patches)
    while True:
        a, b = part[first], part[second]
        keep = a != b
        first, second, vote, a, b = first[keep], second[keep], vote[keep], a[keep], b[keep]
        if not a.size:
            break
        keys, inverse = np.unique(np.minimum(a, b).astype(np.int64) * patches + np.maximum(a, b), return_inverse=True)
        ties = np.bincount(inverse, weights=vote * sign[first] * sign[second], minlength=len(keys))
        p, q = keys // patches, keys % patches
        disagree = (total[p] > 0) != (np.where(ties < 0, -total[q], total[q]) > 0)
        candidates = np.flatnonzero(~(disagree & (np.abs(ties) < np.minimum(np.abs(total[p]), np.abs(total[q])))))
        if not candidates.size:
            break
        # Each part's strongest tie, in one order for all (strength, then key): the picks form a forest.
        order = candidates[np.lexsort((keys[candidates], -np.abs(ties[candidates])))]
        _, picks = np.unique(np.c_[p[order], q[order]].ravel(), return_index=True)
        picked = np.unique(order[picks // 2])
        relative, root = _forest_signs(patches, p[picked], q[picked], ties[picked] >= 0, roots=True)
        parts = np.unique(part)
        total = np.bincount(root[parts], weights=relative[parts] * total[parts], minlength=patches)
        spread = np.bincount(root[parts], weights=spread[parts], minlength=patches)
        sign *= relative[part]
        part = root[part]
    decision = total
    size = np.bincount(part[patch], minlength=patches)  # of each part, under its root patch
    undecided = (np.abs(total) <= UNDECIDED_SIGMAS * np.sqrt(spread)) & (size < n) & (size > 0)
    if undecided.any():
        own = part[patch]
        sums = np.stack([np.bincount(own, weights=points[:, axis], minlength=patches) for axis in range(3)], axis=1)
        rest = (points.sum(axis=0) - sums) / np.maximum(n - size, 1)[:, None]
        facing = np.bincount(own, weights=np.einsum("ij,ij->i", normals * sign[patch, None], rest[own] - points),
                             minlength=patches)
        decision = np.where(undecided, facing, total)
    return sign * np.where(decision[part] < 0, -1.0, 1.0) < 0


def _forest_signs(count: int, rows, cols, agree, *, roots: bool = False):
    """Signs (+1 / -1) of the ``count`` nodes of a forest, each relative to the first node of its tree.

    ``rows -> cols`` are the forest's edges (each once), ``agree`` whether their ends keep the same
    sign. With ``roots``, also each node's tree as that first node's index.
    """
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import breadth_first_order, connected_components

    pieces, piece = connected_components(coo_matrix((np.ones(len(rows)), (rows, cols)), shape=(count, count)),
                                         directed=False)
    firsts = np.unique(piece, return_index=True)[1]
    # One breadth-first pass over the whole forest: a virtual node joined to each tree's first node.
    joined = coo_matrix((np.ones(len(rows) + pieces), (np.r_[rows, np.full(pieces, count)], np.r_[cols, firsts])),
                        shape=(count + 1, count + 1))
    _, parent = breadth_first_order(joined.tocsr(), count, directed=False)
    parent[count] = count
    parent[firsts] = count
    # sign[i] = flip[i] * sign[parent[i]], resolved by pointer jumping: log(depth) vectorised rounds.
    inner = np.flatnonzero(parent[:count] != count)
    key = np.minimum(rows, cols).astype(np.int64) * count + np.maximum(rows, cols)
    order = np.argsort(key)
    wanted = np.minimum(inner, parent[inner]).astype(np.int64) * count + np.maximum(inner, parent[inner])
    sign = np.ones(count + 1)
    sign[inner] = np.where(np.asarray(agree)[order][np.searchsorted(key[order], wanted)], 1.0, -1.0)
    ancestor = parent.copy()
    while (ancestor != count).any():
        sign, ancestor = sign * sign[ancestor], ancestor[ancestor]
    return (sign[:count], firsts[piece]) if roots else sign[:count]


def mean_curvature(points: np.ndarray, normals: np.ndarray, neighbours: np.ndarray) -> np.ndarray:
    """Signed mean curvature of an oriented sampled surface at each point.

    The median over the point's neighbours ``j`` of ``(n_j - n_i) . (p_j - p_i) / |p_j - p_i|^2``:
    1/R on a sphere of radius R with outward normals, -1/R with inward ones, 0 on a plane, about the
    mean of the principal curvatures elsewhere (the median keeps a neighbour across a crease or a
    thin wall from deciding it).

    Parameters
    ----------
    points, normals : (n, 3) float64
        Unit normals, signs consistent between neighbours.
    neighbours : (n, k) int
        Each point's neighbours, itself excluded; an index ``n`` (a row cut short) counts as none.

    Returns
    -------
    (n,) float64
        In inverse units of ``points``.
    """
    n = points.shape[0]

    def curvature(rows):
        near = neighbours[rows]
        near = np.where(near < n, near, rows[:, None])  # a missing neighbour: itself, a zero step
        step = points[near] - points[rows, None, :]
        turn = np.einsum("ijk,ijk->ij", normals[near] - normals[rows, None, :], step)
        return np.median(turn / np.maximum(np.einsum("ijk,ijk->ij", step, step), 1e-300), axis=1)

    return map_rows(curvature, np.arange(n))


def _oriented_from_subset(points, normals, k: int) -> np.ndarray:
    """:func:`orient_normals` of every ``-(-n // ORIENT_POINTS)``-th point (over ``k`` neighbours), each
    other point's axis signed like the nearest of its ``CARRY_CANDIDATES`` nearest subset points whose
    tangent plane passes nearest it."""
    from scipy.spatial import cKDTree

    from ..queries import neighbour_table

    n = points.shape[0]
    chosen = np.arange(0, n, -(-n // ORIENT_POINTS))
    subset = points[chosen]
    tree = cKDTree(subset)  # one tree for the subset's graph and for the rest's nearest subset points
    oriented = orient_normals(subset, normals[chosen], neighbours=neighbour_table(tree, min(k, len(chosen) - 1) + 1))
    _, near = tree.query(points, k=CARRY_CANDIDATES, workers=-1)
    candidates = oriented[near]
    plane = np.abs(np.einsum("ijk,ijk->ij", points[:, None, :] - subset[near], candidates))
    guide = candidates[np.arange(n), plane.argmin(axis=1)]
    result = np.array(normals, np.float64)
    result *= np.where(np.einsum("ij,ij->i", result, guide) < 0, -1.0, 1.0)[:, None]
    result[chosen] = oriented
    return result


def _edge_weights(points, normals, rows, cols):
    """Hoppe's weights of the graph edges ``rows -> cols``.

    Edges along the surface are cheap, so the tree never steps across a thin wall (whose two
    sides share one plane fit and would get the same sign): an edge pays for turning normals
    and for running along them. A zero weight would read as "no edge" to scipy: hence 1e-9.
    """
    direction = points[cols] - points[rows]
    direction /= np.maximum(np.linalg.norm(direction, axis=1), 1e-300)[:, None]
    return (1.0 - np.abs(np.einsum("ij,ij->i", normals[rows], normals[cols])) + 1e-9
            + np.abs(np.einsum("ij,ij->i", direction, normals[rows]))
            + np.abs(np.einsum("ij,ij->i", direction, normals[cols])))


def _flip_patches(normals, vote, patch) -> None:
    """Flips, in place, the normals and votes of each patch whose points clearly vote that they point inward."""
    count = np.bincount(patch)
    # Only a clear verdict flips: near thin walls most probes cannot tell, and a few can mislead.
    flip = (np.bincount(patch, weights=vote, minlength=len(count)) < -0.25 * count)[patch]
    normals[flip] *= -1.0
    vote[flip] *= -1.0


def _outside_votes(points, normals, voxel):
    """+1 where a point's normal points to open space and its back to enclosed space, -1 the other
    way round, 0 when that cannot be told (both sides open: a thin wall, or a cloud with holes).

    Open space is the empty voxels connected to the border of the grid, with the voxels holding
    points grown by one so that the sampled surface has no gaps: ``voxel`` about the distance to
    the 16th neighbour, so that a surface voxel holds about five points. Each point probes three
    voxels along its normal, both ways.
    """
    from scipy import ndimage

    low = points.min(axis=0)
    extent = points.max(axis=0) - low
    voxel = max(voxel, float(extent.max()) / 256)
    if voxel <= 0:
        return np.zeros(points.shape[0])
    shape = np.ceil(extent / voxel).astype(int) + 9  # room for the probes beyond the cloud
    occupied = np.zeros(shape, bool)
    occupied[tuple(np.floor((points - low) / voxel).astype(int).T + 4)] = True
    occupied = ndimage.binary_dilation(occupied, iterations=1)
    labels, _ = ndimage.label(~occupied)
    border = np.unique(np.concatenate([labels[[0, -1]].ravel(), labels[:, [0, -1]].ravel(),
                                       labels[..., [0, -1]].ravel()]))
    open_space = np.isin(labels, border[border > 0])

    def is_open(queries):
        cells = np.clip(np.floor((queries - low) / voxel).astype(int) + 4, 0, np.array(shape) - 1)
        return open_space[tuple(cells.T)]

    return is_open(points + 3 * voxel * normals).astype(float) - is_open(points - 3 * voxel * normals)
