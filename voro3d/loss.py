"""VoroLoss: squared distance from surface samples to the boundary of the Voronoi cell holding them.

For a sample ``x`` whose nearest generator is ``q_i``, the distance to the boundary of cell ``i``
is the smallest distance to a bisector plane ``H(i, j)``,

    d(x, H(i, j)) = ((|q_j|^2 - |q_i|^2) / 2 - x . (q_j - q_i)) / |q_j - q_i|
                  = (q_j - q_i) . ((q_i + q_j) / 2 - x) / |q_j - q_i|,

which is non-negative because ``x`` lies in cell ``i``. The minimum over all ``j`` is attained at
a Voronoi neighbour of ``i`` (the paper's theorem), and in practice among the few generators
nearest to ``x``: the loss searches the ``k`` nearest (a KD-tree, never a samples-by-generators
distance matrix).
"""
from __future__ import annotations

import numpy as np

from ._extras import require
from ._validate import as_points, positive_int

torch = require("torch", "VoroLoss (voro3d.loss)")

__all__ = ["DEFAULT_K", "KNN_BLOCK", "PAIR_BLOCK", "bisector_distance", "bisector_pairs", "knn_candidates",
           "nearest_indices", "nearest_indices_on_device", "voroloss"]

# The official code (``Voroloss``, ``VoronoiValues.kedge + 1``) searches the nearest generator
# plus the 10 next ones. The generators of a fit form a band about one voxel deep on each side of
# the surface, so the faces of the cell around a surface sample that lie near the sample are
# shared with generators among its 10 next-nearest; tests/test_loss.py checks that k = 32 gives
# the same loss on such a configuration.
DEFAULT_K = 11


def knn_candidates(samples, generators, *, k: int = DEFAULT_K) -> np.ndarray:
    """Indices of the ``k`` generators nearest to each sample, nearest first.

    Open3D's KD-tree (nanoflann, float32, all cores), which measured 1.2-1.6 times faster than
    ``scipy.spatial.cKDTree(...).query(workers=-1)`` on 1.5e5-6e5 samples here. The float32
    search can swap near-ties; :func:`voroloss` re-ranks the candidates in full precision.

    Parameters
    ----------
    samples : (m, 3) float array or torch.Tensor
    generators : (n, 3) float array or torch.Tensor
        Detached; the search carries no gradient.
    k : int
        Candidates per sample, ``>= 2``; capped at ``n``.

    Returns
    -------
    (m, min(k, n)) int64 numpy array
        Row ``r`` lists generator indices by increasing distance to ``samples[r]``.

    Raises
    ------
    ValueError
        Bad shapes, NaN/inf, fewer than 2 generators, or ``k < 2``.
    """
    points = as_points(_numpy(samples), "samples", min_count=0, dtype=np.float32)
    sites = as_points(_numpy(generators), "generators", min_count=2, dtype=np.float32)
    k = min(positive_int(k, "k", minimum=2), sites.shape[0])
    return nearest_indices(points, sites, k).astype(np.int64)


def nearest_indices(points: np.ndarray, sites: np.ndarray, k: int) -> np.ndarray:
    """Unchecked core of :func:`knn_candidates`.

    Parameters
    ----------
    points : (m, 3) float32, C-contiguous
    sites : (n, 3) float32, C-contiguous, ``n >= k``
    k : int

    Returns
    -------
    (m, k) int32
    """
    import open3d as o3d

    if points.shape[0] == 0:
        return np.zeros((0, k), dtype=np.int32)
    search = o3d.core.nns.NearestNeighborSearch(o3d.core.Tensor(sites))
    search.knn_index()
    indices, _ = search.knn_search(o3d.core.Tensor(points), k)
    return indices.numpy()


# Samples per block of the on-device search: a (block, n) distance matrix, 1 GB at n = 16k.
KNN_BLOCK = 16384


def nearest_indices_on_device(points: torch.Tensor, sites: torch.Tensor, k: int) -> torch.Tensor:
    """The ``k`` nearest sites of each point, nearest first, by brute force on the tensors' device.

    On a GPU a blocked distance matrix and ``topk`` beat copying to the host for a KD-tree
    (training batches hold a few thousand generators per shape); on a CPU use :func:`nearest_indices`.

    Parameters
    ----------
    points : (m, 3) float torch.Tensor
    sites : (n, 3) float torch.Tensor, same device, ``n >= k``
    k : int

    Returns
    -------
    (m, k) int64 torch.Tensor
    """
    found = torch.empty((points.shape[0], k), dtype=torch.int64, device=points.device)
    with torch.no_grad():
        for start in range(0, points.shape[0], KNN_BLOCK):
            block = points[start:start + KNN_BLOCK]
            distance = torch.cdist(block, sites.to(block.dtype))
            found[start:start + KNN_BLOCK] = distance.topk(k, dim=1, largest=False, sorted=True).indices
    return found


def voroloss(samples, generators, *, k: int | None = None, candidates=None) -> torch.Tensor:
    """Mean squared distance from samples to the boundary of the Voronoi cell holding each one.

    Parameters
    ----------
    samples : (m, 3) float torch.Tensor or array
        Surface samples. Cast to the dtype and device of ``generators``; they carry gradients
        if they require them.
    generators : (n, 3) float32 or float64 torch.Tensor
        Distinct generator positions, ``n >= 2``; the loss is differentiable in them (through
        both the nearest generator ``q_i`` and the bisector's other generator ``q_j``).
    k : int, optional
        Generators searched per sample (the nearest plus ``k - 1`` others); default ``DEFAULT_K``.
        Not with ``candidates``, which fix the generators searched. Searched with
        :func:`knn_candidates` for CPU tensors, on the device otherwise.
    candidates : (m, c) int array or torch.Tensor, optional
        Generator indices to search per sample, ``c >= 2``, e.g. from :func:`knn_candidates`
        on earlier generator positions. The nearest generator is re-ranked among them, so they
        stay exact while they still hold the nearest generator and the one across the nearest
        bisector.

    Returns
    -------
    torch.Tensor
        0-dim, dtype of ``generators``: ``mean_x min_j d(x, H(i_x, j))**2``, with ``i_x`` the
        nearest candidate to ``x``. Copies of ``q_i`` among the candidates are skipped; a sample
        with no other candidate contributes 0.

    Raises
    ------
    ValueError
        Bad shapes or dtypes, NaN/inf, candidate indices outside ``[0, n)``, or both ``k`` and
        ``candidates``.
    TypeError
        ``generators`` is not a torch tensor.
    """
    if k is not None and candidates is not None:
        raise ValueError("give k or candidates, not both: candidates fix the generators searched")
    if not isinstance(generators, torch.Tensor):
        raise TypeError(f"generators must be a torch.Tensor, got {type(generators).__name__}")
    if generators.dtype not in (torch.float32, torch.float64) or generators.ndim != 2 or generators.shape[1] != 3:
        raise ValueError("generators must be a float32 or float64 tensor of shape (n, 3), "
                         f"got {generators.dtype} {tuple(generators.shape)}")
    if generators.shape[0] < 2:
        raise ValueError(f"generators must hold at least 2 points, got {generators.shape[0]}")
    if not torch.isfinite(generators).all():
        raise ValueError("generators holds NaN or inf")
    if isinstance(samples, torch.Tensor):
        if samples.ndim != 2 or samples.shape[1] != 3:
            raise ValueError(f"samples must have shape (m, 3), got {tuple(samples.shape)}")
        if not samples.is_floating_point() or not torch.isfinite(samples).all():
            raise ValueError("samples must be a finite float tensor")
        samples = samples.to(dtype=generators.dtype, device=generators.device)
    else:
        samples = torch.as_tensor(as_points(samples, "samples", min_count=0), dtype=generators.dtype,
                                  device=generators.device)
    if samples.shape[0] == 0:
        raise ValueError("samples must hold at least 1 point, got 0")
    if candidates is None:
        k = DEFAULT_K if k is None else positive_int(k, "k", minimum=2)
        if generators.device.type == "cpu":
            candidates = knn_candidates(samples.detach(), generators.detach(), k=k)
        else:
            candidates = nearest_indices_on_device(samples.detach(), generators.detach(), min(k, generators.shape[0]))
    candidates = torch.as_tensor(candidates, device=generators.device)
    if candidates.dtype.is_floating_point or candidates.dtype == torch.bool or candidates.ndim != 2:
        raise ValueError("candidates must be an integer array of shape (m, c), "
                         f"got {candidates.dtype} {tuple(candidates.shape)}")
    if candidates.shape[0] != samples.shape[0] or candidates.shape[1] < 2:
        raise ValueError(f"candidates must have shape ({samples.shape[0]}, c) with c >= 2, "
                         f"got {tuple(candidates.shape)}")
    if candidates.min() < 0 or candidates.max() >= generators.shape[0]:
        raise ValueError(f"candidates must index generators in [0, {generators.shape[0]})")
    samples_t = samples.t().contiguous()
    generators_t = generators.t().contiguous()
    nearest, other = bisector_pairs(samples_t.detach(), generators_t.detach(), candidates.long().t().contiguous())
    return bisector_distance(samples_t, generators_t, nearest, other).square().mean()


def bisector_pairs(samples_t: torch.Tensor, generators_t: torch.Tensor, candidates_t: torch.Tensor, *,
                   sides_t: torch.Tensor | None = None):
    """For each sample, its nearest candidate ``i`` and the candidate ``j`` whose bisector is closest.

    No gradient and no validation: the search step of :func:`voroloss`, shared with the fit loop.
    Arrays are coordinate-major so that every operation runs over the long sample axis; working
    relative to the sample keeps the terms the size of a voxel, so float32 is accurate enough.

    Parameters
    ----------
    samples_t : (3, m) float torch.Tensor
    generators_t : (3, n) float torch.Tensor, same dtype and device
    candidates_t : (c, m) int32 or int64 torch.Tensor
        Generator indices, ``c >= 2``.
    sides_t : (n,) bool torch.Tensor, optional
        Each generator's label: ``j`` is then sought among the candidates labelled unlike ``i``
        only, as the compiled kernel's ``sides``.

    Returns
    -------
    nearest, other : (m,) int64 torch.Tensor
        Generator indices; ``other == nearest`` where every other candidate is a copy of ``q_i``
        (or, with ``sides_t``, on its side).
    """
    m = candidates_t.shape[1]
    # int64 out: index_add_ (the backward) takes a slow path with int32 indices.
    nearest = torch.empty(m, dtype=torch.int64, device=candidates_t.device)
    other = torch.empty_like(nearest)
    with torch.no_grad():
        # Blocks of samples keep the (c, block) temporaries in cache: twice as fast at 5e5 samples.
        for start in range(0, m, PAIR_BLOCK):
            block = slice(start, start + PAIR_BLOCK)
            _block_pairs(samples_t[:, block], generators_t, candidates_t[:, block], nearest[block], other[block],
                         sides_t=sides_t)
    return nearest, other


# Samples per block in :func:`bisector_pairs`.
PAIR_BLOCK = 32768


def _block_pairs(samples_t, generators_t, candidates_t, nearest, other, *, sides_t=None):
    c, m = candidates_t.shape
    flat = candidates_t.reshape(-1)
    offset = [generators_t[d].index_select(0, flat).view(c, m).sub_(samples_t[d]) for d in range(3)]
    squared = offset[0] * offset[0]
    squared.addcmul_(offset[1], offset[1]).addcmul_(offset[2], offset[2])
    col_i = _argmin_rows_(squared)[0][None]
    for axis in offset:
        axis.sub_(axis.gather(0, col_i))
    edge = offset[0].square_().addcmul_(offset[1], offset[1]).addcmul_(offset[2], offset[2])
    # The squared bisector distance (|x - q_j|^2 - |x - q_i|^2)^2 / (4 |q_j - q_i|^2) ranks
    # like the distance itself (the numerator is >= 0 since i is the nearest) and needs no sqrt;
    # j = i and copies of q_i give 0 / 0 and drop out as inf.
    distance = squared.sub_(squared.gather(0, col_i)).square_().div_(edge).nan_to_num_(nan=float("inf"))
    if sides_t is not None:
        side = sides_t.index_select(0, flat).view(c, m)
        distance.masked_fill_(side == side.gather(0, col_i), float("inf"))  # on i's side: no face to fit
    col_j, finite = _argmin_rows_(distance)
    col_j = torch.where(finite, col_j, col_i[0])[None]
    nearest.copy_(candidates_t.gather(0, col_i)[0])
    other.copy_(candidates_t.gather(0, col_j)[0])


# Integer type of the same width, and the bit pattern of +inf read as that integer.
_INTEGER_VIEW = {torch.float32: (torch.int32, 0x7F800000), torch.float64: (torch.int64, 0x7FF0000000000000)}


def _argmin_rows_(values: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """``values.argmin(0)`` for a ``(c, m)`` float32/float64 tensor of values ``>= 0`` or ``+inf``.

    On CPU, torch's argmin over the leading axis is about 30 times slower than ``amin``. Non-negative
    floats order like their bit patterns read as integers, so the row number is written into the
    lowest mantissa bits, in place, and one integer ``amin`` finds both. Values within ``c`` units
    in the last place count as ties, which go to the lower row; ``values`` keeps that perturbation.

    Returns
    -------
    rows : (m,) int64
    finite : (m,) bool
        False where the whole column is ``+inf``.
    """
    c = values.shape[0]
    bits = max(1, (c - 1).bit_length())
    integer, infinity = _INTEGER_VIEW[values.dtype]
    packed = values.view(integer)
    rows = torch.arange(c, dtype=integer, device=values.device)[:, None]
    smallest = packed.bitwise_and_(-(1 << bits)).bitwise_or_(rows).amin(0)
    return smallest.bitwise_and((1 << bits) - 1).long(), smallest < infinity


def bisector_distance(samples_t: torch.Tensor, generators_t: torch.Tensor, nearest: torch.Tensor,
                      other: torch.Tensor) -> torch.Tensor:
    """Signed distance from each sample to the bisector plane of two generators, differentiably.

    Parameters
    ----------
    samples_t : (3, m) float torch.Tensor
    generators_t : (3, n) float torch.Tensor
        Gradients flow to columns ``nearest`` and ``other`` (and to ``samples_t`` if it requires them).
    nearest, other : (m,) int64 torch.Tensor

    Returns
    -------
    (m,) torch.Tensor
        Positive on the side of ``generators_t[:, nearest]``; 0, with zero gradient, where the two
        generators coincide.
    """
    return _BisectorDistance.apply(samples_t, generators_t, nearest, other)


class _BisectorDistance(torch.autograd.Function):
    """Bisector distance with a hand-written backward.

    With ``e = q_j - q_i``, ``L = |e|``, ``u = e / L`` and ``d = L / 2 - u . (x - q_i)``:
    ``dd/dq_i = (x - q_i + d u) / L``, ``dd/dq_j = u - dd/dq_i`` and ``dd/dx = -u``. Autograd's
    version of the same formula took three times as long, most of it in tiny kernels.
    """

    @staticmethod
    def forward(ctx, samples_t, generators_t, nearest, other):
        q_i = generators_t.index_select(1, nearest)
        from_i = samples_t - q_i
        edge = generators_t.index_select(1, other).sub_(q_i)
        length = edge.square().sum(0).sqrt_()
        inverse = torch.where(length > 0, 1.0 / length, 0.0)
        unit = edge.mul_(inverse)
        distance = (length / 2).sub_((unit * from_i).sum(0))
        ctx.save_for_backward(from_i, unit, inverse, distance, nearest, other)
        ctx.n_generators = generators_t.shape[1]
        return distance

    @staticmethod
    @torch.autograd.function.once_differentiable
    def backward(ctx, grad_distance):
        from_i, unit, inverse, distance, nearest, other = ctx.saved_tensors
        along = unit * grad_distance
        grad_samples = grad_generators = None
        if ctx.needs_input_grad[0]:
            grad_samples = -along
        if ctx.needs_input_grad[1]:
            grad_i = torch.addcmul(from_i, unit, distance).mul_(grad_distance * inverse)
            grad_generators = grad_i.new_zeros((3, ctx.n_generators))
            grad_generators.index_add_(1, nearest, grad_i).index_add_(1, other, along.sub_(grad_i))
        return grad_samples, grad_generators, None, None


def _numpy(value) -> np.ndarray:
    if isinstance(value, torch.Tensor):
        return value.detach().cpu().numpy()
    return np.asarray(value)
