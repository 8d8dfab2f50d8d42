"""Point clouds in: outlier removal, normals, a smooth target surface, the VoroLoss fit to it.

io -> pointcloud.preprocess (outliers, spacing, noise; pointcloud.scanlines thins points on scan lines
far apart) -> pointcloud.normals -> pointcloud.poisson
(closed clouds; pointcloud.denoise filters it where the noise is heavy) or pointcloud.surface
(IMLS + winding-number field for one-sided scans) -> pointcloud.reconstruct (samples, fit, the mesh
fitted to the target) -> pointcloud.colors (a coloured cloud's colours on the mesh). The choices
along the way are a :class:`CloudPlan` (``pointcloud.plan``): normals, denoise, filter, target, hull and thin,
each ``"auto"`` (decided from the cloud by the rules there) or set by the caller
(``voro3d.reconstruct(cloud, plan={"target": "imls"})``, ``voro3d reconstruct --target imls``);
``PointCloudInfo.plan`` and the ``target`` phase line give the plan as it ran, and that plan passed
back in gives the same mesh.

The steps
---------
``voro3d.reconstruct(cloud)`` takes a cloud as scanners and samplers give it: sparse or dense,
noisy, unevenly sampled, with outliers and holes, with or without normals and colours. The
VoroLoss fit never sees the raw points; it sees dense samples of a smooth *target surface* that
the points define (``voro3d/pointcloud/``):

1. **Clean** (``preprocess.py``): outliers out without flags: strays whose mean distance to 20
   neighbours is over twice their neighbours' (a local statistical filter, which keeps the sparse
   end of a 20× density ramp) and points in empty space (8th neighbour over 6× the median distance),
   unless they lie on one plane with their neighbours (a part of the surface sampled far more
   sparsely: a scanned sphere 100× denser in places keeps its sparse side); and clumps holding
   under 1% of the points whose boxes lie apart from the rest. Then the local spacing and the noise level
   (median RMS distance of 24 neighbours to their plane) are measured. A cloud that fills a
   volume (local dimension above 2.45, points × spacing³ over 0.5 of the box volume, *and* noisy
   as in 3: points in a volume have no plane at the spacing's scale; sampled surfaces read about 2
   and under 0.25, though a clean sparse slab reads like a volume on those two) is refused.
   Repeated points (merged scans) are merged first, their normals and colours averaged; points
   on scan lines far apart for their spacing along them (a LiDAR's: their 8 or 24 nearest
   neighbours lie on one line) are thinned along the lines until they do not (``scanlines``,
   plan ``thin``: unthinned, the plane fits turn about the lines and the surface comes apart in
   strips; 12 dev meshes from a 48-beam LiDAR at 3 positions, NC 0.665 -> 0.880); objects
   far apart (pieces of the neighbour graph whose boxes, grown by half their diagonal, do not
   overlap) are reconstructed one by one, each at its own grid (``separate_objects``: two unit
   spheres 50 apart gave 216 faces in all on one grid).
2. **Normals** (``normals.py``): the cloud's own, checked, not trusted: zero or NaN ones are
   repaired from their neighbours (past half, ``REPAIRABLE_SHARE``, ours are estimated instead);
   signs that disagree between neighbours on one sheet (``sign_disagreement`` over 0.1: a bare ``pcd.estimate_normals()`` reads
   0.16-0.36, consistent normals under 0.03) are re-oriented by our orienter (``orient_normals``);
   normals of a closed cloud that all point inward (winding level under -0.25) are flipped.
   ``PointCloudInfo.normals`` says which (``"given"``, ``"given, re-oriented"``, ``", flipped"``).
   Without normals: Open3D plane fits over 16 neighbours (over the 8 nearest where a point's
   neighbourhood spans both sides of a wall a few spacings thick, and half its neighbours' do too:
   ``preprocess.wall_points``; their noise is read there as well) with signs made consistent along a
   minimum spanning tree; smooth patches joined into parts, strongest tie first, each pointing
   outward by its own mean curvature (a flat one facing the rest of the cloud), so that an object
   and the table it stands on are decided apart; then the patches, and within them the points no
   probe calls right, vote on which side is open space (1-2 s for 10⁵ points; see
   ``estimate_normals``). On 30k points
   of 6 dev meshes, ``estimate_normals()`` normals give 1.00-1.03x the CD of no normals and negated
   normals the CD of the true ones (``tests/test_reconstruct.py`` checks both on a torus).
3. **Target surface**. First the side of the points: their generalized winding number (Barill
   et al. 2018) just behind and in front of them reads about 0.5 for a cloud that encloses a
   volume, about 0 for an open, one-sided scan, and 1.5 on the wall of a cavity whose normals
   the bending rule turned out of it (a hollow ball's inner sphere), which are turned back
   (``sides.cavity_walls``). When the noise exceeds 0.13 of the spacing
   (measured over 8 neighbours about a quadric, so that curvature does not count), robust IMLS
   (Kolluri 2008 with RIMLS residual weights, Öztireli et al. 2009) first smooths their normals (a
   pass over the normals alone, then one that moves the points onto their smooth surface; moving
   the points twice shrinks curved parts; the normals' pass is left out where the neighbours'
   normals mostly cancel, the two sides of a wall thinner than the noise) (``plan.denoise``:
   ``"on"``/``"off"`` force it).
   - *Closed clouds* (``poisson.py``): Open3D's screened Poisson (Kazhdan & Hoppe 2013) of the
     oriented points, at an octree depth four times finer than the grid. One indicator function
     over the whole box averages noise over many points and caps holes smoothly; with our
     normals it beat our IMLS field on every sparse, noisy, holed and outlier-ridden dev cloud
     measured, and dense ones too. Pieces nearest to fewer than 1% of the points the best piece
     has are debris and are dropped (a cloud of two real objects keeps both). Where the surface
     runs on to the box Poisson solves in (an unseen hole whose rim's normals lead it outward) it
     stops there open; it is capped on the box's face, so the target stays a closed solid and the
     fit's labels do not scatter into fins about an open winding number. A Poisson surface
     that runs off more than 8% of the diagonal past the points (a flap: normals that disagree
     across a wall thinner than the spacing) is refused for the IMLS target below. Where the
     noise is over 0.85 octree cells (the dev clouds at 0.5% and 1% of the diagonal; 0.25% reads
     0.6), the averaged surface still undulates at the kernel's scale; its face normals are then
     bilaterally filtered (Zheng et al. 2011: averaged over the 64 nearest faces, Gaussian in
     distance at twice the noise and in normal difference at 0.35, so sharp edges stay) and its
     vertices moved to fit them (``denoise.py``, ``PointCloudInfo.filtered``). On four dev shapes at
     0.5% and 1% noise: CD 3-15% lower (armadillo at 0.5%: +0.7%), NC up, fandisk's flat faces
     flat, for 1.5-3 s more a cloud.
   - *One-sided scans* (``surface.py``): the IMLS field (kernel width per point the larger of
     0.75-1.5 local spacings and 4 noise deviations) near the points and the winding number
     away from them (a distance to its level set), at the level that puts the solid behind the
     scanned side, held by the points' convex hull where the plan cuts to it (``hull.py``; auto
     for open clouds; where their rim is a crop, not a silhouette, a terrain or a flat map, also
     within a thin shell's depth: ``hull.rim_facing``), else within each point's shell depth (the
     radius of the seen surface's curvature, made the least within two field nodes and averaged
     over them, at most ``SHELL_DEPTH``, 6% of the diagonal) of the points where they do not enclose it (a
     shell under the seen side instead of a block out to the box; ``fields.py``), its pieces
     less than ``MAX_BRIDGE_GAP`` apart (what one viewpoint sees apart) joined by thin rods
     (``fields.bridge``; also the shell below), sampled on a
     grid twice as fine as the VoroMesh grid and meshed by Marching Cubes, debris removed as
     above (and stray cells after the fit, ``debris.py``).
   - *Walls thinner than the spacing, sampled on both sides* (a lid, a shell): the normals of
     the two sides mix and both targets above come out as a lumpy solid whose surface runs far
     from the points. When the target misses the points both ways (the points lie on average
     more than 0.15 spacings from it, and it more than a spacing from them; filled holes and
     noise on a closed cloud each do only one of these), a shell around the points is tried (``shell.py``: the
     blurred distance to the points at 1.6 spacings, cavities filled, then closed back to a quarter
     spacing from the points, a node thick where they are one-sided; no normals needed; its mesh
     then laid a twentieth of a spacing off each side of a wall, ``shell.hug_points``) and kept
     when its misfit (mean distance points → surface + surface → points) is under 0.7 of the
     target's (``SHEET_WIN``) and the points hold it on both faces (``SHEET_SUPPORT``: its surface
     lies within 0.78 spacings of them on average; around a wall's two sides 0.55-0.76, around one
     side of a solid or an open scan, whose depth noise alone passes the first test, 0.8 and more).
     The wall then comes out as a thin solid that follows both of its sides (a cup lid,
     abc_00000007, grid 64: CD 2.6 at 20k points and 2.3 from 6 range views, against 14.7 and
     62 before; alpha wrap 2.5). ``PointCloudInfo.target`` says which target was used.
4. **Fit**: 75·g² samples (``CLOUD_SAMPLES_PER_FACE``; a mesh fit takes 150·g²) of the target
   mesh (or, for a dense one-sided scan, the points themselves with target samples only in the
   holes); the target labels the cells. Inside cells in tiny groups apart from the rest are turned outside. The result is the usual checked,
   watertight VoroMesh: Poisson's mesh is only the target, the guarantees come from the Voronoi
   extraction.
5. **Mesh** (``pointcloud.cloud_mesh``): the surface is extracted, cleaned (:mod:`voro3d.cleaning`)
   and its vertices fitted to the target surface (``to_open3d(surface=...)``, see :mod:`voro3d.snapping`): the
   fit leaves facets tilted where its Voronoi faces could not settle, and the target is known.
   Not for a dense one-sided scan, whose VoroMesh was fitted to its own points.
6. **Colours**: a cloud with colours gives vertex colours (inverse-distance mean of the 8
   nearest points), like Open3D's Poisson, on the mesh split flat until it has about one vertex
   per point (``colors.colored_mesh``: the same surface, up to 64x the faces; the VoroMesh's few
   large faces would blur colours that vary faster than they do); a cloud without gives none.

``grid="auto"`` (the default) makes the finest voxels about 2.5 median spacings wide, between 32
and 128, in an adaptive band that coarsens to 32^3 where the target is flat (``resolution.py``); an
explicit grid finer than the spacing supports works and warns once. A target surface that
misses the points (under 90% of them on it) raises a one-line ``ValueError`` instead of returning
a junk mesh, and so does a mesh whose median point lies over a voxel off it, or that encloses
over 10 times the points' convex hull (``pointcloud/tuning.py`` holds these numbers with their measurements).
With ``progress=True`` (the ``voro3d reconstruct`` command unless ``-q``) each phase prints one line
on stderr: points kept, spacing, noise and grid; where the normals came from; the target and
why; the fit; the mesh. ``voro3d.pointcloud.reconstruct_points`` returns the VoroMesh and a
``PointCloudInfo`` (outliers removed, spacing, noise, target, grid, time split, the target surface
as a mesh); ``voro3d.pointcloud.cloud_mesh(shape, info)`` turns them into the mesh ``reconstruct`` returns.

Large clouds
------------
kNN statistics are computed a block of points at a time, in the kd-tree's leaf order
(``queries.knn_blocks``, 2.7x faster than the cloud's order), so no (n, k) table of gathered
coordinates is ever whole (where a graph or a second pass needs the neighbours, they are kept as
int32 indices, ``queries.neighbour_table``); the noise, the local dimension and the sign agreement
of given normals are medians or means over a seeded subset of 200k / 100k points (within 0.1% /
0.001 of every point's at 10^6 points; smaller clouds use all); the points' winding numbers come
from a compiled Barnes-Hut kd-tree (``_fitkernel.point_winding_number``: libigl's octree held
14.5 GB at 10^6 points). 10^6 oriented bunny points: 115 s and 14.5 GB before, 36 s and 0.96 GB
after (``benchmarks/results/large_profile.md``); clouds of 100k points give the same meshes as
before (``benchmarks/results/cloud_regression.md``). Over 250k points (``normals.ORIENT_POINTS``)
estimated normals are oriented on an evenly spread subset that size, and each other point takes its
sign from a nearby subset point on its own side: 10^6 bunny points without normals 60 s and 1.5 GB
-> 51 s and 1.2 GB, the same mesh to 0.2% CD.

Past 2 million points (``TILE_POINTS``) a cloud is reconstructed from a seeded uniform subset of
a million (``tiles.analysis_subset``): its statistics, normals and target at the 64 grid's
resolution read the same from it, and the rest add nothing at that resolution (3M bunny points all
used as samples: CD 0.599 / NC 0.985 at 141^3, against 0.590 / 0.990 from the subset's target).
Its fit runs in tiles of at most 500k samples (``tiles.py``): boxes cut at medians, each fitted
with a margin around it as a task of a local process pool or of Ray (``engine="ray"``), the
generators merged, the ones at the cuts fitted again against their final neighbours, then one
labelling and one extraction: one Voronoi diagram, so one closed mesh with no seams to stitch, the
same bytes from either engine. Objects far apart are found on the subset too. 10^7 oriented bunny
points: 45 s and 2.1 GB, closed, one piece, no crossing triangles (``benchmarks/results/tiles.md``).
"""
from .normals import estimate_normals, orient_normals, repair_normals, sign_disagreement
from .preprocess import cloud_stats, fill_ratio, local_dimension, merge_duplicates, outlier_mask, separate_objects
from .colors import colored_mesh, transfer_colors
from .plan import CloudPlan
from .scanlines import line_ratio, thin_lines
from .reconstruct import PointCloudInfo, SnapTarget, cloud_mesh, reconstruct_points
from .resolution import auto_grid, max_supported_grid
from .poisson import PoissonSurface, poisson_surface
from .surface import TargetSurface, imls, target_surface

__all__ = ["estimate_normals", "orient_normals", "repair_normals", "sign_disagreement", "cloud_stats", "fill_ratio",
           "local_dimension", "merge_duplicates", "outlier_mask", "separate_objects", "line_ratio", "thin_lines", "CloudPlan", "PointCloudInfo", "SnapTarget",
           "auto_grid", "cloud_mesh", "max_supported_grid", "reconstruct_points", "colored_mesh", "transfer_colors", "TargetSurface", "imls",
           "target_surface", "PoissonSurface", "poisson_surface"]
