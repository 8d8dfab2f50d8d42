"""Snap a cleaned surface onto the smooth surface it was fitted to, every guarantee kept.

The VoroMesh of a point cloud follows its smooth target surface only as closely as its Voronoi
faces allow: the cleaned surface keeps small facets tilted where the fit could not settle. Here
the vertices move (at most ``max_move`` voxels) so that the surface fits the target in least
squares: damped Gauss-Newton steps on the residuals (nearest target point minus point, its
part along the target's normal between nearest-point queries) at the vertices and at
``FACE_POINTS`` of every triangle, each vertex moved by its own normal equations,
with an optional pull towards the mean of its neighbours (``smoothing``, for noisy targets).
Fitting faces, not just vertices, keeps the faces straddling the target as the VoroLoss fit left
them: moving the vertices onto the target instead lays the faces inside its convex parts (their
sagitta), which cost 2-7% CD on clean dev clouds. Every path that knows what a shape approximates
applies it after the clean (``VoroMesh.to_open3d(surface=...)``). Measured on 38 dev meshes and 16
dev clouds (``benchmarks/bench_clean.py [--clouds]``): ``benchmarks/results/clean_32_64.md`` and
``clean_clouds.md``, the *output* rows.

A vertex moves only where nothing breaks, else it stays where it was, with the corners of the
triangles that would break:

- no triangle turns by ``max_turn`` degrees or more (CGAL's bounded normal change: none flips) or,
  where the faces are fitted, becomes thinner than ``MIN_ANGLE`` degrees (unless it was already);
- the star of every vertex (its triangles) stays a graph over its mean normal: each triangle faces
  it and, seen along it, their angles at the vertex sum to one turn. Then the star's projection is
  one-to-one, so triangles that share a vertex meet only at what they share; the exact crossing
  test does not look at such pairs;
- no two other triangles cross or touch (CGAL's exact test).

Connectivity is unchanged, so the surface stays closed, manifold and oriented.

The steps, the paths that snap
------------------------------
The clean keeps every face within 0.2 voxel of the Voronoi surface, so the facets that the VoroLoss
fit left tilted stay tilted. ``voro3d.snap(mesh, surface)`` moves the
vertices, at most a quarter voxel each, so that the mesh fits ``surface`` in least squares: six
damped Gauss-Newton steps on the residuals (nearest point of ``surface`` minus point) at the vertices
and at four points of every triangle. The nearest points are queried every third step, and the
steps between fit the planes of the triangles found (ICP's point-to-plane): 1.4-1.7 times faster,
results within 0.1%. Fitting the faces, not the vertices, leaves them straddling
the surface as the fit did (vertices moved onto the surface lay the faces inside its convex parts:
CD +2-7% on clean dev clouds). ``smoothing`` adds a pull of each vertex towards the mean of its
neighbours (0.3 on noisy clouds, whose target carries the noise's bumps).

The triangles stay the same, so the result stays closed, manifold and oriented. A vertex stays
where it was, with the corners of the triangles concerned, when its move would turn a triangle by
90° or more, make one thinner than 5° (that was not), make the star of a vertex stop being a graph
over its mean normal (its triangles would overlap each other, which the crossing test does not look
at: it skips triangles that share a vertex) or make two triangles cross or touch (CGAL's exact
test). Every point of the result is within a quarter voxel of the input and back; with the clean,
0.45 voxel of the Voronoi surface.

**Point clouds** get it by default (``pointcloud.cloud_mesh``, as ``reconstruct`` returns them; not a
dense one-sided scan, fitted to its own points), with smoothing where the cloud is noisy.

**Meshes** get it by default too: ``reconstruct``, ``VoroMeshStage``, ``voro3d fit``, ``voro3d predict``
on a mesh, ``run_batch`` and the demo return ``shape.to_open3d(surface=input)``, the cleaned surface
fitted to the input (``to_open3d()`` without a surface, ``voro3d extract`` and an SDF-grid prediction
have nothing to fit to and return the cleaned surface).
"""
from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

from .geometry import centred_scene, face_area_vectors as _normals, face_normals, smallest_angles, vertex_normals
from .io import mesh_arrays
from .watertight import self_intersections, signed_volume

__all__ = ["SnapInfo", "snap", "snap_to_surface"]

MAX_MOVE = 0.25  # voxels; half a voxel gained nothing on the noisy dev clouds, snapped without smoothing
MAX_TURN = 90.0  # degrees
MIN_ANGLE = 5.0  # degrees: the sliver angle of metrics.triangle_quality
# A split mesh (VoroMesh.to_open3d's refine) keeps the pieces of the triangles at a crease, a side
# where its surface turns by more than this, where they are: a smooth target rounds the crease.
# 11 CAD dev meshes from 2x10^5 true-normal points (bench_edges' clouds, grid "auto", most split once)
# and the 12 benchmark meshes at 10^5 clean points (grid 64, split once or twice; 2026-12-05), mean
# edge F-score / NC: unsplit 0.345 / 0.9809; split, nothing kept: abc_00000003 0.474 -> 0.342,
# abc_00000005 0.699 -> 0.583 (stopped there) / 0.9856; kept past 40 degrees: abc_00000003 0.566,
# abc_00000005 0.721, fandisk 0.507 -> 0.587 / armadillo 0.9674 -> 0.9656, thingi32_252119 0.9308 ->
# 0.9253 (34% and 59% of their grid-64 triangles have a side past 40 degrees, 4% and 16% past 75:
# facets the fit left tilted read as creases); past 60: 0.360 / 0.9823 (screwdriver 0.346 -> 0.289);
# past 75: 0.358 / 0.9840, no mesh's edge F-score more than 0.005 under unsplit. Past one split the
# vertices go onto a target as fine as the triangles and nothing is kept: kept there, 10^6 true-normal
# points of fandisk (split twice, CD / NC the means of 5 evaluation seeds) read 0.6617 / 0.9901 ->
# 0.6636 / 0.9885, and the 100k clouds split twice at grid 64 (abc_00000008, cow, homer,
# thingi32_252119) NC 0.9875 / 0.9806 / 0.9943 / 0.9474 -> 0.9858 / 0.9778 / 0.9934 / 0.9385.
CREASE_DEGREES = 75.0
# Least-squares fit: residuals at the vertices and at these barycentric points of each triangle;
# ITERATIONS steps of DAMPING times the Gauss-Newton step. Bunny and rocker-arm clouds, triangles
# more than 30 degrees off the true normal after 3 steps of 0.5 / 6 of 0.7 / 10 of 0.8: clean 20k
# 4.1 / 3.8 / 3.7% (bunny), 0.5% noise 10.9 / 10.2 / 9.6% (bunny); CD within 0.5%; the last at 1.5
# times the time.
FACE_POINTS = np.array([[1, 1, 1], [4, 1, 1], [1, 4, 1], [1, 1, 4]]) / np.array([[3.0], [6.0], [6.0], [6.0]])
ITERATIONS = 6
DAMPING = 0.7
# Nearest points are queried every QUERY_EVERY steps; the steps between keep those points and fit
# the planes of their target triangles (ICP's point-to-plane). The queries were three quarters of
# the time; on 6 dev meshes at 64^3 and 12 dev clouds the fit is 1.4-1.7 times faster with CD,
# NC and off-normal shares within 0.1% (querying once: CD +0.6% on noisy clouds).
QUERY_EVERY = 3
# The smoothing weight for a noisy cloud's target, which carries the noise's bumps. Ten clouds of
# four dev shapes at 0.25-1% noise, against none: triangles more than 30 degrees off the true normal
# fewer on all (at 0.5%: 16.0/7.1/20.4/10.2% -> 11.8/4.2/17.8/6.1%), CD 1-8% lower, NC and F1
# higher (a thin-walled lid: CD +0.3%, fewer off-normal too). Clean clouds lose by it (CD +3-6%: the
# umbrella pulls convex parts in, volume -0.2 to -0.4%); 1.0 took noisy volumes down by up to 1.6%.
NOISY_SMOOTHING = 0.3
# A star's triangle faces its mean normal when cos > this (the clean's graph test: 89.9 degrees).
MIN_FACING = 1e-3
# Angles around a vertex that sum to one turn within this (radians) do.
TURN_TOLERANCE = 1e-6


@dataclass(frozen=True)
class SnapInfo:
    """What :func:`snap_to_surface` did.

    Attributes
    ----------
    moved : int
        Vertices moved.
    held : int
        Vertices held where they were because a move broke a rule (module docstring).
    max_move : float
        Largest move, in mesh units.
    volume_change : float
        Signed, relative to the input's volume.
    rounds : int
        Crossing tests run.
    """

    moved: int
    held: int
    max_move: float
    volume_change: float
    rounds: int

    def as_dict(self) -> dict:
        return asdict(self)


def _graph_stars(vertices, triangles):
    """(n,) bool: the vertices whose star is a graph over its mean (area-weighted) normal."""
    normals = _normals(vertices, triangles)
    n = len(vertices)
    direction = vertex_normals(vertices, triangles)  # zero where the star has no area
    graph = direction.any(axis=1)
    turn = np.zeros(n)
    for c in range(3):
        at, after, before = triangles[:, c], triangles[:, (c + 1) % 3], triangles[:, (c + 2) % 3]
        d = direction[at]
        facing = np.einsum("ij,ij->i", normals, d) > MIN_FACING * np.linalg.norm(normals, axis=1)
        graph[at[~facing]] = False
        u, w = vertices[after] - vertices[at], vertices[before] - vertices[at]
        u = u - np.einsum("ij,ij->i", u, d)[:, None] * d
        w = w - np.einsum("ij,ij->i", w, d)[:, None] * d
        turn += np.bincount(at, np.arctan2(np.einsum("ij,ij->i", np.cross(u, w), d), np.einsum("ij,ij->i", u, w)),
                            minlength=n)
    return graph & (np.abs(turn - 2 * np.pi) < TURN_TOLERANCE)


def _star_corners(triangles, centres):
    """The vertices of the triangles around ``centres`` ((n,) bool)."""
    return triangles[centres[triangles].any(axis=1)].reshape(-1)


def _least_squares_fit(surface, vertices, triangles, smoothing: float, fit: str = "faces"):
    """Vertices moved to fit ``surface`` in least squares (module docstring); (n, 3) float64.
    ``fit="vertices"``: the residuals at the vertices alone, one full step (onto ``surface``
    where ``smoothing`` is 0)."""
    import open3d as o3d
    from scipy.sparse import coo_matrix

    # About the surface's centre (map coordinates); the vertices and their checks stay in float64.
    scene, origin = centred_scene(*surface)
    planes = face_normals(*surface)
    face_points, iterations, damping = (FACE_POINTS, ITERATIONS, DAMPING) if fit == "faces" \
        else (FACE_POINTS[:0], 1, 1.0)
    n = len(vertices)
    # A vertex's weight in each face point is its barycentric coordinate there: its normal
    # equations sum the residuals times those, over the sum of their squares.
    weight_squares = np.ones(n)
    for c in range(3):
        weight_squares += np.bincount(triangles[:, c], minlength=n) * np.sum(face_points[:, c] ** 2)
    if smoothing:
        edges = triangles[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2)
        adjacency = coo_matrix((np.ones(len(edges)), (edges[:, 0], edges[:, 1])), shape=(n, n)).tocsr()
        adjacency = ((adjacency + adjacency.T) > 0).astype(np.float64)
        neighbours = np.asarray(adjacency.sum(axis=1)).ravel()
    fitted = vertices.copy()
    for step in range(iterations):
        points = np.vstack([fitted, np.einsum("bk,tkd->tbd", face_points, fitted[triangles]).reshape(-1, 3)])
        if step % QUERY_EVERY == 0:
            answer = scene.compute_closest_points(o3d.core.Tensor((points - origin).astype(np.float32)))
            nearest = answer["points"].numpy().astype(np.float64) + origin
            normal = planes[answer["primitive_ids"].numpy().astype(np.int64)]
            residual = nearest - points
        else:
            residual = np.einsum("ij,ij->i", nearest - points, normal)[:, None] * normal
        face_residual = residual[n:].reshape(len(triangles), len(face_points), 3)
        pull = residual[:n].copy()
        for c in range(3):
            share = np.einsum("b,tbd->td", face_points[:, c], face_residual)
            pull += np.stack([np.bincount(triangles[:, c], share[:, k], minlength=n) for k in range(3)], axis=1)
        if smoothing:  # a pull towards the mean of the neighbours, weighted like the fit's
            pull += smoothing * weight_squares[:, None] * (adjacency @ fitted / neighbours[:, None] - fitted)
        fitted += damping * pull / ((1 + smoothing) * weight_squares)[:, None]
    return fitted


def snap(mesh, surface, *, voxel: float | None = None, max_move: float = MAX_MOVE, max_turn: float = MAX_TURN,
         smoothing: float = 0.0):
    """A copy of a watertight surface with its vertices fitted to ``surface`` where no guarantee breaks.

    Parameters
    ----------
    mesh : open3d.geometry.TriangleMesh or (vertices, triangles)
        Closed, manifold, outward-oriented, no crossing triangles (a cleaned VoroMesh surface).
    surface : open3d.geometry.TriangleMesh or (vertices, triangles)
        What ``mesh`` approximates (the input mesh of a fit, the target surface of a cloud).
    voxel : float, optional
        The unit of ``max_move``: the grid's voxel (``VoroMesh.voxel``); default estimated from
        the triangles (:func:`voro3d.cleaning.voxel_size`, 0.90-1.21 of it on the dev meshes).
    max_move, max_turn, smoothing
        See :func:`snap_to_surface`.

    Returns
    -------
    open3d.geometry.TriangleMesh
        Same triangles, with vertex normals; closed, manifold, outward-oriented, no crossing triangles.

    Examples
    --------
    >>> shape, _ = voro3d.fit(mesh, grid=32)  # doctest: +SKIP
    >>> fitted = voro3d.snap(shape.to_open3d(), mesh, voxel=shape.voxel)  # doctest: +SKIP
    >>> fitted = shape.to_open3d(surface=mesh)  # the same at extraction (what reconstruct does)  # doctest: +SKIP
    """
    from .cleaning import voxel_size
    from .io import to_triangle_mesh

    vertices, triangles = mesh_arrays(mesh)
    voxel = voxel_size(vertices, triangles) if voxel is None else voxel
    vertices, _ = snap_to_surface(vertices, triangles, surface, voxel=voxel,
                                  max_move=max_move, max_turn=max_turn, smoothing=smoothing)
    return to_triangle_mesh(vertices, triangles, normals=True)


def snap_to_surface(vertices, triangles, surface, *, voxel: float, max_move: float = MAX_MOVE,
                    max_turn: float = MAX_TURN, smoothing: float = 0.0, fit: str = "faces", fixed=None):
    """Vertices moved to fit ``surface`` where no guarantee breaks.

    Parameters
    ----------
    vertices : (n, 3) float64
    triangles : (t, 3) int64
        Closed, manifold, outward-oriented, no crossing triangles (a cleaned VoroMesh surface).
    surface : open3d.geometry.TriangleMesh or (vertices, triangles)
        The target surface, same units; need not be closed.
    voxel : float
        The unit of ``max_move``, in mesh units: the fit grid's voxel (``VoroMesh.voxel``, as
        ``VoroMesh.to_open3d`` passes it), or the clean's estimate of it (:func:`voro3d.cleaning.voxel_size`).
    max_move : float
        Largest move of a vertex, in voxels: every point of the result is within it of the input
        and every point of the input within it of the result.
    max_turn : float
        A triangle's normal turns by less than this, degrees, in (0, 90].
    smoothing : float
        Weight, against the fit, of a pull of each vertex towards the mean of its neighbours
        (``NOISY_SMOOTHING`` for a noisy target, whose bumps the fit would follow); >= 0.
    fit : {"faces", "vertices"}
        What fits ``surface``: points of every face and the vertices, in least squares (module
        docstring), or the vertices alone, each moved to its nearest point of ``surface``, with
        no limit on how thin a triangle gets: for triangles split about as fine as the facets of
        ``surface`` (``VoroMesh.to_open3d``'s ``refine`` past one split), whose chords no longer
        cut into it and which follow its facets, thin ones too. 10^6 true-normal points, split
        twice (``benchmarks/results/large.md``): with the angle limit, 8,020 of homer's 168k vertices
        were held (6,800 by the limit alone), and the triangles around them carried 88% of the
        squared distance to the target; without, CD / NC (5 evaluation seeds) 0.4217 / 0.9935 ->
        0.4206 / 0.9955 (Poisson depth 9: 0.4195 / 0.9965), armadillo 0.4585 / 0.9854 -> 0.4577 /
        0.9864; homer's triangles under 5 degrees 2.0 -> 2.7% (Poisson's own 5.0%).
    fixed : (n,) bool, optional
        Vertices that stay where they are.

    Returns
    -------
    vertices : (n, 3) float64
        The triangles are unchanged. Vertices at a position another vertex shares (sheets that
        touch at a duplicated vertex) stay where they are.
    info : SnapInfo

    Raises
    ------
    ValueError
        Bad arrays, or a parameter out of range (named).
    """
    from .cleaning import shared_positions

    vertices, triangles = mesh_arrays((vertices, triangles))
    target = mesh_arrays(surface, "surface")
    if not (np.isfinite(voxel) and voxel > 0):
        raise ValueError(f"voxel must be finite and > 0, got {voxel}")
    if not (np.isfinite(max_move) and max_move >= 0):
        raise ValueError(f"max_move must be finite and >= 0, got {max_move}")
    if not (np.isfinite(smoothing) and smoothing >= 0):
        raise ValueError(f"smoothing must be finite and >= 0, got {smoothing}")
    if not 0 < max_turn <= 90:
        raise ValueError(f"max_turn must be in (0, 90] degrees, got {max_turn}")
    if fit not in ("faces", "vertices"):
        raise ValueError(f"fit must be 'faces' or 'vertices', got {fit!r}")
    step = _least_squares_fit(target, vertices, triangles, smoothing, fit) - vertices
    length = np.linalg.norm(step, axis=1)
    limit = max_move * voxel
    step *= np.minimum(1.0, limit / np.maximum(length, 1e-300))[:, None]
    moving = (length > 0) & ~shared_positions(vertices)
    if fixed is not None:
        fixed = np.asarray(fixed, bool)
        if fixed.shape != (len(vertices),):
            raise ValueError(f"fixed must be one bool per vertex, shape ({len(vertices)},), got {fixed.shape}")
        moving &= ~fixed
    graph_before = _graph_stars(vertices, triangles)
    moving[_star_corners(triangles, ~graph_before)] = False  # stars that are not graphs stay as they are
    wanted = int(moving.sum())
    before_normals = _normals(vertices, triangles)
    # Fitted by its vertices, a mesh is split about as fine as the target's facets and follows them,
    # thin triangles too (see ``fit``); fitted by its faces, it keeps its shapes.
    min_angles = np.minimum(smallest_angles(vertices, triangles), MIN_ANGLE) if fit == "faces" \
        else np.zeros(len(triangles))
    cos_turn = np.cos(np.radians(max_turn))

    result = np.where(moving[:, None], vertices + step, vertices)

    def hold(corners):
        """Put ``corners`` back where they were; the triangles whose shape that changes."""
        moving[corners] = False
        result[corners] = vertices[corners]
        touched = np.zeros(len(vertices), bool)
        touched[corners] = True
        return touched[triangles].any(axis=1)

    def hold_bad_shapes(check):
        """Hold back the corners of triangles that turn too far or get too thin, and of stars that
        stop being graphs, until none do (holding vertices brings their triangles back towards the
        input); the vertices held. Only the triangles in ``check`` ((t,) bool) and the stars of
        their corners are tested, then only those that a hold changed: a shape changes only
        with the places of its corners."""
        held = np.zeros(len(vertices), bool)
        while check.any():
            tested = triangles[check]
            normals = _normals(result, tested)
            cosine = np.einsum("ij,ij->i", before_normals[check], normals)
            length = np.linalg.norm(before_normals[check], axis=1) * np.linalg.norm(normals, axis=1)
            bad = (cosine <= cos_turn * length) | (smallest_angles(result, tested) < min_angles[check])
            # A star lies within the triangles that touch its centre, so its test there is its own.
            centres = np.zeros(len(vertices), bool)
            centres[tested] = True
            stars = triangles[centres[triangles].any(axis=1)]
            corners = np.concatenate([tested[bad].reshape(-1),
                                      _star_corners(stars, centres & ~_graph_stars(result, stars))])
            corners = corners[moving[corners]]
            if not len(corners):
                break
            held[corners] = True
            check = hold(corners)
        return held

    # Shapes first (cheap, vectorised), then crossings (exact); after a crossing holds vertices
    # back, the triangles around them are checked again, both ways, until a pass holds none.
    changed = moving[triangles].any(axis=1)
    check = changed.copy()
    rounds = 0
    while True:
        held = hold_bad_shapes(check)
        changed |= held[triangles].any(axis=1)
        if not changed.any():
            break
        crossing, touching = self_intersections(result, triangles, changed=changed)
        rounds += 1
        # Touching at a shared position is the input's own (sheets that meet at a duplicated vertex)
        # unless a move made it: the moved corners are held either way.
        corners = triangles[np.concatenate([crossing, touching]).reshape(-1)].reshape(-1)
        corners = corners[moving[corners]]
        if not len(corners):  # pairs of the input, left as they were
            break
        changed = check = hold(corners)
    info = SnapInfo(moved=int(moving.sum()), held=wanted - int(moving.sum()),
                    max_move=float(np.linalg.norm(result - vertices, axis=1).max()),
                    volume_change=signed_volume(result, triangles) / signed_volume(vertices, triangles) - 1,
                    rounds=rounds)
    return result, info
