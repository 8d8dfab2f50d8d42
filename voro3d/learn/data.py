"""Training shapes made here: random CAD-like solids, their SDF grids and surface samples.

Nothing is downloaded. :func:`cad_shape` builds ABC-like parts with manifold3d booleans (boxes,
chamfered and rounded boxes, cylinders, cones, spheres, tori, tubes and prisms, unions of a few
of them minus holes, pockets and slots), :func:`thin_shape` thin-walled shells and plates,
:func:`organic_shape` smooth bumpy bodies (the level set of a sum of stretched Gaussians with
ripples), optionally cut by planes into sharp-smooth mixes; all deterministic given a seed. :func:`build_dataset` puts
each shape (or each closed mesh of an optional folder) in the fit frame and caches what training
needs as one ``.npz`` per shape:

``vertices (v, 3) float64``, ``triangles (t, 3) int32``
    The watertight mesh in the fit frame: stage 2 labels predicted cells with its inside test.
``sdf_<g> (g, g, g) float32``
    :func:`voro3d.queries.sdf_grid` for every requested grid size ``g``, negative inside.
``samples (m, 3) float32``
    Area-uniform surface samples, the targets of VoroLoss.
"""
from __future__ import annotations

import functools
import json
import logging
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .._validate import positive_int
from ..frames import fit_frame
from ..io import MESH_SUFFIXES, atomic_path, load_mesh, mesh_arrays
from ..queries import InsideOutside, sdf_grid
from ..sampling import sample_surface

__all__ = ["DatasetSpec", "ShapeSet", "build_dataset", "cad_shape", "organic_shape", "thin_shape"]

log = logging.getLogger(__name__)

# Segments of every circle: enough that facets stay below a 64^3 voxel on the largest parts.
CIRCLE_SEGMENTS = 64
# A part thinner than this fraction of its bounding box is mostly degenerate at 32^3; redraw it.
MIN_FILL = 0.02
DATASET_VERSION = 2
# Nodes per axis of the field an organic shape is meshed from: finer than a 64^3 fit grid.
ORGANIC_RESOLUTION = 112


def _rotation(rng: np.random.Generator, *, axis_aligned: bool) -> np.ndarray:
    """A random rotation matrix: a signed axis permutation (CAD parts are often grid-aligned) or uniform."""
    if axis_aligned:
        matrix = np.eye(3)[rng.permutation(3)] * rng.choice([-1.0, 1.0], size=3)
        return matrix * np.linalg.det(matrix)  # a reflection times -1 is a rotation in 3D
    from scipy.spatial.transform import Rotation

    return Rotation.random(random_state=rng).as_matrix()


def _place(solid, rotation: np.ndarray, translation):
    """``solid`` rotated about the origin, then translated."""
    return solid.transform(np.hstack([rotation, np.asarray(translation, float)[:, None]]))


def _primitive(rng: np.random.Generator, size: float):
    """One random solid centred on the origin whose largest extent is about ``size``."""
    from manifold3d import CrossSection, Manifold

    kind = rng.choice(["box", "chamfer_box", "round_box", "cylinder", "cone", "sphere", "torus", "tube", "prism"],
                      p=[0.16, 0.12, 0.1, 0.18, 0.1, 0.08, 0.08, 0.1, 0.08])
    half = size / 2 * rng.uniform(0.3, 1.0, size=3)
    half[rng.integers(3)] = size / 2
    if kind == "box":
        return Manifold.cube(2 * half, center=True)
    if kind == "chamfer_box":
        # Convex hull of the box shrunk by the chamfer along each pair of axes: every edge cut at 45 degrees.
        cut = rng.uniform(0.1, 0.5) * half.min()
        corners = np.array([[i, j, k] for i in (-1, 1) for j in (-1, 1) for k in (-1, 1)], float)
        shrink = cut * (1.0 - np.eye(3))
        return Manifold.hull_points(np.concatenate([corners * (half - s) for s in shrink]))
    if kind == "round_box":
        radius = rng.uniform(0.1, 0.5) * half.min()
        ball = Manifold.sphere(radius, CIRCLE_SEGMENTS // 2)
        corners = np.array([[i, j, k] for i in (-1, 1) for j in (-1, 1) for k in (-1, 1)], float)
        return Manifold.batch_hull([ball.translate(c * (half - radius)) for c in corners])
    if kind == "cylinder":
        return Manifold.cylinder(2 * half[2], half[:2].min(), circular_segments=CIRCLE_SEGMENTS, center=True)
    if kind == "cone":
        radius = half[:2].max()
        return Manifold.cylinder(2 * half[2], radius, radius * rng.choice([0.0, rng.uniform(0.2, 0.8)]),
                                 circular_segments=CIRCLE_SEGMENTS, center=True)
    if kind == "sphere":
        return Manifold.sphere(size / 2 * rng.uniform(0.5, 1.0), CIRCLE_SEGMENTS)
    if kind == "torus":
        major = size / 2 * rng.uniform(0.6, 0.8)
        minor = major * rng.uniform(0.15, 0.4)
        ring = CrossSection.circle(minor, CIRCLE_SEGMENTS // 2).translate([major, 0.0])
        return Manifold.revolve(ring, CIRCLE_SEGMENTS)
    if kind == "tube":
        outer = half[:2].min()
        cylinder = Manifold.cylinder(2 * half[2], outer, circular_segments=CIRCLE_SEGMENTS, center=True)
        bore = Manifold.cylinder(4 * half[2], outer * rng.uniform(0.4, 0.8), circular_segments=CIRCLE_SEGMENTS,
                                 center=True)
        return cylinder - bore
    # A prism on a random convex or L-shaped profile.
    if rng.random() < 0.5:
        angles = np.sort(rng.uniform(0, 2 * np.pi, rng.integers(3, 7)))
        profile = np.stack([np.cos(angles) * half[0], np.sin(angles) * half[1]], axis=1)
        section = CrossSection.hull_points(profile)
    else:
        a, b = half[0] * rng.uniform(0.3, 0.7), half[1] * rng.uniform(0.3, 0.7)
        section = CrossSection([[[-half[0], -half[1]], [half[0], -half[1]], [half[0], -b],
                                 [-a, -b], [-a, half[1]], [-half[0], half[1]]]])
    return Manifold.extrude(section, 2 * half[2]).translate([0.0, 0.0, -half[2]])


def _cutter(rng: np.random.Generator, size: float):
    """A hole, pocket, slot or dimple to subtract, centred on the origin."""
    from manifold3d import Manifold

    kind = rng.choice(["hole", "pocket", "slot", "dimple"], p=[0.45, 0.25, 0.15, 0.15])
    if kind == "hole":
        return Manifold.cylinder(3 * size, size * rng.uniform(0.06, 0.25), circular_segments=CIRCLE_SEGMENTS,
                                 center=True)
    if kind == "pocket":
        return Manifold.cube(size * rng.uniform([0.15, 0.15, 0.1], [0.6, 0.6, 0.5]), center=True)
    if kind == "slot":
        width = size * rng.uniform(0.05, 0.15)
        return Manifold.cube([size * rng.uniform(0.3, 1.0), width, 3 * size], center=True)
    return Manifold.sphere(size * rng.uniform(0.1, 0.3), CIRCLE_SEGMENTS // 2)


def cad_shape(seed: int) -> tuple[np.ndarray, np.ndarray]:
    """A random CAD-like part: a base solid, up to three added solids, up to four cutters.

    Added solids and cutters sit at random points of the base's bounding box, most of them
    axis-aligned; the whole part is then rotated, by a signed axis permutation in 60% of the
    parts (grid-aligned faces, as in ABC) and uniformly otherwise. Parts that come out empty or
    thinner than ``MIN_FILL`` of their bounding box are redrawn from the same generator.

    Parameters
    ----------
    seed : int
        Seed of ``numpy.random.default_rng``; the same seed gives the same part.

    Returns
    -------
    vertices : (v, 3) float64
        Arbitrary units (about unit size).
    triangles : (t, 3) int64
        Closed, manifold, outward-oriented (manifold3d guarantees it).
    """
    from manifold3d import Manifold, OpType

    rng = np.random.default_rng(seed)
    while True:
        base = _primitive(rng, 1.0)
        low, high = (np.asarray(v) for v in np.split(np.asarray(base.bounding_box()), 2))
        added = [base]
        for _ in range(rng.integers(0, 4)):
            anchor = rng.uniform(low, high)
            part = _primitive(rng, rng.uniform(0.25, 0.7))
            added.append(_place(part, _rotation(rng, axis_aligned=rng.random() < 0.8), anchor))
        solid = Manifold.batch_boolean(added, OpType.Add)
        low, high = (np.asarray(v) for v in np.split(np.asarray(solid.bounding_box()), 2))
        cutters = [_place(_cutter(rng, float((high - low).max())), _rotation(rng, axis_aligned=rng.random() < 0.8),
                          rng.uniform(low, high)) for _ in range(rng.integers(0, 5))]
        if cutters:
            solid = solid - Manifold.batch_boolean(cutters, OpType.Add)
        solid = _place(solid, _rotation(rng, axis_aligned=rng.random() < 0.6), np.zeros(3))
        if solid.is_empty() or solid.status().name != "NoError":
            continue
        low, high = (np.asarray(v) for v in np.split(np.asarray(solid.bounding_box()), 2))
        if solid.volume() < MIN_FILL * np.prod(high - low):
            continue
        mesh = solid.to_mesh()
        return np.asarray(mesh.vert_properties, np.float64)[:, :3], np.asarray(mesh.tri_verts, np.int64)


def thin_shape(seed: int) -> tuple[np.ndarray, np.ndarray]:
    """A random thin-walled part: an opened shell, or plates, fins and ribs, walls about 1-3 voxels at 64^3.

    A shell is a solid minus its copy shrunk about its centre by the wall thickness along every
    axis, usually cut open by a box; plates are two to five thin boxes or discs, mostly
    axis-aligned, joined at random points of each other's bounding boxes. Holes may pierce
    either. The walls (0.02-0.07 of a part of unit size) are what neither the shells nor the
    solids of :func:`cad_shape` have: surfaces a voxel or two apart with opposite normals.

    Parameters
    ----------
    seed : int

    Returns
    -------
    vertices : (v, 3) float64
        Arbitrary units (about unit size).
    triangles : (t, 3) int64
        Closed, manifold, outward-oriented.
    """
    from manifold3d import Manifold, OpType

    rng = np.random.default_rng(seed)
    while True:
        wall = rng.uniform(0.02, 0.07)
        if rng.random() < 0.5:
            base = _primitive(rng, 1.0)
            low, high = (np.asarray(v) for v in np.split(np.asarray(base.bounding_box()), 2))
            centre, half = (low + high) / 2, (high - low) / 2
            inner = base.translate(-centre).scale(np.maximum(half - wall, 0.1 * half) / half).translate(centre)
            solid = base - inner
            if rng.random() < 0.7:
                opening = Manifold.cube(2 * half * rng.uniform(0.5, 1.2, 3), center=True)
                side = rng.choice([-1.0, 1.0], 3) * (np.arange(3) == rng.integers(3))  # one face, pushed out
                solid = solid - opening.translate(centre + half * side)
        else:
            plates = []
            low, high = -0.5 * np.ones(3), 0.5 * np.ones(3)
            for _ in range(rng.integers(2, 6)):
                extent = rng.uniform(0.3, 1.0, 3)
                extent[rng.integers(3)] = wall
                if rng.random() < 0.3:
                    plate = Manifold.cylinder(wall, extent.max() / 2, circular_segments=CIRCLE_SEGMENTS, center=True)
                else:
                    plate = Manifold.cube(extent, center=True)
                anchor = rng.uniform(low, high) if plates else np.zeros(3)
                plates.append(_place(plate, _rotation(rng, axis_aligned=rng.random() < 0.8), anchor))
                low, high = (np.asarray(v) for v in np.split(np.asarray(plates[-1].bounding_box()), 2))
            solid = Manifold.batch_boolean(plates, OpType.Add)
        low, high = (np.asarray(v) for v in np.split(np.asarray(solid.bounding_box()), 2))
        holes = [_place(_cutter(rng, float((high - low).max())), _rotation(rng, axis_aligned=True),
                        rng.uniform(low, high)) for _ in range(rng.integers(0, 3))]
        if holes:
            solid = solid - Manifold.batch_boolean(holes, OpType.Add)
        solid = _place(solid, _rotation(rng, axis_aligned=rng.random() < 0.6), np.zeros(3))
        if solid.is_empty() or solid.status().name != "NoError" or solid.volume() < 1e-4:
            continue
        mesh = solid.to_mesh()
        return np.asarray(mesh.vert_properties, np.float64)[:, :3], np.asarray(mesh.tri_verts, np.int64)


def organic_shape(seed: int, *, cut: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """A random smooth, bumpy body, like the scanned and sculpted meshes of Thingi or animals.

    The level set ``f = 1/2`` of ``f(x) = sum_i exp(-|A_i (x - c_i)|^2)`` over two to eight
    randomly stretched and rotated Gaussians, rippled by three random plane waves, meshed by
    Marching Cubes on a ``ORGANIC_RESOLUTION^3`` grid. Bodies that come out thinner than
    ``MIN_FILL`` of their bounding box are redrawn from the same generator.

    Parameters
    ----------
    seed : int
    cut : bool, keyword-only
        Intersect the body with one to three random half-spaces and drill a hole through it
        half of the time: smooth surfaces meeting flat ones at sharp edges, as in sculpted or
        machined organic parts. (The zero set of the maximum of two implicit functions is the
        intersection of their insides, whatever their scales.)

    Returns
    -------
    vertices : (v, 3) float64
        Arbitrary units (about unit size).
    triangles : (t, 3) int64
        Closed and outward-oriented (each component).
    """
    from ..baselines import marching_cubes
    from ..sampling import grid_nodes

    rng = np.random.default_rng(seed)
    nodes = grid_nodes(ORGANIC_RESOLUTION) * 1.6  # room around the blobs: the level set never meets the border
    while True:
        field = np.zeros(nodes.shape[0])
        for _ in range(rng.integers(2, 9)):
            centre = rng.uniform(-0.5, 0.5, 3)
            stretch = _rotation(rng, axis_aligned=False) * (1.0 / rng.uniform(0.12, 0.45, 3))[:, None]
            field += np.exp(-np.square((nodes - centre) @ stretch.T).sum(axis=1))
        for _ in range(3):
            wave = rng.normal(size=3)
            wave *= rng.uniform(6.0, 20.0) / np.linalg.norm(wave)
            field += rng.uniform(0.0, 0.06) * np.sin(nodes @ wave + rng.uniform(0, 2 * np.pi))
        sdf = 0.5 - field
        if cut:
            for _ in range(rng.integers(1, 4)):
                normal = rng.normal(size=3)
                sdf = np.maximum(sdf, nodes @ (normal / np.linalg.norm(normal)) - rng.uniform(-0.2, 0.4))
            if rng.random() < 0.5:
                axis = rng.normal(size=3)
                axis /= np.linalg.norm(axis)
                offset = nodes - rng.uniform(-0.3, 0.3, 3)
                radial = np.linalg.norm(offset - np.outer(offset @ axis, axis), axis=1)
                sdf = np.maximum(sdf, rng.uniform(0.04, 0.15) - radial)
        sdf = sdf.reshape((ORGANIC_RESOLUTION,) * 3)
        if sdf.min() >= 0 or (sdf[[0, -1]] <= 0).any() or (sdf[:, [0, -1]] <= 0).any() or (sdf[..., [0, -1]] <= 0).any():
            continue
        vertices, triangles = marching_cubes(sdf)
        extent = vertices.max(axis=0) - vertices.min(axis=0)
        if (sdf < 0).mean() * 3.2**3 < MIN_FILL * np.prod(extent):
            continue
        return vertices, triangles


@dataclass(frozen=True)
class DatasetSpec:
    """What :func:`build_dataset` caches.

    A cache is reused when the fields that decide a file's content match (:data:`CONTENT_KEYS`);
    the counts may differ, since shape ``i`` of a kind is the same file in every set, so a cache
    grows (or serves a smaller set) without being rebuilt.
    """

    n_shapes: int
    grids: tuple[int, ...]
    seed: int
    n_samples: int
    mesh_dir: str | None
    n_organic: int = 0
    n_thin: int = 0
    n_cut: int = 0

    def as_dict(self) -> dict:
        return {"version": DATASET_VERSION, "n_shapes": self.n_shapes, "n_organic": self.n_organic,
                "n_thin": self.n_thin, "n_cut": self.n_cut, "grids": list(self.grids), "seed": self.seed,
                "n_samples": self.n_samples, "mesh_dir": self.mesh_dir}


# Spec fields that decide the content of a cached file.
CONTENT_KEYS = ("version", "grids", "seed", "n_samples", "mesh_dir")


def _shape_record(vertices, triangles, grids, n_samples, seed) -> dict:
    """The cached arrays of one shape: fit-frame mesh, SDF grids, surface samples."""
    frame = fit_frame((vertices, triangles))
    vertices = frame.apply(vertices)
    # Building the inside test once checks the mesh is closed before any grid is computed.
    InsideOutside((vertices, triangles))
    record = {"vertices": vertices, "triangles": triangles.astype(np.int32)}
    for grid in grids:
        record[f"sdf_{grid}"] = sdf_grid((vertices, triangles), grid)
    record["samples"] = sample_surface((vertices, triangles), n_samples, seed=seed)[0].astype(np.float32)
    return record


def build_dataset(out_dir, n_shapes: int, *, grid=(32, 64), seed: int = 0, n_samples: int = 50_000,
                  mesh_dir=None, n_organic: int = 0, n_thin: int = 0, n_cut: int = 0) -> list[Path]:
    """Generate (or reuse) the cached training set in ``out_dir``.

    Shape ``i`` is ``cad_shape`` of a seed derived from ``(seed, i)``, so a cache can be grown
    or rebuilt after a crash and every file stays the same; files already present are kept.
    ``n_organic`` :func:`organic_shape` bodies follow, with seeds from ``(seed, "organic")``, then
    ``n_thin`` :func:`thin_shape` parts and ``n_cut`` cut organic bodies (``organic_shape(...,
    cut=True)``), each kind with its own seed sequence.
    Closed meshes from ``mesh_dir`` follow the generated shapes (sorted by name); open or
    unreadable ones are skipped with a warning, since no inside test exists for them.

    Parameters
    ----------
    out_dir : str or os.PathLike
        Created if needed; holds ``shape_<i>.npz`` files and ``index.json`` (the spec).
    n_shapes : int
        Generated shapes, ``>= 0``.
    grid : int or sequence of int, keyword-only
        SDF grid sizes to cache (each ``>= 4``).
    seed : int, keyword-only
        Master seed.
    n_samples : int, keyword-only
        Surface samples per shape.
    mesh_dir : str or os.PathLike, optional, keyword-only
        A folder of real meshes to add (any :data:`voro3d.io.MESH_SUFFIXES`).
    n_organic, n_thin, n_cut : int, keyword-only
        Generated organic bodies, thin-walled parts and cut organic bodies, each ``>= 0``.

    Returns
    -------
    list of pathlib.Path
        The ``.npz`` files, generated shapes first.

    Raises
    ------
    ValueError
        Bad sizes, or ``out_dir`` holds a cache built with different content fields
        (:data:`CONTENT_KEYS`).
    FileNotFoundError
        ``mesh_dir`` does not exist.
    """
    from tqdm import tqdm

    n_shapes = positive_int(n_shapes, "n_shapes", minimum=0)
    grids = tuple(sorted({positive_int(g, "grid", minimum=4) for g in np.atleast_1d(grid).tolist()}))
    n_samples = positive_int(n_samples, "n_samples")
    n_organic = positive_int(n_organic, "n_organic", minimum=0)
    n_thin = positive_int(n_thin, "n_thin", minimum=0)
    n_cut = positive_int(n_cut, "n_cut", minimum=0)
    mesh_files = []
    if mesh_dir is not None:
        mesh_dir = Path(mesh_dir)
        if not mesh_dir.is_dir():
            raise FileNotFoundError(f"mesh_dir {mesh_dir} is not a folder")
        mesh_files = sorted(p for p in mesh_dir.iterdir() if p.suffix.lower() in MESH_SUFFIXES)
    spec = DatasetSpec(n_shapes, grids, int(seed), n_samples, None if mesh_dir is None else str(mesh_dir.resolve()),
                       n_organic, n_thin, n_cut)
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    index = out_dir / "index.json"
    if index.is_file():
        cached = json.loads(index.read_text())
        wanted = spec.as_dict()
        if any(cached.get(key) != wanted[key] for key in CONTENT_KEYS):
            built = {key: cached.get(key) for key in CONTENT_KEYS}
            raise ValueError(f"out_dir {out_dir} holds a dataset built with {built}, "
                             f"not { {key: wanted[key] for key in CONTENT_KEYS} }")

    seeds = np.random.SeedSequence(seed).generate_state(n_shapes + len(mesh_files), dtype=np.uint32)
    files = []
    makers = {"organic": (organic_shape, np.random.SeedSequence([seed, 0x0A6]).generate_state(n_organic, np.uint32)),
              "thin": (thin_shape, np.random.SeedSequence([seed, 0x7A1]).generate_state(n_thin, np.uint32)),
              "cut": (functools.partial(organic_shape, cut=True),
                      np.random.SeedSequence([seed, 0xC07]).generate_state(n_cut, np.uint32))}
    jobs = [(f"shape_{i:05d}.npz", i, None) for i in range(n_shapes)]
    jobs += [(f"{kind}_{i:05d}.npz", i, kind) for kind in makers for i in range(len(makers[kind][1]))]
    jobs += [(f"mesh_{path.stem}.npz", n_shapes + j, path) for j, path in enumerate(mesh_files)]
    for name, i, path in tqdm(jobs, desc="shapes", unit="shape", leave=False):
        target = out_dir / name
        if not target.is_file():
            try:
                if path is None:
                    vertices, triangles, shape_seed = *cad_shape(int(seeds[i])), int(seeds[i])
                elif isinstance(path, str):
                    make, kind_seeds = makers[path]
                    vertices, triangles, shape_seed = *make(int(kind_seeds[i])), int(kind_seeds[i])
                else:
                    vertices, triangles, shape_seed = *mesh_arrays(load_mesh(path)), int(seeds[i])
                record = _shape_record(vertices, triangles, grids, n_samples, shape_seed)
            except ValueError as error:
                if not isinstance(path, Path):
                    raise
                log.warning("skipping %s: %s", path, error)
                continue
            with atomic_path(target, suffix=".npz") as tmp:
                with open(tmp, "wb") as handle:
                    np.savez_compressed(handle, **record)
        files.append(target)
    with atomic_path(index, suffix=".json") as tmp:
        Path(tmp).write_text(json.dumps({**spec.as_dict(), "files": [f.name for f in files]}, indent=1))
    return files


class ShapeSet:
    """Shapes cached by :func:`build_dataset`, loaded lazily one ``.npz`` at a time.

    Parameters
    ----------
    files : sequence of path
        ``.npz`` files from :func:`build_dataset`.

    Indexing returns a dict of the arrays listed in the module docstring.
    """

    def __init__(self, files):
        self.files = [Path(f) for f in files]
        missing = [str(f) for f in self.files if not f.is_file()]
        if missing:
            raise FileNotFoundError(f"dataset files not found: {missing[:3]}{' ...' if len(missing) > 3 else ''}")

    def __len__(self) -> int:
        return len(self.files)

    def __getitem__(self, i: int) -> dict:
        with np.load(self.files[i], allow_pickle=False) as data:
            return {name: data[name] for name in data.files}
