"""What a raw cloud needs before a surface is fitted to it: outliers out, scale and noise measured."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..rowblocks import map_rows
from .tuning import (CHECK_POINTS, SPARSE_SPACINGS, STATISTICS_SAMPLE, STRAY_RATIO, SUSPECT_FLATNESS, SUSPECT_OFFSET,
                     TWO_SHEET_CLEARANCE, TWO_SHEET_POINTS, WALL_VOTE)

__all__ = ["CloudStats", "check_stride", "cloud_stats", "stride", "outlier_mask", "outlier_neighbours", "local_dimension", "fill_ratio", "merge_duplicates",
           "group_means", "separate_objects", "plane_normals", "two_sheets", "wall_points"]

# Neighbours of the spacing and noise estimates.
SPACING_NEIGHBOURS = 8
NOISE_NEIGHBOURS = 24
# Neighbours whose own wall test a point's must share (wall_points): those of estimate_normals' plane fits.
WALL_VOTERS = 16
STRAY_NEIGHBOURS = 20


def stride(count: int, at_most: int) -> int:
    """k such that every k-th of ``count`` points is at most ``at_most`` points."""
    return max(1, -(-count // at_most))


def check_stride(count: int) -> int:
    """k such that every k-th of ``count`` points, at most ``CHECK_POINTS`` of them, stand for all
    in a check of the surface against the points (a mean, a median, a share)."""
    return stride(count, CHECK_POINTS)


def merge_duplicates(points: np.ndarray, *attributes):
    """Points at the same position merged into one, their attributes averaged.

    Merged scans and resampled clouds repeat points exactly; a repeated point looks like a
    point with no neighbours around it (its nearest ones are itself), which the spacing, the
    outlier tests and the plane fits cannot use.

    Parameters
    ----------
    points : (n, 3) float64
    *attributes : (n, c) float64 or None
        Normals, colours: averaged over each point's copies. Normals are not renormalised here:
        :func:`~voro3d.pointcloud.normals.repair_normals` does that, and copies that cancel come
        back zero for it to repair.

    Returns
    -------
    points : (m, 3) float64
        The distinct positions, in the order they first appear.
    *attributes : (m, c) float64 or None
    """
    # Copies share a hash of their coordinates' bits (+ 0.0: -0 and 0 alike): where no two points do
    # (most clouds), a sort of one column of hashes tells there is nothing to merge, 20x faster than
    # the row-wise unique (1M points: 0.14 s against 2.9 s); a sort of x alone did not on CAD clouds,
    # whose faces share coordinates (10^5 fandisk points: 0.007 s against 0.12 s).
    bits = (points + 0.0).view(np.uint64)
    key = np.sort(bits[:, 0] ^ (bits[:, 1] * np.uint64(0x9E3779B97F4A7C15)) ^ (bits[:, 2] * np.uint64(0xC2B2AE3D27D4EB4F)))
    if not (key[1:] == key[:-1]).any():
        return (points, *attributes)
    unique, first, index = np.unique(points, axis=0, return_index=True, return_inverse=True)
    if len(unique) == len(points):
        return (points, *attributes)
    order = np.argsort(first)
    rank = np.empty_like(order)
    rank[order] = np.arange(len(order))
    index = rank[index.reshape(-1)]
    return (unique[order], *group_means(index, *attributes))


def group_means(group: np.ndarray, *values) -> list:
    """The mean of each of ``values`` ((n, c) float64 or None) over the points of each ``group`` ((n,) int, 0 to m - 1)."""
    count = np.bincount(group)
    return [None if column_values is None else
            np.stack([np.bincount(group, weights=column) for column in column_values.T], axis=1) / count[:, None]
            for column_values in values]


def separate_objects(points: np.ndarray, *, min_points: int, margin: float = 0.5) -> list[np.ndarray]:
    """Groups of points far enough apart to be reconstructed one by one.

    The points' neighbour graph (:func:`_pieces`) splits into connected pieces; pieces whose
    bounding boxes, each grown by ``margin`` of its own diagonal, overlap are joined. One grid
    over objects far apart spends most of its voxels on the empty space between them (two unit
    spheres 50 apart: 216 faces in all); apart, each gets the grid its own spacing asks for,
    and their meshes, inside disjoint boxes, can neither touch nor cross.

    Parameters
    ----------
    points : (n, 3) float64
        Distinct points, outliers included.
    min_points : int
        Fewest points a group can be reconstructed from: with a smaller group, nothing is split.

    Returns
    -------
    list of (k,) int64
        Indices of each group, the largest first; one group holding every point when nothing is
        far apart.
    """
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components
    from scipy.spatial import cKDTree

    from ..queries import neighbour_table

    n = points.shape[0]
    distance, neighbour = neighbour_table(cKDTree(points), min(SPACING_NEIGHBOURS + 1, n))
    piece = _pieces(distance, neighbour, np.ones(n, bool))
    low, high = _grown_boxes(points, piece, margin)
    group = connected_components(coo_matrix(_overlap(low, high, low, high)), directed=False)[1][piece]
    members = sorted((np.flatnonzero(group == g) for g in np.unique(group)), key=len, reverse=True)
    if len(members[-1]) < min_points:
        return [np.arange(n)]
    return members


@dataclass(frozen=True)
class CloudStats:
    """Scale of a cloud, in its own units.

    Attributes
    ----------
    spacing : (n,) float64
        Local point spacing: mean distance to the ``SPACING_NEIGHBOURS`` nearest points,
        median-filtered over them (robust to one stray neighbour).
    median_spacing : float
    noise : float
        Estimated standard deviation of the points about the surface: the median over the points
        of the RMS distance of their ``NOISE_NEIGHBOURS`` neighbours to their best-fit plane
        (a clean curved surface reads as a small noise, a fraction of the spacing); with normals,
        of the neighbours whose normal agrees in sign with the point's.
    fine_noise : float
        The same over ``SPACING_NEIGHBOURS`` neighbours, about a quadric instead of a plane, so
        that curvature does not count, and sharp edges barely: it tells a noisy cloud from a
        sparse clean one (measured beside ``NOISY``).
    walls : (n,) bool
        Points whose neighbourhood spans both sides of a wall a few spacings thick
        (:func:`wall_points`); their noise is read over their ``SPACING_NEIGHBOURS`` nearest. None
        where normals were given (they tell the sides apart).
    """

    spacing: np.ndarray
    median_spacing: float
    noise: float
    fine_noise: float
    walls: np.ndarray | None = None


def cloud_stats(points: np.ndarray, *, tree=None, sample: int | None = STATISTICS_SAMPLE,
                neighbours=None, normals: np.ndarray | None = None) -> CloudStats:
    """Local spacing and noise level of ``(n, 3)`` points (see :class:`CloudStats`).

    The spacing is every point's; the noise is a median over the neighbourhoods of up to
    ``sample`` random points (None: all; ``STATISTICS_SAMPLE``, where it is measured).
    ``neighbours``: a :func:`~voro3d.queries.neighbour_table` of ``points`` to reuse
    (:func:`outlier_mask`'s), used with ``NOISE_NEIGHBOURS + 1`` columns or more without
    ``normals``, ``SPACING_NEIGHBOURS + 1`` with them; with ``NOISE_NEIGHBOURS + 1``, the noise's
    neighbourhoods are read from it too (the same as queried). ``normals``: (n, 3) consistently oriented
    normals, when known; a neighbour whose normal points against the point's lies on the other
    side of a thin wall, and is left out of the noise. Without them the two sides of a wall a few
    spacings thick would read as noise (``bench_thin_walls``): the points of :func:`wall_points`
    read it over their nearest ``SPACING_NEIGHBOURS`` instead.
    """
    from scipy.spatial import cKDTree

    from ..queries import knn_blocks, neighbour_table, query_order

    tree = cKDTree(points) if tree is None else tree
    n = points.shape[0]
    k = min(NOISE_NEIGHBOURS, n - 1)
    near = min(SPACING_NEIGHBOURS, k)
    columns = 1 + (near if normals is not None else k)
    table = neighbours if neighbours is not None and neighbours[0].shape[0] == n else None
    if table is not None and table[0].shape[1] >= columns:
        distance, neighbour = (part[:, :columns] for part in table)
    else:
        distance, neighbour = neighbour_table(tree, columns)
    spacing = _neighbour_median(distance[:, 1:near + 1].mean(axis=1), neighbour[:, :near + 1])
    walls = None if normals is not None else wall_points(points, neighbour)
    del distance, neighbour

    def residuals(found):
        side = None if normals is None else np.einsum("nkj,nj->nk", normals[found], normals[found[:, 0]]) > 0
        nearest, near_side = points[found[:, :near + 1]], None if side is None else side[:, :near + 1]
        wide = _plane_residuals(points[found], side)
        if walls is not None:  # (normals not given) wall points read their noise over their nearest alone
            wall = walls[found[:, 0]]
            wide[wall] = _plane_residuals(nearest[wall])
        return wide, _quadric_residuals(nearest, near_side)

    if table is not None and table[1].shape[1] >= k + 1:  # the rows knn_blocks would query, read instead
        found_blocks = [table[1][query_order(tree, sample), :k + 1]]
    else:
        found_blocks = (found for _, _, found in knn_blocks(tree, k + 1, sample=sample))
    noise, fine_noise = zip(*(map_rows(residuals, found) for found in found_blocks))
    return CloudStats(spacing=spacing, median_spacing=float(np.median(spacing)), noise=_median_residual(noise),
                      fine_noise=_median_residual(fine_noise), walls=walls)


def _neighbour_median(values: np.ndarray, neighbour: np.ndarray) -> np.ndarray:
    """(n,) median of ``values`` over each row of ``neighbour`` (n, k), a block of rows at a time
    (the gathered (n, k) float64 table is never whole)."""
    return map_rows(lambda rows: np.median(values[rows], axis=1), neighbour)


def _plane_residuals(neighbourhoods: np.ndarray, members: np.ndarray | None = None) -> np.ndarray:
    """(n,) smallest covariance eigenvalue of (n, k, 3) neighbourhoods: the squared RMS distance to
    their best-fit plane; only over the (n, k) bool ``members`` of each, when given."""
    if members is None:
        return np.linalg.eigvalsh(_centred_covariance(neighbourhoods)[1])[:, 0]
    weight = members / members.sum(axis=1, keepdims=True)
    local = neighbourhoods - np.einsum("nk,nki->ni", weight, neighbourhoods)[:, None, :]
    return np.linalg.eigvalsh(np.einsum("nk,nki,nkj->nij", weight, local, local))[:, 0]


def two_sheets(neighbourhoods: np.ndarray, near: int) -> tuple[np.ndarray, np.ndarray]:
    """Which neighbourhoods lie on two parallel sheets, the two sides of a wall a few spacings thick.

    The plane of a neighbourhood's ``near`` nearest points, and on one side of it a parallel sheet
    of the others: at least ``TWO_SHEET_POINTS`` further off it than 0.8 of the near part's radius,
    their offsets within a quarter of each other, ``TWO_SHEET_CLEARANCE`` times the near part's
    scatter off its plane and none between. A bend reads otherwise (the others' offsets grow
    along it), and so does noise (on both sides, and within a few times the scatter).

    Parameters
    ----------
    neighbourhoods : (n, k, 3) float64
        Each point first, then its neighbours, nearest first.
    near : int
        Neighbours of the near plane.

    Returns
    -------
    (n,) bool
        On two sheets.
    (n, 3) float64
        The near plane's unit normal.
    """
    centre = neighbourhoods[:, :near + 1].mean(axis=1)
    values, normal = plane_normals(neighbourhoods[:, :near + 1], values=True)
    offset = np.einsum("nkj,nj->nk", neighbourhoods - centre[:, None, :], normal)
    size = np.abs(offset)
    far = size > 0.8 * np.sqrt(values[:, 1] + values[:, 2])[:, None]
    count = far.sum(axis=1)
    height = np.where(far, size, 0.0).sum(axis=1) / np.maximum(count, 1)
    spread = np.sqrt(np.where(far, (size - height[:, None]) ** 2, 0.0).sum(axis=1) / np.maximum(count, 1))
    one_side = np.abs(np.where(far, np.sign(offset), 0.0).sum(axis=1)) == count
    clear = height > TWO_SHEET_CLEARANCE * np.sqrt(np.maximum(values[:, 0], 0.0))
    return (count >= TWO_SHEET_POINTS) & one_side & (spread < 0.25 * height) & clear, normal


def plane_normals(neighbourhoods: np.ndarray, *, values: bool = False):
    """(n, 3) unit normals of the best-fit planes of (n, k, 3) neighbourhoods; with ``values``,
    after their (n, 3) covariance eigenvalues, ascending (the first: squared RMS distance to it)."""
    eigenvalues, vectors = np.linalg.eigh(_centred_covariance(neighbourhoods)[1])
    return (eigenvalues, vectors[:, :, 0]) if values else vectors[:, :, 0]


def wall_points(points: np.ndarray, neighbours: np.ndarray) -> np.ndarray:
    """Points whose neighbourhood spans both sides of a wall a few spacings thick.

    A point's ``NOISE_NEIGHBOURS``-neighbourhood reads :func:`two_sheets` (near plane over its
    ``SPACING_NEIGHBOURS`` nearest), and so do at least ``WALL_VOTE`` of its ``WALL_VOTERS``
    nearest neighbours': a wall's sides run on, while noise reads two sheets at scattered points.
    (16-neighbourhoods, those of the normals' plane fits, miss the far side of walls 2 spacings
    thick: a tube at 30k points reads two sheets at 39% of its points with 16, 88% with 24.)

    Parameters
    ----------
    points : (n, 3) float64
    neighbours : (n, m) int
        Each point's neighbours, itself first, nearest first (:func:`~voro3d.queries.neighbour_table`);
        the first ``NOISE_NEIGHBOURS + 1`` columns are used.

    Returns
    -------
    (n,) bool
    """
    table = neighbours[:, :NOISE_NEIGHBOURS + 1]
    near = min(SPACING_NEIGHBOURS, table.shape[1] - 1)
    across = map_rows(lambda rows: two_sheets(points[rows], near)[0], table)
    return across & (across[table[:, :WALL_VOTERS + 1]].mean(axis=1) >= WALL_VOTE)


def _centred_covariance(neighbourhoods: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(n, k, 3) neighbourhoods -> their points about their centroid (n, k, 3) and covariance (n, 3, 3)."""
    local = neighbourhoods - neighbourhoods.mean(axis=1, keepdims=True)
    return local, np.einsum("nki,nkj->nij", local, local) / neighbourhoods.shape[1]


def _quadric_residuals(neighbourhoods: np.ndarray, members: np.ndarray | None = None) -> np.ndarray:
    """(n,) squared RMS distance of (n, k, 3) neighbourhoods to their best-fit quadric height field over
    their plane, on :func:`_plane_residuals`' scale for pure noise (times (k - 3) / (k - 6), the
    degrees of freedom): what is left is noise, not curvature. Only over the (n, k) bool ``members``
    of each when given; a neighbourhood with fewer than 8 members reads its plane residual."""
    weight = np.ones(neighbourhoods.shape[:2]) if members is None else members.astype(np.float64)
    count = weight.sum(axis=1)
    local = neighbourhoods - (weight[:, None, :] @ neighbourhoods) / count[:, None, None]
    weighted = local * weight[..., None]  # batched matmuls: einsum's three-operand sums took 3x as long
    value, frame = np.linalg.eigh(weighted.transpose(0, 2, 1) @ local / count[:, None, None])
    # In the plane's frame, scaled by the neighbourhood's extent so that the 6x6 systems are well conditioned.
    scale = np.sqrt(np.maximum(value[:, 2], 1e-300))
    height, v, u = np.moveaxis(local @ frame / scale[:, None, None], 2, 0)
    terms = np.stack([u * u, u * v, v * v, u, v, np.ones_like(u)], axis=-1)
    weighted = terms * weight[..., None]
    normal = weighted.transpose(0, 2, 1) @ terms + 1e-9 * np.eye(6)
    coefficients = np.linalg.solve(normal, weighted.transpose(0, 2, 1) @ height[..., None])
    misfit = height - (terms @ coefficients)[..., 0]
    squared = (weight * misfit**2).sum(axis=1) * scale**2 / np.maximum(count - 6.0, 1.0) * (count - 3.0) / count
    return np.where(count >= 8, squared, value[:, 0])


def _median_residual(blocks: list) -> float:
    """Median RMS plane distance over the blocks of :func:`_plane_residuals`."""
    return float(np.sqrt(max(np.median(np.concatenate(blocks)), 0.0)))


def outlier_mask(points: np.ndarray, *, tree=None, neighbours=None) -> np.ndarray:
    """True for points that look like outliers rather than surface samples.

    Two tests find suspects. A point whose mean distance to its ``STRAY_NEIGHBOURS`` neighbours is
    more than ``STRAY_RATIO`` times theirs (the median) is a stray near the surface: a local version
    of Open3D's statistical filter, which compares with the whole cloud's mean and so would cut
    the sparse end of an unevenly sampled surface. A point whose 8th neighbour is more than
    ``SPARSE_SPACINGS`` times the cloud's median distance away is in empty space, or on a part of the
    surface sampled far more sparsely than the rest. A suspect that lies on the plane of its
    neighbours, which lie on it too (:func:`_on_sheet`), is that sparse surface and stays: scattered
    outliers have neither. Last, clumps far from the rest (:func:`_small_clusters`).

    Parameters
    ----------
    points : (n, 3) float64
    neighbours : (distance, neighbour), optional
        :func:`outlier_neighbours` of ``points``, to reuse; queried when not given.

    Returns
    -------
    (n,) bool
    """
    distance, neighbour = (table[:, :STRAY_NEIGHBOURS + 1] for table in
                           (outlier_neighbours(points, tree=tree) if neighbours is None else neighbours))
    spacing = distance[:, SPACING_NEIGHBOURS]
    suspect = spacing > SPARSE_SPACINGS * np.median(spacing)
    mean = distance[:, 1:].mean(axis=1)
    suspect |= mean > STRAY_RATIO * _neighbour_median(mean, neighbour[:, 1:])
    index = np.flatnonzero(suspect)
    suspect[index[_on_sheet(points, neighbour[index])]] = False
    distance = distance[:, :SPACING_NEIGHBOURS + 1].copy()  # all _small_clusters needs
    return suspect | _small_clusters(points, distance, neighbour[:, :SPACING_NEIGHBOURS + 1], ~suspect)


def _on_sheet(points, neighbourhood) -> np.ndarray:
    """(m,) bool: the ``neighbourhood`` rows (m, k) of point indices, each point first, whose points
    lie within ``SUSPECT_FLATNESS`` of their in-plane spread (RMS) from their best-fit plane, and
    the first point within ``SUSPECT_OFFSET`` of it."""
    def flat(rows):
        local, covariance = _centred_covariance(points[rows])
        value, vector = np.linalg.eigh(covariance)
        spread = np.sqrt(value[:, 2])
        offset = np.abs(np.einsum("ni,ni->n", local[:, 0], vector[:, :, 0]))
        return (np.sqrt(np.maximum(value[:, 0], 0.0)) < SUSPECT_FLATNESS * spread) & (offset < SUSPECT_OFFSET * spread)

    return map_rows(flat, neighbourhood) if len(neighbourhood) else np.zeros(0, bool)


def outlier_neighbours(points: np.ndarray, *, tree=None) -> tuple[np.ndarray, np.ndarray]:
    """The kNN table :func:`outlier_mask` reads (``STRAY_NEIGHBOURS`` and the point itself,
    :func:`~voro3d.queries.neighbour_table`), as wide as :func:`cloud_stats`' wall test needs
    (``NOISE_NEIGHBOURS``): the spacing, walls and point areas of the same points read theirs from
    it too (one query instead of two: 100k bunny points, the clean phase 1.6-1.9 s -> 1.3-1.4 s)."""
    from scipy.spatial import cKDTree

    from ..queries import neighbour_table

    tree = cKDTree(points) if tree is None else tree
    return neighbour_table(tree, min(max(STRAY_NEIGHBOURS, NOISE_NEIGHBOURS) + 1, points.shape[0]))


def _small_clusters(points, distance, neighbour, candidate, *, share: float = 0.01, block: int = 2**14):
    """``candidate`` points in small pieces (:func:`_pieces`; fewer than ``share`` of them) that lie
    apart from every large piece, as :func:`separate_objects` tells objects apart (grown bounding
    boxes that do not overlap): far-off clumps of strays. A sparsely sampled part of the surface
    falls into small pieces too, but among the rest, and stays."""
    index = np.flatnonzero(candidate)
    if not index.size:
        return np.zeros(len(candidate), bool)
    piece = np.unique(_pieces(distance, neighbour, candidate)[index], return_inverse=True)[1].reshape(-1)
    size = np.bincount(piece)
    small = size < max(share * len(index), 10)
    low, high = _grown_boxes(points[index], piece)
    apart = np.zeros(len(size), bool)
    few = np.flatnonzero(small)
    for start in range(0, len(few), block):  # (block, large pieces, 3) at a time: a million singletons fit
        rows = few[start:start + block]
        apart[rows] = ~_overlap(low[rows], high[rows], low[~small], high[~small]).any(axis=1)
    clump = np.zeros(len(candidate), bool)
    clump[index] = apart[piece]
    return clump


def _pieces(distance, neighbour, candidate, *, reach: float = 4.0) -> np.ndarray:
    """Connected piece of each point in the graph joining ``candidate`` points within ``reach``
    median 8th-neighbour distances (``distance``, ``neighbour``: a kNN query, itself first)."""
    from scipy.sparse import csr_matrix
    from scipy.sparse.csgraph import connected_components

    n = distance.shape[0]
    cols = neighbour[:, 1:]
    near = (distance[:, 1:] <= reach * np.median(distance[:, -1])) & candidate[:, None] & candidate[cols]
    # Row by row, as the table is: built as CSR, the graph needs no sort (10^5 points: 0.08 -> 0.05 s).
    starts = np.concatenate([[0], np.cumsum(near.sum(axis=1))])
    graph = csr_matrix((np.ones(int(starts[-1]), np.int8), cols[near], starts), shape=(n, n))
    return connected_components(graph, directed=False)[1]


def _grown_boxes(points, piece, margin: float = 0.5) -> tuple[np.ndarray, np.ndarray]:
    """(p, 3) low and high corners of each piece's bounding box, grown by ``margin`` of its diagonal."""
    low = np.full((piece.max() + 1, 3), np.inf)
    high = np.full((piece.max() + 1, 3), -np.inf)
    np.minimum.at(low, piece, points)
    np.maximum.at(high, piece, points)
    grow = margin * np.linalg.norm(high - low, axis=1)[:, None]
    return low - grow, high + grow


def _overlap(low_a, high_a, low_b, high_b) -> np.ndarray:
    """(a, b) bool: which boxes of the first set overlap which of the second."""
    return np.all((low_a[:, None] <= high_b[None]) & (low_b[None] <= high_a[:, None]), axis=2)


# A cloud is taken to fill a volume, rather than sample a surface, when both tests say so. The
# local dimension reads 2.0-2.1 on clean sampled surfaces, up to 2.6 with 1% noise or on thin
# parts whose neighbourhoods span several sheets, and 2.5-2.9 for points spread through a box.
# The fill ratio (points times spacing cubed over the box volume) reads under 0.25 on surfaces
# and 0.8-0.9 in a uniformly filled box; alone it would refuse a thin flat plate.
MAX_SURFACE_DIMENSION = 2.45
MAX_SURFACE_FILL = 0.5


def fill_ratio(points: np.ndarray, spacing: float) -> float:
    """``n spacing^3 / V``: about 1 for points filling their bounding box, far less on a surface."""
    volume = float(np.prod(np.ptp(points, axis=0)))
    return points.shape[0] * spacing**3 / volume if volume > 0 else float("inf")


def local_dimension(points: np.ndarray, *, tree=None, sample: int | None = STATISTICS_SAMPLE) -> float:
    """Median growth exponent of the neighbourhoods: ``log 4 / log(d_4k / d_k)`` with ``d_k`` the
    distance to the ``k``-th neighbour (k = 32, or fewer for small clouds): 2 on a surface, 3 in
    a volume. The median is over up to ``sample`` random points (None: all)."""
    from scipy.spatial import cKDTree

    from ..queries import knn_blocks

    tree = cKDTree(points) if tree is None else tree
    far = min(128, points.shape[0] - 1)
    near = max(far // 4, 1)
    ratio = np.concatenate([distance[:, 1] / np.maximum(distance[:, 0], 1e-300)
                            for _, distance, _ in knn_blocks(tree, [near + 1, far + 1], sample=sample)])
    return float(np.median(np.log(far / near) / np.log(np.maximum(ratio, 1.0 + 1e-12))))
