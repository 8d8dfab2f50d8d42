"""The VoroMesh type: generators with a binary occupancy, the grid they were fitted on, save/load.

A VoroMesh knows its grid and the frame that maps its generators onto the grid's ``[-1, 1]^3``,
so its voxel is known exactly wherever it goes: the clean and the snap measure their lengths
in it. It also keeps its Delaunay triangulation once built, so labels, the point-cloud passes
and extraction share one.
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from ._validate import as_mask, as_points, trusted
from .delaunay import DEFAULT_TOLERANCE, Triangulation, triangulate
from .frames import NormalizationFrame
from .geometry import grid_voxel

__all__ = ["VoroMesh"]

@dataclass
class VoroMesh:
    """A shape as Voronoi generators with a binary occupancy.

    Attributes
    ----------
    generators : (n, 3) float64
        Generator positions, in the shape's units.
    occupancy : (n,) bool
        True for generators whose Voronoi cell is inside the shape.
    grid : int, optional
        Nodes per axis of the grid the generators were fitted or predicted on (None: unknown).
    frame : voro3d.frames.NormalizationFrame, optional
        Maps the generators' units onto the grid's ``[-1, 1]^3``; None when they are in it already.
    triangulation : voro3d.delaunay.Triangulation, optional
        The generators' Delaunay triangulation at ``DEFAULT_TOLERANCE``, built on first use and
        kept (:meth:`triangulated`).
    """

    generators: np.ndarray
    occupancy: np.ndarray
    grid: int | None = None
    frame: NormalizationFrame | None = None
    triangulation: Triangulation | None = field(default=None, repr=False, compare=False)

    def __post_init__(self):
        self.generators = as_points(self.generators, "generators")
        self.occupancy = as_mask(self.occupancy, "occupancy", self.generators.shape[0])
        if self.grid is not None:
            if isinstance(self.grid, bool) or int(self.grid) != self.grid or self.grid < 2:
                raise ValueError(f"grid must be an int >= 2 or None, got {self.grid!r}")
            self.grid = int(self.grid)
        if self.frame is not None and not isinstance(self.frame, NormalizationFrame):
            raise TypeError(f"frame must be a voro3d.frames.NormalizationFrame or None, got {type(self.frame).__name__}")
        if self.triangulation is not None and self.triangulation.site.shape[0] != self.generators.shape[0]:
            raise ValueError(f"triangulation is of {self.triangulation.site.shape[0]} generators, "
                             f"not {self.generators.shape[0]}")

    @property
    def voxel(self) -> float | None:
        """The grid's voxel in the generators' units, or None when the grid is unknown."""
        if self.grid is None:
            return None
        return grid_voxel(self.grid) / (1.0 if self.frame is None else self.frame.scale)

    def triangulated(self) -> Triangulation:
        """The generators' Delaunay triangulation (:func:`voro3d.delaunay.triangulate`), built once."""
        if self.triangulation is None:
            self.triangulation = triangulate(self.generators)
        return self.triangulation

    def relabelled(self, occupancy) -> "VoroMesh":
        """The same generators, grid, frame and triangulation with another occupancy."""
        return replace(self, occupancy=occupancy)

    def to_open3d(self, *, clean: bool = True, surface=None, smoothing: float = 0.0, refine: int = 0,
                  tolerance: float = DEFAULT_TOLERANCE):
        """The watertight surface: extracted, then cleaned, then fitted to ``surface``.

        Runs :func:`voro3d.extract.voronoi_surface`, then (``clean``)
        :func:`voro3d.cleaning.clean_surface`, then (``surface`` given)
        :func:`voro3d.snapping.snap_to_surface`, both with :attr:`voxel` as their unit (estimated
        from the triangles, :func:`voro3d.cleaning.voxel_size`, when the grid is unknown).

        Parameters
        ----------
        clean : bool
            Remove slivers, tiny faces and nearly coincident Voronoi vertices (within 0.2 voxel of
            the Voronoi faces, volume within 0.5%; every guarantee checked again). ``False`` gives
            the Voronoi faces themselves, fan-triangulated, as :func:`voro3d.extract_mesh` does.
        surface : open3d.geometry.TriangleMesh or (vertices, triangles), optional
            What the shape approximates, in the generators' units: the input mesh of a fit, a
            cloud's target surface. The vertices are then fitted to it (at most a quarter voxel
            each, where no guarantee breaks), which straightens the facets the VoroLoss fit left
            tilted (dev meshes at 32^3: triangles over 30 degrees off the input's normal 9.1% ->
            6.4%, CD -2.6%; ``benchmarks/results/clean_32_64.md``). Needs ``clean``: the
            uncleaned faces' slivers would hold most vertices back.
        smoothing : float
            The fit's pull of each vertex towards its neighbours, for a noisy ``surface``.
        refine : int
            Times the cleaned triangles are split in four (:func:`voro3d.geometry.split_triangles`:
            fewer where a split would make triangles cross) before the fit to ``surface``, which then
            shapes the surface past the grid's faces: for a ``surface`` finer than the grid (a cloud's
            target from dense points). Split once, the faces are fitted; split more, the vertices go
            onto ``surface`` (:func:`voro3d.snapping.snap_to_surface`'s ``fit``). Split once, the
            pieces of a triangle at a crease (``snapping.CREASE_DEGREES``) stay where they are, since
            a smooth ``surface`` rounds it. Needs ``surface``.
        tolerance : float
            As in :func:`voro3d.extract_mesh`.

        Returns
        -------
        open3d.geometry.TriangleMesh
            Closed, edge- and vertex-manifold, outward-oriented, no crossing triangles (when
            cleaned: tested exactly), with vertex normals.

        Raises
        ------
        ValueError
            ``surface`` without ``clean``, ``refine`` without ``surface`` or below 0, or what the
            stages refuse (named).
        """
        from .extract import voronoi_surface
        from .io import mesh_arrays, to_triangle_mesh
        from .watertight import assert_closed_manifold

        if surface is not None:
            if not clean:
                raise ValueError("surface needs clean=True: the uncleaned Voronoi faces are not fitted to a surface")
            surface = mesh_arrays(surface, "surface")
        if not (np.isfinite(smoothing) and smoothing >= 0):
            raise ValueError(f"smoothing must be finite and >= 0, got {smoothing}")
        if isinstance(refine, bool) or not isinstance(refine, (int, np.integer)) or refine < 0:
            raise ValueError(f"refine must be an int >= 0, got {refine!r}")
        if refine and surface is None:
            raise ValueError("refine needs a surface: split triangles are shaped only by the fit to one")
        # The generators were checked when the VoroMesh was made: the stages below trust them.
        with trusted():
            triangulation = self.triangulated() if tolerance == DEFAULT_TOLERANCE else None
            vertices, triangles = voronoi_surface(self.generators, self.occupancy, tolerance=tolerance,
                                                  triangulation=triangulation)
            assert_closed_manifold(vertices, triangles)
            if clean:
                from .cleaning import clean_surface

                vertices, triangles, info = clean_surface(vertices, triangles, voxel=self.voxel)
                if surface is not None:
                    from .geometry import split_triangles
                    from .snapping import CREASE_DEGREES, snap_to_surface
                    from .topology import creased_triangles

                    # Split once, the faces are fitted to a target that rounds the creases the
                    # Voronoi faces hold: the pieces of a triangle at one stay as they are (a
                    # triangle's pieces are numbered together, in its place). Split more, the
                    # vertices go onto a target as fine as they are, creases too.
                    unsplit = vertices, triangles
                    vertices, triangles, splits = split_triangles(vertices, triangles, refine)
                    fixed = None
                    if splits == 1:
                        fixed = np.zeros(len(vertices), bool)
                        fixed[triangles[np.repeat(creased_triangles(*unsplit, CREASE_DEGREES), 4)]] = True
                    # Split more than once, the faces' chords no longer cut into the surface: the vertices go onto it.
                    vertices, _ = snap_to_surface(vertices, triangles, surface, voxel=info.voxel, smoothing=smoothing,
                                                  fit="vertices" if splits > 1 else "faces", fixed=fixed)
            return to_triangle_mesh(vertices, triangles, normals=True)

    def to_polygons(self, *, tolerance: float = DEFAULT_TOLERANCE):
        """The Voronoi faces of the surface as polygons, see :func:`voro3d.extract.voronoi_polygons`."""
        from .extract import voronoi_polygons

        triangulation = self.triangulated() if tolerance == DEFAULT_TOLERANCE else None
        return voronoi_polygons(self.generators, self.occupancy, tolerance=tolerance, triangulation=triangulation)

    def save(self, path) -> None:
        """Write the VoroMesh (generators, occupancy, grid and frame when known) to a ``.npz`` file, atomically."""
        from .io import atomic_path

        arrays = dict(generators=self.generators, occupancy=self.occupancy)
        if self.grid is not None:
            arrays["grid"] = np.int64(self.grid)
        if self.frame is not None:
            arrays.update(frame_center=self.frame.center, frame_scale=np.float64(self.frame.scale))
        with atomic_path(path, suffix=".npz") as tmp:
            with open(tmp, "wb") as handle:
                np.savez_compressed(handle, **arrays)

    @classmethod
    def load(cls, path) -> "VoroMesh":
        """Read a file written by :meth:`save` (files with only ``generators`` and ``occupancy`` too)."""
        path = Path(path)
        if not path.is_file():
            raise FileNotFoundError(f"no such VoroMesh file: {path}")
        try:
            with np.load(path, allow_pickle=False) as data:
                arrays = {name: data[name] for name in data.files}
        except Exception as error:  # zip, pickle and OS errors of a corrupt or foreign file
            raise ValueError(f"{path} is not a readable .npz file: {error}") from error
        missing = {"generators", "occupancy"} - set(arrays)
        if missing:
            raise ValueError(f"{path} lacks arrays {sorted(missing)}; it holds {sorted(arrays)}")
        frame = None
        if "frame_center" in arrays and "frame_scale" in arrays:
            frame = NormalizationFrame(arrays["frame_center"], float(arrays["frame_scale"]))
        grid = int(arrays["grid"]) if "grid" in arrays else None
        return cls(arrays["generators"], arrays["occupancy"], grid=grid, frame=frame)
