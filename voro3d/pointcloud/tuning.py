"""The tuned numbers of the point-cloud path, each with the measurement that set it.

Gates and widths of :func:`~voro3d.pointcloud.reconstruct.reconstruct_points`, in the fit frame's
terms (diagonal 2) unless said otherwise. A number stays here only with a measurement beside it.
"""

__all__ = ["CLOUD_STEPS", "CLOUD_BOUNDARY_STEPS", "CLOUD_SAMPLES_PER_FACE", "CLOUD_REFRESH_VOXELS", "WIDTH_PER_SPACING", "TRUSTED_WIDTH_PER_SPACING", "WIDTH_PER_NOISE", "MAX_TRUSTED_OUTLIERS", "MIN_NORMAL_AGREEMENT", "MAX_SIGN_DISAGREEMENT", "MAX_TIE_WEIGHT", "UNDECIDED_SIGMAS", "NOISY", "HEAVY_NOISE", "FILTER_WIDTH_PER_NOISE", "AUTO_SPACINGS_PER_VOXEL", "AUTO_GRID_RANGE", "COARSEST_GRID", "BAND_TOLERANCE", "MAX_TARGET_GRID", "MAX_REFINE", "DETAIL_SPACINGS", "TARGET_CELL_SPACINGS", "MIN_SPACINGS_PER_VOXEL", "DENSE_SPACINGS", "HOLE_VOXELS", "STRAY_CELL_SHARE", "CLOSED_LEVEL", "HOLE_LEVEL", "SHELL_DEPTH", "THINNEST_SHELL_NODES", "SHELL_ROUNDING_NODES", "MAX_BRIDGE_GAP", "MAX_POISSON_ESCAPE", "HULL_MARGIN_NODES", "MIN_COVERAGE", "FIELD_REFINEMENT", "MAX_FIELD_RESOLUTION", "SHEET_POINTS_GATE", "SHEET_WALLS", "SHEET_WIN", "SHEET_SUPPORT", "SHEET_OFFSET", "SHEET_HUG", "MAX_HULL_VOLUME", "MAX_MEDIAN_DISTANCE", "CHECK_POINTS", "STATISTICS_SAMPLE", "SIGN_SAMPLE", "LINE_RATIO", "LINE_SAMPLE", "THIN_ROUNDS", "SPARSE_SPACINGS", "STRAY_RATIO", "SUSPECT_FLATNESS", "SUSPECT_OFFSET",
           "SIGHT_ANGLE", "SIGHT_LINES", "SIGHT_GAP", "SIGHT_POINTS", "MIN_REVEALING", "SEPARATE_POINTS", "TILE_POINTS", "ANALYSIS_POINTS", "TILE_SAMPLES", "TILE_MARGIN",
           "SEAM_WIDTH", "SEAM_STEPS", "SPLIT_POINTS", "SPLIT_MARGIN_CELLS", "TWO_SHEET_POINTS", "TWO_SHEET_CLEARANCE", "WALL_VOTE"]

# Kernel width of a point: this many local spacings, or this many noise standard deviations.
# Sparse clean clouds (no noise, under MAX_TRUSTED_OUTLIERS of strays) get the narrower width:
# on 5k-point clouds of the bunny and fandisk it cut the CD 2-4 times against 1.5 spacings,
# which noisy clouds and clouds with strays need (fandisk at 0.5% noise: CD 2.9 vs 6.3 at 1.0).
WIDTH_PER_SPACING = 1.5
TRUSTED_WIDTH_PER_SPACING = 0.75
WIDTH_PER_NOISE = 4.0
MAX_TRUSTED_OUTLIERS = 0.01
# A noisy cloud gets a second IMLS pass from the normals of the first before its points move (moving them twice
# shrinks curved parts: bunny and armadillo at 0.5% noise, CD +16-24%). On four dev shapes at 0.5% noise: the target's
# CD 4-9% lower, NC +0.010-0.012, triangles > 30 deg off the true normal 8.4-8.9% -> 5.5% (bunny, rocker-arm); a third
# pass gains no more. Not where the first pass's mean normals mostly cancel (median length under this): the two sides
# of walls thinner than the noise, whose normals the second pass mixes (a cup lid at 1% noise: 0.46, CD 21 -> 64 with
# it; other dev shapes at 0.25-1% noise read 0.64-0.98).
MIN_NORMAL_AGREEMENT = 0.6
# Given normals whose signs disagree between this share of neighbours on one sheet
# (:func:`~voro3d.pointcloud.normals.sign_disagreement`) are re-oriented by our orienter. 30k points of each of
# the 38 dev meshes: their true normals read 0-0.0045 (0-0.029 with 0.5% noise), but for abc_00000001 (0.18: its
# triangles are not consistently oriented); random signs 0.50; Open3D's estimate_normals() on the noisy clouds,
# as a user runs it, 0.156-0.364; our own orientation of those clouds 0-0.076.
MAX_SIGN_DISAGREEMENT = 0.1
# Graph edges that tie smooth patches into parts in the orientation (normals._part_flips): those whose Hoppe weight (1 -
# |n_i.n_j| + |d.n_i| + |d.n_j|) is under this, i.e. that stay closer to the surface than a right-angle turn; edges
# across a thin wall would tie its two sides as one. Wrongly signed normals (mean %) against the meshes' own, 38 dev
# meshes, our estimate (the benchmark range scanner, 30k points), 2026-12-05. Kinds: objects alone from 1 / 3 / 6 views,
# 5k clean points, 20k at 0.5% noise; on bench_scenes' plate from 1 / 3 views; on it cropped to 0.85 of its half-width
# (its edge out of the frame), from 1 / 3 views. Each piece of the graph flipped on its curvature sum (the rule before
# the parts): 1.20 / 0.72 / 1.31, 5.38, 4.90; 18.1 / 8.49; 22.9 / 16.7. Parts with every edge a tie: 1.11 / 1.28 / 1.77,
# 5.48, 4.43; 1.12 / 3.02; 22.7 / 17.4 (the cup abc_00000009 from 3 views 0 -> 21%: its inside tied to its outside
# across the wall). Under 0.5: 1.14 / 0.76 / 1.12, 5.20, 6.09; 1.18 / 0.74; 7.8 / 8.9. Under 1.0: 1.11 / 0.72 / 1.31,
# 5.39, 4.52; 1.10 / 0.70; 11.0 / 7.7. Under 1.5: 1.11 / 0.72 / 1.49, 5.39, 4.44; 1.12 / 0.70; 12.6 / 5.7. The
# orientation tree's own edges as ties as well (it joins the table to the object through their coin-toss relation): on
# the cropped plate 18.2 / 13.6, the rest the same.
MAX_TIE_WEIGHT = 1.0
# A part of the orientation whose curvature sum is within this many of its own spread (the root of its sum of squares:
# what random signs would give) has no outward side of its own, and faces the rest of the cloud (a table whose edge is
# out of view faces what stands on it). Wrongly signed normals as above (mean %), 0 / 3 / 10 sigmas: on the cropped
# plate 21.2 / 11.0 / 10.4 from 1 view, 16.3 / 7.7 / 7.0 from 3; the object held 3% of its diagonal above the cropped
# plate (apart) 29.2 / 2.5 / 3.1 and 23.8 / 2.2 / 0.6 (before the parts: 24.0 and 31.1); on the whole plate from 1
# view 1.11 / 1.10 / 2.03, the object held above it 0.73 / 0.73 / 1.64 (before the parts 12.9); the rest within 0.1.
UNDECIDED_SIGMAS = 3.0
# Fine-scale noise (about a quadric through 9 neighbours: curvature is not noise) over this share of the spacing turns
# on the smoothing (plan denoise "auto"). 12 benchmark meshes x 17 conditions: clean ones 0-0.083, 0.25-1% noise and
# noisy range scans 0.168-0.331. About a plane (until 2026-12-07) clean sparse clouds read noisy (pointcloud_sparse: smoothed
# 12 / 9 / 3 of 12 at 300 / 600 / 1k points, now 4 / 1 / 1; CD 172.9 -> 93.0, 69.2 -> 53.9, 30.5 -> 25.8, F1 +0.06-0.13),
# and thingi32_252119's clean 5k (0.169; CD 15.9 -> 17.5, NC 0.758 -> 0.791, F1 0.396 -> 0.611).
NOISY = 0.13
# Noise over this many cells of the Poisson octree (2 / 2^depth in the fit frame; four dev shapes, 20k points: 0.61-0.66
# at 0.25% of the diagonal, 1.06-1.09 at 0.5%, 1.46-1.59 at 1%) leaves bumps the target resolves: it is
# bilateral-filtered (pointcloud.denoise) over FILTER_WIDTH_PER_NOISE noise deviations. On the four at 0.5% and 1%
# noise: CD 3-15% lower but armadillo at 0.5% (+0.7%), triangles over 30 degrees off the true normal 10.0% -> 8.9%
# (0.5%) and 23.1% -> 18.3% (1%), NC +0.002-0.03, fandisk's flat faces flat; at 0.25% it cost CD 4-10% on three.
HEAVY_NOISE = 0.85
FILTER_WIDTH_PER_NOISE = 2.0
# grid="auto": the finest voxels about this many median spacings wide, within these bounds. The top at 10^6 true-normal
# points (bench_large's clouds, reconstruct in its own process), 128 against 256: armadillo CD 0.463 / 0.460, NC 0.978 /
# 0.983, 36 / 49 s (192: 0.460, 0.981, 44 s); bunny CD 0.589 / 0.589, NC 0.989 / 0.991, 38 / 49 s; the CAD parts, flat
# where they are not sharp, lose at 256: fandisk CD 0.664 / 0.668, abc_00000005 0.629 / 0.633 (Poisson depth 9: 0.667,
# 0.632), 29-34 / 32-35 s. The width: 12 benchmark meshes, no normals (2026-12-07), 2.5 / 2.0 / 1.5 spacings, mean CD
# clean 5k 2.61 / 2.56 / 2.54, clean 20k 0.64 / 0.63 / 0.63, 5k at 0.25% noise 4.46 / 4.31 / 3.76 (the cow's legs: 10.4
# / 9.1 / 2.7), 3-view scans 39.2 / 39.1 / 39.2, NC at most +0.0045, F1 within 0.006; faces 1.2-1.6x / 1.6-2.3x, seconds
# up to 1.15x / 1.5x; 1k-2k: grid 32. Rerun: bench_pointcloud.py --grid auto --no-poisson --auto-width 2.0.
AUTO_SPACINGS_PER_VOXEL = 2.5
AUTO_GRID_RANGE = (32, 128)
# grid="auto" fits an adaptive band (voro3d.generators.AdaptiveBand) from the finest grid up to voxels of this grid,
# splitting a voxel while its target surface is further than BAND_TOLERANCE finest voxels (rms) from a plane.
COARSEST_GRID = 32
BAND_TOLERANCE = 0.05
# The target surface's resolution follows the grid up to this one (Poisson depth 8), finer only
# for dense points (TARGET_CELL_SPACINGS); its Poisson depth: pointcloud.poisson.poisson_depth.
MAX_TARGET_GRID = 64
# The Poisson target goes finer than MAX_TARGET_GRID asks while its octree cells stay this many median spacings wide
# (pointcloud.poisson.poisson_depth): dense clouds hold the detail. 1M oriented points of 4 dev meshes (bench_large,
# depth 9 instead of 8): CD bunny 0.595 -> 0.589, fandisk 0.666 -> 0.664, abc_00000005 0.635 -> 0.629 (Poisson depth 9
# alone: 0.591, 0.665, 0.630), armadillo 0.463 both; 33-40 s instead of 18-28 s. At 100k points depth 9 gained nothing
# (CD -0.2% to +0.6%, 1.2-2 s more), and this keeps them at 8: cells 1.2 spacings wide at depth 9. With the mesh split
# before its snap (resolution.refine_levels), depth 8 forced at 10^6 points, split all the same (CD / NC the means of
# 5 evaluation seeds, 2026-12-04): armadillo 0.4601 / 0.9823 -> 0.4610 / 0.9820 and 47.7 -> 31.2 s, bunny 0.5903 /
# 0.9903 -> 0.5911 / 0.9902 and 60.0 -> 30.5 s (Poisson depth 9 alone: 0.4589, 0.5908): half the time for 0.1-0.2% CD,
# kept at depth 9. The 1M-point subset of a denser cloud (pointcloud.tiles) reads its own spacing and goes to depth 9
# as well (it stayed at the grid's depth 8 before the mesh was split to the target's cells): bunny, 3M / 10M
# true-normal points, CD 0.595 / 0.589 -> 0.589 / 0.588, NC 0.9883 / 0.9885 -> 0.9933 / 0.9929, 41 / 40 -> 53 / 53 s,
# 32k -> 510k faces (large_scaling.md; Poisson depth 9: 0.589, 0.9939).
TARGET_CELL_SPACINGS = 1.5
# Most midpoint splits of a dense cloud's mesh before its fit to the target (resolution.refine_levels): each
# quadruples the faces. Two bring a 128 grid's triangles to a depth-9 target's cells (1M points: 520-650k faces
# against Poisson depth 9's 1.1-1.5M); a 64 grid asked for by hand would want three, 64 times its faces. 10^6
# true-normal points (bench_large's clouds, grid "auto": 128 over 3 levels, target depth 9), CD / NC the means of 5
# evaluation seeds, unsplit -> split once: bunny 0.5930 / 0.9886 -> 0.5903 / 0.9903, armadillo 0.4623 / 0.9775 ->
# 0.4601 / 0.9823, fandisk 0.6630 / 0.9881 -> 0.6635 / 0.9889, abc_00000005 0.6334 / 0.9943 -> 0.6328 / 0.9945; split
# twice, to the cells of the depth-9 target (quiet machine, 2026-12-04, benchmarks/results/large_quiet.md ->
# large.md), CD / NC / whole seconds: bunny 0.5909 / 0.9903 / 53.0 -> 0.5872 / 0.9931 / 42.9, armadillo 0.4602 /
# 0.9823 / 43.0 -> 0.4577 / 0.9864 / 51.2, fandisk 0.6639 / 0.9889 -> 0.6617 / 0.9901, abc_00000005 0.6323 / 0.9945 ->
# 0.6315 / 0.9950, abc_00000008 0.2451 / 0.9907 -> 0.2455 / 0.9919, homer 0.4218 / 0.9929 -> 0.4206 / 0.9955 (Poisson
# depth 9 in the second run: 0.5901 / 0.9938, 0.4594 / 0.9874, 0.6618 / 0.9907, 0.6333 / 0.9950, 0.2451 / 0.9920,
# 0.4212 / 0.9964); the mesh stage 5-6 s -> 5-10 s, 4x the faces (160-650k, Poisson's 0.4-1.5M). With 10^6 evaluation
# samples, whose spacing no longer hides the facets, armadillo CD 0.0480 -> 0.0469 (Poisson 0.0464).
MAX_REFINE = 2
# A cloud's mesh is split until its triangles are about as fine as the finest detail its Poisson target holds
# (resolution.refine_levels): the target's octree cell, or this many median spacings, the coarser (points a spacing
# apart show nothing finer than two spacings: sparse clouds are not split however fine the octree). Noisy clouds are not
# split (bunny, cow, elephant at 0.5% noise, 20k points, once: CD +1%, +3%, +3%). 12 benchmark meshes at grid 64, split
# 0 / 1 / 2 times (2026-12-05, /tmp sweep, shared machine), mean NC: clean 100k 0.9809 / 0.9847 / 0.9867, 2% outliers
# 0.9792 / 0.9830 / 0.9848, 20x density ramp 0.9788 / 0.9825 / 0.9844, a third missing 0.8975 / 0.9001 / 0.9010 (this
# rule, 1-2 splits there, nothing kept at creases: 0.9856, 0.9830, 0.9837, 0.9001); CD about 1.3% lower at one split,
# the same at two; faces 12k -> 46k / 186k (Poisson's 100-220k), the mesh stage 0.5 -> 1.2 / 2.3 s. Clean 5k and 20k
# (voxels 1.1-3.4 spacings: not split, but for one 20k cloud) would gain 0.002-0.003 NC for 4x the faces, at 5k more
# than Poisson's. As landed, split once with the pieces at creases kept (snapping.CREASE_DEGREES;
# benchmarks/results/pointcloud.md, 2026-12-05): NC 0.9852 / 0.9821 / 0.9835 / 0.8993 against Open3D's 0.9855 / 0.9797 /
# 0.9641 / 0.9019, faces 85k / 47k / 99k / 49k, seconds a cloud within run-to-run noise (clean 100k 9.7 -> 9.2, outliers
# 7.9 -> 8.3); the 38 dev meshes at clean 100k NC 0.9822 -> 0.9855, CD 0.6547 -> 0.6513 (pointcloud_dense38.md).
DETAIL_SPACINGS = 2.0
# A voxel narrower than the median spacing has empty voxels all over the surface.
MIN_SPACINGS_PER_VOXEL = 1.0
# Clean points closer than this share of a voxel are dense: exact samples themselves, and their winding number decides
# inside near the surface (:class:`~voro3d.pointcloud.surface.TargetSurface`). Range scans of 30k points sit at
# 0.32-0.45 voxel at grid 64; at 1/3, the 3-view scans at 0.32-0.33 (fandisk, cow, thingi32_75655 of the 12 benchmark
# meshes) were dense and came out scaly: the winding number of points with depth noise and uneven coverage labels the
# cells near the surface (cow NC 0.842, against 0.884 at 1/4 and CD 24.6 against 21.4). 3-view scans of the 12, mean
# CD / NC / F1 at 1/3 and 1/4: 71.3 / 0.869 / 0.655 and 72.4 / 0.876 / 0.661; the dev clouds of 10^5 points and more
# read 0.16-0.22 and stay dense. Rerun: bench_pointcloud.py --dense-spacings 0.3333.
DENSE_SPACINGS = 1 / 4
# Proxy samples fill the holes of a dense cloud where no point is within this many voxels (nearer,
# they only blur the exact points: 2 spacings added 13% proxy samples on organic_arm, NC 0.979 -> 0.968).
HOLE_VOXELS = 1.0
# Inside cells in groups (joined by Voronoi faces) of fewer cells than this share of the largest group's are strays:
# cells whose label the samples nearby could not settle; outside cells cut off from the exterior in groups under this
# share of its cells are bubbles (pointcloud.debris). A 3-view range scan of fandisk (HOLE_LEVEL 0.42) held bubbles of
# 14 and 46 cells against 5,725 exterior ones, cavities a voxel under its top: 3 pieces, 1 with the rule (bubbles of
# at most 8 cells only before it); no other of the 144 benchmark outputs had more pieces than its cloud has islands.
STRAY_CELL_SHARE = 0.02
# Winding number level (:func:`~voro3d.pointcloud.sides.winding_level`) above which the points enclose a volume (0.5
# closed, about 0 for a one-sided scan): their target is screened Poisson. Ablation, range scans of 12 dev meshes
# (bench_pointcloud, grid 64): every cloud taken as closed (this level at -1) gave CD 6,500-10,700 on 10 of the 12
# one-view scans and 7 of the 12 three-view ones (Poisson ran off, and IMLS then lacked the one-sided scans' smoothing
# pass) against 35-3,400 and 4.5-1,270 with it. The other way, every cloud's target IMLS (no Poisson), 2026-12-06, one
# session, 12 benchmark meshes unless said: clean 5k CD 2.43 -> 4.20, NC 0.947 -> 0.938; clean 20k 0.64 -> 0.95, 0.973
# -> 0.965; a third missing 361 -> 497, 0.899 -> 0.858; 6 views 1.29 -> 1.51, 0.972 -> 0.957; but 3 views 45.8 -> 23.8
# (NC 0.877 -> 0.870, F1 0.660 -> 0.666; abc_00000008 142 -> 12.6, homer 105 -> 13.8, spot 35 -> 10.4) and on the 16
# meshes of pointcloud_range_more 65.7 -> 51.6 (NC 0.904 -> 0.889; arm 62 -> 6.9, fertility 74 -> 13): a 3-view scan's
# kept Poisson surface balloons under what no view saw. Neither the level nor MAX_POISSON_ESCAPE tells those from a
# third missing, where Poisson wins: levels 0.32-0.47 against 0.38-0.48, escapes 0.028-0.079 against 0.0005-0.061.
CLOSED_LEVEL = 0.25
# Not settled: which target for clouds that read closed but were seen in part. Each target forced (plan target), 12
# dev meshes, grid 64, at 17c2436, mean CD / NC auto -- poisson -- imls: 3-view range scans 71.3 / 0.869 -- 553.7 /
# 0.816 -- 48.8 / 0.863 (Poisson's CD lower on 0 of 12; the auto rule sends 5 to it, homer 105 against IMLS's 11.4), a
# third missing 355.4 / 0.899 -- same -- 467.2 / 0.857 (Poisson lower on 11), 6 views 1.2 / 0.972 -- same -- 2.0 /
# 0.956 (Poisson lower on 9). The winding level does not tell the first two apart: 0.23-0.41 on 3-view scans,
# 0.39-0.48 with a third missing (6 views 0.50). Nor do (same clouds, at e9c897c) the share of either target's area
# over 4-16 spacings from the points, points whose outward normal ray it blocks, or the thickness of Poisson's
# unsupported parts (20-57 octree cells on the 3-view clouds it is sent: fills, not flaps); with the true normals
# Poisson still fails the 3-view scans (homer CD 91.7, IMLS 7.8). The IMLS target of a closed cloud closes its holes
# and unseen parts at a winding number of at least this (surface.target_surface's hole_level; near the points the IMLS
# field decides). 3-view range scans of the 12 benchmark meshes (7 take IMLS), grid 64, DENSE_SPACINGS 1/4, mean CD /
# NC / F1 with the cloud's own level (0.23-0.42) / 0.42 / 0.46 / 0.5: 72.4 / 0.876 / 0.661 -- 47.5 / 0.877 / 0.661 --
# 47.0 / 0.872 / 0.649 -- 49.1 / 0.868 / 0.637 (fandisk 176 -> 45, thingi32_75655 138 -> 38, elephant 73 -> 16: caps
# that ballooned; at 0.5 limbs seen from one side are cut: armadillo 4.2 -> 16.6). On 8 dev meshes outside the
# benchmark (abc_00000003, screwdriver, camel_b, fertility, cheburashka, thingi32_44234 / 96481, decimated-max; 3 take
# IMLS), own level against 0.42: 69.2 / 0.899 / 0.677 -> 33.8 / 0.903 / 0.686 (thingi32_96481 269 -> 41). Rerun:
# bench_pointcloud.py --conditions "range scan 3 views" --no-poisson --hole-level 0 (--shapes ... for the others).
HOLE_LEVEL = 0.42
# The IMLS target of an open cloud (winding level under CLOSED_LEVEL) left uncut by the hull (plan hull "off") reaches
# no further than this from the points, but where they enclose it (target_surface's depth): behind a one-sided scan
# the winding number reads inside out to the box, a block that only a round object resembles. Range scans of 12 dev
# meshes, grid 64, no cut, mean CD with no limit / 0.0625 / 0.125 / 0.25 / 0.375: one view 1337 / 455 / 361 / 370 /
# 562 (CAD parts 1073-5536 -> 96-487 at 0.125; bunny 385 -> 874), NC 0.762 / 0.750 / 0.732 / 0.740 / 0.759; three
# views 259 -> 63.6 (two balloons gone). Cut to the hull (auto for open clouds), the hull bounds it and no limit
# applies: all 38 dev meshes from 1 view (2026-12-06, no normals, grid 64), limit 0.125 / 0.25 / 0.5 / 1 / none: CD
# 390.8 / 303.6 / 267.2 / 252.5 / 252.5, NC 0.776 / 0.800 / 0.811 / 0.823 / 0.823, F1 0.403 / 0.402 / 0.405 / 0.412 /
# 0.412 (none against 0.125: lower CD on 35 of 38; the lid abc_00000007 131 -> 216, abc_00000008 63 -> 181), 0.89x the
# time (poste_france 6 -> 39 s). Closed clouds keep no limit: the 20 clouds of the 38 dev meshes whose Poisson target
# is refused (MAX_POISSON_ESCAPE's ablation below), limited at this depth too (2026-12-05): mean CD 65.9 -> 89.7, NC
# 0.881 -> 0.857, F1 0.634 -> 0.572, lower CD on 4 (the lid from 3 views 357 -> 83), and up to 9x higher on the rest
# (cow 7.4 -> 70, bunny 11 -> 92): their holes are closed, not cut.
SHELL_DEPTH = 0.125
# Each point's depth (surface.shell_depths: the radius of the seen surface's mean curvature) is at most SHELL_DEPTH
# and at least this many nodes of the field's grid (two VoroMesh voxels at FIELD_REFINEMENT 2: a layer of inside cells
# the fit can hold). SHELL_DEPTH for every point (the rule before) against each point's own, 2026-12-05, no normals,
# grid 64: objects on a table (bench_scenes.py, 12 dev meshes) from 1 view CD 138.3 -> 135.5, NC 0.807 -> 0.808, F1
# 0.285 -> 0.286 (lower CD on 11 of 12); from 3 views 124.7 -> 93.7, 0.886 -> 0.889, 0.392 -> 0.406 (12 of 12: the
# objects no longer sit in a slab the table's depth deep); the objects alone from 1 view (bench_pointcloud) 249.8 ->
# 248.7, NC 0.722 -> 0.721, F1 0.350 either way; 3 and 6 views read closed (no limit). This bound at 2 / 4 / 8 nodes:
# 1 view CD 248.7 / 248.7 / 249.8. Rerun: bench_scenes.py --shell-depth uniform.
THINNEST_SHELL_NODES = 4.0
# Where the depth limit meets the IMLS target's own far field (the winding number's level set, behind an open scan's
# seen side), their crease is rounded over this many nodes of the field's grid (fields.smooth_maximum): where the two
# nearly coincide, a sharp intersection showed each place they cross as terraces and rings on the shell's back. 12
# benchmark meshes, no normals, grid 64, far field as a distance, no blend (2026-12-06), range scans from 1 view,
# rounding 0 / 0.75 / 1.5 / 3 / 6 nodes: CD 209.2 / 209.4 / 209.5 / 210.3 / 235.3 (at 6 the elephant's thin parts cut,
# 262 -> 522), NC 0.7313 / 0.7323 / 0.7340 / 0.7381 / 0.7479, F1 0.3673 / 0.3684 / 0.3690 / 0.3727 / 0.3841; from 3
# views (7 IMLS targets) CD 45.78 / 45.74 / 45.61 / 45.34 / 44.65, NC 0.8953 / 0.8953 / 0.8955 / 0.8958 / 0.8966. At
# 1.5 / 3: pointcloud_range_more's 16 from 1 view CD 442.9 / 446.7, NC 0.7614 / 0.7638, from 3 views 69.1 / 68.9, NC
# 0.9173 both; objects on a table (bench_scenes.py) from 1 view 134.5 / 132.5, NC 0.816 / 0.820, F1 0.330 / 0.334,
# from 3 views 84.7 / 83.5, 0.903 / 0.904, 0.459 / 0.464. Rerun, both with --no-poisson: bench_pointcloud.py
# --conditions "range scan 1 view" "range scan 3 views"; bench_scenes.py. Not kept (2026-12-06), with this rounding:
# the IMLS band (surface.IMLS_BAND) giving way to the far field over its last 1 / 2 kernel widths, so that past the
# rim of a seen patch (a scan's silhouette) the band's edge, a union of balls, shows no crust. 12 meshes from 1 view
# CD 210.3 -> 211.3 / 211.9, NC 0.7381 -> 0.7460 / 0.7490; 3 views 45.34 -> 45.13 / 45.15, NC 0.8958 -> 0.9034 /
# 0.9064; range_more's 16 from 1 view NC 0.7638 -> 0.7744 / 0.7781, 3 views 0.9173 -> 0.9208 / 0.9231; on a table NC
# 0.820 / 0.904 -> 0.831 / 0.915 (at 2). But the blend cut what the band held across an unseen gap: the elephant from
# 3 views lost a foot and cheburashka from 1 view an ear (two pieces each). The far field capped at the distance to
# the points, without it, split an armadillo on a table from 3 views.
SHELL_ROUNDING_NODES = 3.0
# Pieces of an open cloud's solid (or of the offset shell) closer than this, fit-frame units (about 12% of the
# diagonal), are joined by a rod (fields.bridge): patches one viewpoint sees apart (a cow seen from behind: rump, head
# and a leg, 0.04-0.09 apart; an elephant's trunk, 0.15). Range scans of the 12 dev meshes, grid 64, same session, no
# bridges (0) / 0.25: one view one piece 75% / 92% (cow 3 -> 1, elephant 2 -> 1 pieces; thingi32_252119's shell is
# joined in the target but its thin waist parts in the fit, 3 -> 2), mean CD 341.5 / 339.5, NC 0.722 / 0.720, F1 0.334
# / 0.334; three and six views have no gap to bridge (every figure the same). Clouds that read closed are never
# bridged: two objects side by side stay two. Rerun: bench_pointcloud.py --bridge-gap 0.
MAX_BRIDGE_GAP = 0.25
# A Poisson surface that runs further than this share of the diagonal out of the points' box is refused
# (:meth:`~voro3d.pointcloud.poisson.PoissonSurface.escape`). Ablation on all 38 dev meshes, grid 64 (2026-12-05): it
# fires on 17 of the 3-view range scans, 1 of the 6-view ones and 2 with a third missing. Off (Poisson kept), mean CD
# over the 38 from 3 views 55.5 -> 537.8, NC 0.889 -> 0.868, F1 0.644 -> 0.593 (fandisk 44 -> 4406, bunny 11 -> 2045,
# cheburashka 16 -> 3753; the lid abc_00000007 alone gains, 357 -> 5.0); 6 views 2.6 -> 2.7 (the lid's shell 2.27,
# Poisson 8.26); a third missing 345.9 -> 338.9, NC 0.8865 -> 0.8915 (thingi32_75665 355 -> 82; bumpy-cube 105 -> 112,
# NC 0.81 -> 0.93). Judged after the sightline carve instead (2026-12-07: those 38 from 3 / 6 views and a third missing,
# the 12 benchmark meshes' other range and clean 5k / 1% noise clouds), 4 decisions change: the lid from 3 views (flap
# 32% -> 4.5% out) CD 392.8 -> 3.4, but spikes under decimated-knight 7.7 -> 39.9, thingi32_90889 20.3 -> 74.9 and the
# misaligned armadillo 7.5 -> 27.6 (NC -0.05 to -0.08); nor does either target's misfit both ways tell them apart.
# Rerun: bench_pointcloud.py --no-poisson --poisson-escape none --conditions "range scan 3 views" ...
MAX_POISSON_ESCAPE = 0.08
# With plan hull "on", a target's solid more than this many nodes of its grid (a VoroMesh voxel at FIELD_REFINEMENT 2)
# outside the points' convex hull is cut away (voro3d.pointcloud.hull); "auto" cuts an open cloud's (level under
# CLOSED_LEVEL), whose solid it then holds (SHELL_DEPTH). Off -> on, 38 dev meshes, no normals, grid 64
# (plan_hull_open.md, 2026-12-06): 1 view CD 368.8 -> 252.5, NC 0.758 -> 0.823, F1 0.381 -> 0.412 (lower CD on 34),
# 3-view scans that read open (3) 65.8 -> 21.4; on a table (scenes.md) 1 / 3 views CD 122.7 / 74.1 -> 30.1 / 23.5 (the
# table as thin as its seen edges); the 2 third-missing clouds that read open lose (388.5 -> 494.4, 381.9 -> 427.1);
# all closed, one piece. Closed 3-view scans gain too (54.0 -> 32.3, 27 of 35), a third missing loses (28 meshes,
# plan_hull.md: 325 -> 451, NC -0.019, 1 of 28), and neither the level (0.14-0.46 against 0.31-0.48), the share of the
# solid cut (0-0.27 both), the closure's mean reach past the hull (0.04-0.11 against 0.03-0.24) nor this margin
# (homer's 3-view scan 53 / 96 / 106 at 4 / 8 / 16 nodes, spot's third missing 180 / 107 / 71, against 236 at 2 and 78
# off) tells them apart. Margin 0 / 1 / 2 nodes (2026-12-07, --hull-margin): one-view scans want it (their unseen back
# lies past the hull): CD 280.1 at 0 against 227.1 on 28 dev meshes, 314.4 at 1 against 264.7 on 19; a table from 3 views
# does not (bench_scenes: the plate, seen to its lower edges, ends at the hull): CD / F1 3.9 / 0.832, 9.2 / 0.510, 23.5 /
# 0.498. The cut at the hull where the solid is over a voxel thick, the margin only where thinner, loses the one-view
# scans alike (302.5 against 258.3 on 23): a plate's lower edge and a silhouette's rim look alike to the points.
HULL_MARGIN_NODES = 2.0
# Share of the points that must lie on the target surface (within two kernel widths).
MIN_COVERAGE = 0.9
# The target field is sampled this many times finer than the VoroMesh grid (at most MAX). Range scans
# of the 12 benchmark meshes, grid 64, the field at 96 / 128 / 160 nodes (2026-12-05, one quiet run
# each), mean CD / NC / F1 and seconds summed: one view (IMLS) 267.7 / 0.715 / 0.349, 34.7 s -- 246.6 /
# 0.722 / 0.349, 48.8 s -- 246.4 / 0.724 / 0.350, 65.8 s; three views with an IMLS target (7) 34.1 /
# 0.846 / 0.586 -- 32.2 / 0.875 / 0.644 -- 32.0 / 0.883 / 0.659, 38.3 / 46.3 / 57.9 s; Poisson targets
# (the other 5, a third missing) within 2.5% CD and 0.01 F1 of each other, 0.97-1.0x the time.
FIELD_REFINEMENT = 2
MAX_FIELD_RESOLUTION = 160
# The offset shell (sheet_surface) is tried when the points lie over SHEET_POINTS_GATE median spacings from the target
# (a lid with walls under the spacing: 0.37-0.62, from 6 views 0.150; right clouds, holes and real scans too: under
# 0.08) and kept when its misfit (mean distance points -> surface -> points) is under SHEET_WIN times the target's (the
# lid: 0.2-0.55). A second entry gate, the target's surface over a spacing from the points (SHEET_SURFACE_GATE), only
# spared time once SHEET_SUPPORT and SHEET_WIN decided. Dropped (2026-12-07): no decision changes on 12 benchmark meshes
# x 9 conditions (clean 5k, 3 noises, outliers, a third missing, 1 / 3 / 6 views), nor on 24 noisy and 5k clouds of 6
# parts (benchmarks/parts.py: misfit ratios 1.08-1.80), nor (both gates dropped) on 380 dev clouds before; 144 clouds
# had read 0.50-0.81 on it. parts.py's pipe tee at 5k points, walls thinner than the spacing read as noise, read 0.84 /
# 0.92 (clean / 0.25% noise) and now takes the shell: clean CD / NC / F1 34.2 / 0.931 / 0.051 -> 2.24 / 0.982 / 0.473
# (alpha wrap 2.66 / 0.853 / 0.650). Its cost: the shell built on noisy clouds, +0.6-0.9 s a cloud (22.1 -> 26.3 s on
# 6). At 10^5 clean points only abc_00000001 of the 38 passes the gate (0.93; misfit 2.59, 0.74 needed). A shell only
# where points span a wall lost the lid at 5k (14.0 -> 445); only for closed clouds, at 20k (5.1 -> 114).
SHEET_POINTS_GATE = 0.15
# Also tried, whatever those read, for a cloud that reads closed with at least SHEET_WALLS of its points spanning a
# wall (wall_points): its target, closing holes, fills what the walls enclose (a bowl: a dome). containers.py's (8
# conditions, grid 64, 2026-12-07): bowl clean 20k CD / NC / F1 331.5 / 0.680 / 0.451 -> 1.18 / 0.990 / 0.813, from 6
# views 21.0 -> 1.20, vase clean 20k 15.2 / 0.806 / 0.174 -> 1.62 / 0.994 / 0.683, no other change. 38 dev meshes x 10
# conditions: with both gates dropped none changes (3 of 380 read over 0.25); x 11 more (outliers, flying pixels,
# LiDAR, 300-1k points): 14 closed clouds read over it, one changes (thingi32_75656 at 600 points 191.6 / 0.872 /
# 0.333 -> 14.4 / 0.900 / 0.244); 1-2 s more. Open clouds left out (2 over it; LiDAR's lines read as walls):
# abc_00000001 from 1 position CD 13,636 -> 15,157; abc_00000005 at 300 points 259 -> 18.8.
SHEET_WALLS = 0.25
# SHEET_WIN 0.65 -> 0.7 (2026-12-06): with the IMLS rims smoothed (surface.BAND_EDGE_BLUR_NODES) the
# plate of test_a_thin_plate_is_a_surface read 0.678 (0.643), a slab 0.2 thick; the rest did at 0.65.
SHEET_WIN = 0.7
# ... and only when the points hold the shell on both faces, its surface within this many median spacings of them
# on average: a wall sampled on both sides, not one side of a solid or an open sheet. It replaced SHEET_NEAR (the
# points at most 4.5 times as far from the shell as from the target), which depth noise beat: at 0.3% (bench_pointcloud's
# noisy range scans) the points lie 0.17-0.33 spacings off any smooth target and the shell, a blob a spacing off them,
# was taken on 59 of 76 clouds (38 dev meshes, 1 and 3 views; 12 benchmark meshes CD / NC / F1 509 / 0.769 / 0.144
# and 63.5 / 0.879 / 0.322 -> 134.7 / 0.805 / 0.372 and 40.8 / 0.898 / 0.644; abc_00000008 lost, 20.4 -> 152.9 from 3).
# Read on the 84 of 286 clouds at grid 64 that build it (those 76, 38 meshes' 1 / 3 / 6-view scans, 12 meshes x 7
# more conditions, cup and lid 5k-100k): 0.55-0.69 where it wins (lid abc_00000007 at 5k / 20k / 6 views / 0.5% noise,
# cup abc_00000009 at 5k), 0.81-1.39 on the noisy scans, 4.2-6.0 on dense one-view scans. Coarser nodes than the
# spacing read higher: at grid 32 the lid at 5k 0.76, test_walls_thinner_than_the_spacing's cup 0.95 (now IMLS's solid,
# CD 601; at grid 48 the shell's 10). Rerun: bench_pointcloud.py --conditions "noisy range scan 1 view" ... --sheet-support inf.
SHEET_SUPPORT = 0.78
# Its offset: this many median spacings, at least a field step. (The noise estimate is no guide there: it reads the two
# sides of the walls as noise.) 1.25 until the shell was closed back to the points (SHEET_HUG): a wider ball then leaves
# fewer tunnels through a wall sampled at random, where a closing ball fits through the gaps between points. Genus of
# the shell (the lid abc_00000007 at 5k / 20k points, from 6 range views; the cup abc_00000009 at 5k; the offset shell:
# 0 / 1 / 5 / 1), offset 1.25 spacings and a hug of 0.25: 15 / 2 / 28 / 16 (white specks through the walls in the
# pictures); 1.6 and 0.25: 1 / 1 / 16 / 0; 2.0 and 0.25: 0 / 0 / 28 / 0. CD / NC at grid 64: 1.25: 3.10 / 0.910, 2.21 /
# 0.929, 2.29 / 0.916, 3.14 / 0.962; 1.6: 4.64 / 0.917, 2.57 / 0.931, 2.27 / 0.921, 3.38 / 0.976; 2.0: 6.91 / 0.910,
# 3.18 / 0.931, 2.55 / 0.925, 3.92 / 0.980 (the wider ball fills the lid's groove). Landed, 1.6 and SHEET_HUG 0.16
# (0.256 spacing): genus 1 / 1 / 16 / 0, CD / NC 4.71 / 0.917, 2.59 / 0.932, 2.27 / 0.923, 3.45 / 0.976.
SHEET_OFFSET = 1.6
# The union of balls is closed back to this share of its offset from the points (fields.closing; one-sided parts keep
# a node's half thickness): a quarter spacing at SHEET_OFFSET. CD / NC / F1 at grid 64 (2026-12-05, offset 1.25
# spacings), the offset shell -> closed at 0.5 / 0.35 / 0.2 / 0.1 / 0 (distances to the shell's vertices; exact ones
# at 0.2: the lid 3.10 / 2.21 / 2.29, the cup 3.14 / 0.962 / 0.416; landed: 0.16 of an offset of 1.6, SHEET_OFFSET
# above):   lid abc_00000007 5k points: 47.8 / 0.915 / 0.000 -> 8.79, 5.83, 3.18 / 0.910 / 0.539, 2.99, 3.33   lid 20k
# points: 14.7 / 0.937 / 0.003 -> 4.32, 2.96, 2.33 / 0.929 / 0.603, 2.26, 2.30   lid from 6 range views (the shell
# forced): 8.22 / 0.933 / 0.044 -> 2.87, 2.41, 2.29 / 0.917 / 0.592, 2.29, 2.29   cup abc_00000009 5k points (forced):
# 80.4 / 0.962 / 0.000 -> 6.74, 6.74, 3.27 / 0.960 / 0.369, 3.37, 4.12 NC falls as the share does (lid 5k 0.919,
# 0.919, 0.910, 0.899, 0.885). On 6 other dev meshes (bunny, fandisk, armadillo, thingi32_252119, abc_00000001,
# nmc_sample0) x clean 5k / 20k, the shell forced, a node's offset everywhere -> 0.2: CD lower on 11 of 12 (mean 8.0
# -> 5.2), F1 higher on all 12 (0.107 -> 0.346), NC -0.003 to -0.043 (mean -0.018).
SHEET_HUG = 0.16
# voro3d.reconstruct refuses a cloud's mesh when it encloses more than this many times the volume of the points'
# convex hull, or when the median point lies more than this many voxels off it beyond the offset its target keeps by
# design (the sheet's: a cup lid at 5k points, its shell 1.0 voxel off the points, was refused before it counted).
# Measured on right outputs (3 dev meshes x clean 5k / noise 1% / outliers 2% / third missing, the 4 dev scans):
# volume 0.28-0.91 of the hull, 2.17 for point_set_3 (its unseen underside closed below its base); median distance
# 0.009-0.23 voxel. The volume test catches only gross balloons: a one-view scan of abc_00000005 closes at 8.3 times
# the hull of the side it saw, a torus with estimate_normals() signs trusted (before the sign check) 7.5.
MAX_HULL_VOLUME = 10.0
MAX_MEDIAN_DISTANCE = 1.0
# Both read every k-th point, at most CHECK_POINTS. Against all 10^6 points of 3 dev meshes (Poisson depth 7 meshes of
# them, 2026-12-04): volume ratio within 0.2%, median distance within 0.3%; 0.14-0.17 s instead of 1.5-2.0 s.
CHECK_POINTS = 100_000
# Lines of sight (voro3d.pointcloud.sightlines): a point is seen from within SIGHT_ANGLE degrees of its normal (the
# range scans of bench_pointcloud drop hits beyond 75 degrees), tested along SIGHT_LINES lines of that cone; a line
# crossing only surface more than SIGHT_GAP median spacings from every point crosses a closure; every k-th point is
# tested, at most SIGHT_POINTS. A target is carved where more than MIN_REVEALING of the tested points are hidden with
# such a line. Shares on the 28 dev meshes of bench_pointcloud's two range tables (30k points, grid 64; 2026-12-04),
# carved or not: 6 views, the cup abc_00000009 3.8%, the cap abc_00000006 0.65%, cad_nmc_sample0 0.75%, carved: CD 155
# / 85 / 87 -> 4.8 / 22.5 / 25.6 (alpha wrap 7.0 / 32.9 / 33.5), NC +0.004 to +0.010, F1 0.52 / 0.63 / 0.63 -> 0.58 /
# 0.53 / 0.52 (the unseen inner walls sit a guessed wall off); the rest 0-0.013%. 3 views: thingi32_252119 0.95%
# carved (CD 23.6 -> 15.3, NC 0.825 -> 0.807, F1 0.717 -> 0.646); the rest 0-0.47% (the cup 0.39%: carved at 0.2%, CD
# 130 -> 45). A third missing, where points were sampled, not seen, and the assumption fails: abc_00000001 3.97% (CD
# 409 -> 411, NC 0.785 -> 0.802), thingi32_252119 2.0% (CD 341 -> 350, NC 0.792 -> 0.783, F1 0.695 -> 0.629) and
# organic_cheburashka 0.69% (CD 283 -> 477, NC 0.918 -> 0.859: the carve opens the solid behind the cut) carved; the
# other 25 at 0-0.44%. The 12 benchmark meshes' other 8 conditions: never carved.
SIGHT_ANGLE = 70.0
SIGHT_LINES = 32
SIGHT_GAP = 6.0
SIGHT_POINTS = 20_000
MIN_REVEALING = 0.005
# Objects far apart (voro3d.reconstruction._objects) are told apart on every k-th point, at most SEPARATE_POINTS of
# them (every point then goes with its nearest subset point; a group that ends under MIN_POINTS joins the rest). The
# same groups, point for point, as from every point on 10^6 samples of bunny, fandisk and thingi32_75655 (one group),
# two 500k bunnies 1.05 and 2.2 box sides apart (one: their grown boxes overlap) and a 500k bunny with 2,000 or 300
# points of spot 3 sides away (two); 1.1-2.8 s instead of 3.4-10.6 s (2026-12-04, beside another benchmark).
SEPARATE_POINTS = 200_000
# Adam steps of a cloud's fit (a mesh's stays 400): its mesh is fitted to the target afterwards, which settles what
# the last steps would. 4 dev meshes x clean 20k / 0.5% noise / a third missing at grid 64, 200 against 400 steps: CD
# +0.04% on average, +0.78% at worst (bunny clean), NC at worst -0.0007, F1 within 0.001; the fit 0.67x and the whole
# call 0.84x the time. Bunny and fandisk at 100k clean points and 3-view range scans: CD -0.9% to +0.8%, NC at worst
# -0.0018. 120 against 200 (2026-12-04): 6 dev meshes (bunny, fandisk, armadillo, abc_00000005, cow, thingi32_75655) x
# clean 20k / 0.5% noise / a third missing / 3-view range scans at grid 64, mean CD +0.6% / -0.7% / -0.0% / +0.0%
# (worst +1.6%, thingi32_75655 clean), NC -0.0002 to -0.0004 on average (worst -0.0012), F1 within 0.0001, the fit
# 0.72-0.80x; 6 dev meshes (armadillo, fandisk, abc_00000005 / 08, bunny, screwdriver) at 10^5 true-normal points,
# grid "auto": CD -0.6% to +0.6%, NC at worst -0.0006, edge F-score (bench_edges' measure) up on 5 of 6, mean 0.419 ->
# 0.454. At 80 steps NC fell by up to 0.0024. What it costs: thin walls from dense oriented points converge less far.
# 5 CAD dev meshes at 2x10^5 true-normal points: the lid abc_00000007 NC 0.970 -> 0.964 and 12% more faces, the cup
# abc_00000009 NC 0.9943 -> 0.9916 and 13% more faces; abc_00000001, screwdriver and rocker-arm CD -2.6% to +0.3%, NC
# at worst -0.0007 (bench_edges over its 11 meshes: edge F-score 0.355 -> 0.371).
CLOUD_STEPS = 120
# Steps on the faces between inside and outside cells alone after the labels (fitting.fit_samples' boundary_steps; not
# in the tiles over TILE_POINTS). In poste_france's slab, a cell or two thick, faces between inside cells held the
# samples while inside cells poked out: the mesh area near the points tilted over 30 degrees off their plane fits,
# seeds 0 / 1 / 2, 2.0% / 0.17% / 0.17% -> 0.14% / 0.16% / 0.16% (40 more ordinary steps: bumps). 12 benchmark meshes,
# grid 64, no normals (2026-12-06, quiet), mean CD / NC without -> with: 1 / 3 / 6 views 138.61 / 39.17 / 1.286 ->
# 138.69 / 39.24 / 1.289, NC 0.8146 / 0.9167 / 0.9723 -> 0.8143 / 0.9164 / 0.9730; clean 5k / 20k, 0.5% noise 2.434 /
# 0.635 / 1.361 -> 2.429 / 0.632 / 1.352, NC +0.0002 to +0.0006; F1 within 0.0012; per cloud 0.95-1.08x; the fit 0.28
# s a cloud longer. bench_edges 0.358 -> 0.359; with 100 main steps the same CD, 0.13 s less, edge F-score 0.353.
# Rerun: bench_pointcloud.py --no-poisson, bench_edges.py, with the constant set.
CLOUD_BOUNDARY_STEPS = 40
# VoroLoss samples of a cloud's fit per grid face (a mesh's stay 150, the official code's): its mesh is fitted to the
# target afterwards. 6 dev meshes x clean 20k / 0.5% noise / clean 100k / 3-view range scans at grid 64, 75 against 150
# (benchmarks/results/cloud_samples.md): CD +0.1% to +0.4% on average per condition (-2.3% on the scans), +4.2% at worst
# (a 3-view scan; +2.2% on the rest), NC at worst -0.0008 on average, F1 within 0.0005; samples and fit 0.56-0.64x, the
# call 0.83-0.87x the time. At 40: CD +0.5%, +3.2% at worst, NC -0.0019 on clean 100k, for 0.4x the fit.
CLOUD_SAMPLES_PER_FACE = 75
# kNN candidates of a cloud's fit searched again after a generator moved this many voxels (a mesh's fit keeps
# fitting.REFRESH_VOXELS, 1.5; both at most fitting.MAX_REFRESH_DISTANCE, 2.5 voxels at 64^3). 16 dev meshes at 10^5
# true-normal points (grid "auto": 128 over 3 levels), 1.5 against 2.5: searches 8-12 -> 5-8, fit CPU time 0.54-0.80x
# (8 of them), the call 0.89x; CD -0.4% to +0.6% (mean +0.1%), NC within 0.0003, F1 -0.0008 to +0.0025, faces up to
# +2.5%. At 3.5 voxels (8 meshes): 3-5 searches, NC down to -0.0011 and faces up to +4.4%. At grid 64 (the cap), 6 dev
# meshes x clean 20k / 0.5% noise / 3-view range scans: searches 4-6 -> 2-3, fit CPU 0.61-1.04x; mean CD -0.1% / +0.5%
# / 0.0% (worst +1.1%, on noise), NC at worst -0.0010 / -0.0008 / -0.0020.
CLOUD_REFRESH_VOXELS = 2.5
# A point is suspected (preprocess.outlier_mask) whose 8th neighbour lies over SPARSE_SPACINGS times the median
# 8th-neighbour distance away, or whose mean distance to 20 neighbours is over STRAY_RATIO times theirs (median).
# Sparse 6 / 4 / 3, 12 benchmark meshes (2026-12-07): flying pixels from 3 views CD 150.0 / 126.1 / 125.3, one piece
# 83 / 75 / 100%, 1 view 189.3 / 166.0 / 171.3; range scans 1 view 138.8 / 141.9 / 144.3, ramp 0.553 / 0.556 / 0.571.
# 26 other dev meshes, 6 / 4: flying 3 views 182.2 / 149.9, F1 0.596 / 0.586, one piece 96 / 92%; 1 view 237.7 /
# 235.4; ramp 17.29 / 17.31. Kept: lower, flying pixels gain erratically (x0.15 to x4.5 a shape) and sparse surface
# goes. Stray 1.5 / 2 / 3, on 6 meshes, dropped: 5246 / 5114 / 4569 of 5,275 uniform outliers, 2949 / 2313 / 1311 of
# 3,639 flying pixels, 171 / 17 / 4 of 157k 3-view range points. Rerun: bench_pointcloud.py --sparse-spacings 4.
SPARSE_SPACINGS = 6.0
STRAY_RATIO = 2.0
# A point the outlier tests suspect (preprocess.outlier_mask: sparse, or a stray) stays when it and its 20 neighbours
# lie within SUSPECT_FLATNESS of their in-plane spread (RMS) of one plane, itself within SUSPECT_OFFSET (the centre of
# a curved patch sits off the patch's plane by about twice its RMS): a part of the surface sampled far more sparsely
# than the rest. Suspects kept, 12 benchmark meshes, flatness 0.1 and offset 0.1 / 0.15 / 0.2: the uniform outliers of
# "outliers 2%" 0 / 1 / 1 of 10,359 (both at 0.15: 33); 1% noise 0 of 234; the dev scan radar.xyz (a sphere sampled
# 100 times more densely in places) 476 / 490 / 496 of 502; a unit sphere of 150k points with a cap sampled 100 times
# more sparsely 420 / 487 / 487 of 487 (45k points, cap spacing 0.36 of the radius: 47 / 101 / 115 of 149); 1-view
# range scans 38 / 41 / 45 of 100 (grazing silhouettes). Mean scan point distance to the mesh (diagonals), before ->
# after (clumps of _small_clusters kept among the rest): radar 2.99e-3 (1,147 points dropped, a side left open) ->
# 1.26e-4 (12 dropped, closed; Poisson 6.06e-4), hippo2 8.96e-4 -> 5.43e-4 (Poisson 7.08e-4).
SUSPECT_FLATNESS = 0.1
SUSPECT_OFFSET = 0.15
# Statistics of large clouds are medians or means over a random subset of this many points
# (:func:`~voro3d.queries.knn_blocks`): the noise and fine noise (cloud_stats) and the local dimension over
# STATISTICS_SAMPLE, the sign disagreement of given normals over SIGN_SAMPLE (16 pairs a point). 4 dev meshes (bunny,
# fandisk, armadillo, abc_00000005) at 10^6 points, clean and at 0.5% noise, subset against every point: noise within
# 0.1% (fine noise 0.5%; fandisk's and abc's clean noise, under 1e-7, within 2%), dimension within 0.08%, sign
# disagreement with 5% of the normals flipped within 0.0009 of 0.095 (true normals: within 0.0001); cloud_stats
# 2.5-4.8 s instead of 8-10 s (those figures with subsets of 200k and 100k). Clouds up to these sizes use every point.
# STATISTICS_SAMPLE 50k: the same 4 meshes at 10^5 points, clean and at 0.25% noise, read noise within 1% of every
# point's, and their clean 100k / density ramp 20x / 2% outliers outputs are unchanged (CD, NC, F1 to 4 digits); the
# clean phase 0.54-0.79 s instead of 0.83-1.36 s. SIGN_SAMPLE 20k: the sign disagreement only decides against
# MAX_SIGN_DISAGREEMENT; on those meshes at 10^5 points (true normals, 5% flipped, Open3D's estimate_normals()) it
# reads within 0.0018 of every point's (0 / 0.0045-0.062 / 0.130-0.150), in 0.1 s instead of 0.4-0.8 s.
STATISTICS_SAMPLE = 50_000
SIGN_SAMPLE = 20_000
# A cloud sampled along lines far apart for their spacing along them (a LiDAR's scan lines) is thinned along them
# (scanlines.thin_lines) while the median middle-over-largest eigenvalue of its 9-point neighbourhoods, or of its
# 25-point ones, read at every k-th point (at most LINE_SAMPLE: within 0.003 of every point's on 12k-100k-point clouds
# (9 points), 0.025 s against 0.48 s at 10^5), is under LINE_RATIO. The lower of the two reads 0.40-0.67 on every
# cloud of the 38 dev meshes x the benchmark's 24 other conditions (lowest: sparse 300, 0.399) and on the 4 real scans
# (0.41-0.47); 0.002-0.043 on LiDAR scans whose lines lie 5 to 50 times as far apart as the steps along them (the 38
# dev meshes from the 48-beam LiDAR at 1 and 3 positions: all thinned); 0.33-0.36 at 4 times, where the bunny needs no
# thinning (NC 0.912 unthinned, 0.910 thinned). Over 9 points alone, a 128-beam bunny (lines 20x apart, depth noise as
# wide as a step) read 0.12: not thinned, CD 77.9, NC 0.612, 15.4 s; with the 25 (0.03), thinned 179k -> 33k points in
# 4 rounds, CD 22.2, NC 0.946, 6.1 s. The 12 benchmark meshes so ("dense lidar", 70k-204k points): over 9 points
# 0.103-0.125, none thinned; with the 25 0.023-0.040, all thinned: grid 64, CD 134.4 -> 22.6, NC 0.645 -> 0.924, F1
# 0.302 -> 0.694, 6.9 -> 5.4 s a cloud (alpha wrap 171.3 / 0.863 / 0.548). 12 benchmark meshes from a 48-beam LiDAR
# (lines 10x apart; bench_pointcloud "lidar"), grid 64, thinned against not (--line-ratio 0), 2026-12-07: 3 positions
# CD 89.5 -> 33.2, NC 0.665 -> 0.880, F1 0.329 -> 0.582, 4.2 -> 2.8 s a cloud; 1 position CD 1065 -> 988, NC 0.594 ->
# 0.712, F1 0.180 -> 0.265; unthinned the surfaces come apart in strips along the lines. A bunny from 16 beams (50x):
# NC 0.586 -> 0.792. Cubes of the mean 8-neighbour distance instead of twice the nearest one (one round, fewer points
# left), 4 of those meshes from 3 positions at grid auto: CD 73.3 / 11.6 / 78.5 / 83.2 against 76.2 / 7.9 / 74.0 /
# 76.7, NC within 0.009 either way. Merging only the points still on lines, cubes doubling each round, did no better
# (3 positions 33.8 / 0.887 / 0.574; objects on a plate from 3 positions CD 56.9 against 52.2, NC 0.876 against 0.884).
# THIN_ROUNDS only bounds the loop on points along a true curve (a wire), which no round makes two-dimensional.
LINE_RATIO = 0.1
LINE_SAMPLE = 5_000
THIN_ROUNDS = 6
# Clouds of more than TILE_POINTS distinct points are reconstructed from a uniform subset of ANALYSIS_POINTS
# (statistics, normals, the target at MAX_TARGET_GRID, the samples) and fitted in tiles of at most TILE_SAMPLES
# samples (voro3d.pointcloud.tiles); TILE_MARGIN: coarsest voxels of the band around a tile from which it also takes
# samples and generators. The rest of the points add nothing at the target's resolution: 3M bunny points, all of them
# the samples in tiles at 141^3, CD 0.5987 / NC 0.9853 (0.6131 / 0.9726 without the snap to the target), against
# 0.5907 / 0.9900 from the target's samples at 128^3 (Poisson's samples beat the points, see target_samples).
TILE_POINTS = 2_000_000
ANALYSIS_POINTS = 1_000_000
TILE_SAMPLES = 500_000
TILE_MARGIN = 2.0
# The pass that fits the generators within SEAM_WIDTH coarsest voxels of the tiles' cuts again, for
# SEAM_STEPS steps (voro3d.pointcloud.tiles.fit_tiles). 400k samples of the bunny, 63^3 over 2 levels,
# seeds 0 and 1, CD / NC against one untiled fit (0.6055 / 0.9788, 0.6050 / 0.9785): 4 tiles without
# the pass 0.6230 / 0.9759, 0.6187 / 0.9761 (margin 4 coarsest voxels: 0.6144, 0.6161); with it
# 0.6035 / 0.9784, 0.6007 / 0.9786; 8 tiles without 0.6349, 0.6386, with 0.6039 / 0.9786, 0.6022 / 0.9790.
SEAM_WIDTH = 1.0
SEAM_STEPS = 100
# A Poisson target of at least SPLIT_POINTS points is solved in two halves at once, in two processes
# (voro3d.pointcloud.poisson.poisson_surface: Open3D's solver must run on one thread to repeat exactly, and holds the
# interpreter). poisson_surface alone at depth 8, whole against split with a started helper (2026-12-04, shared
# machine): armadillo 30k / 50k / 70k / 100k points 2.97 / 4.41 / 4.50 / 5.13 s -> 2.14 / 3.36 / 3.73 / 4.31 s, bunny
# 1.92 / 4.80 / 7.39 / 9.65 -> 1.97 / 5.16 / 5.45 / 6.78 s; the helper's start (importing Open3D, about 1 s of the
# other core) is paid whether or not the target turns out to be Poisson, so only from here on. Whole reconstruct,
# fresh processes, old and new interleaved in one session (load 1.3-1.9): 10^5 true-normal points, bunny / armadillo /
# fandisk / abc_00000005 15.6 / 12.4 / 12.0 / 9.8 -> 13.6 / 12.0 / 11.0 / 9.0 s (summed 0.92x; against Poisson depth 8
# alone 3.42x -> 3.13x); the same without normals, grid 64, bunny / armadillo / fandisk 13.4 / 10.2 / 10.5 -> 11.6 /
# 10.1 / 9.8 s (0.92x); 10^6 points (margin 8) armadillo 49.6 -> 41.1 s, bunny 54.1 -> 48.0 s. All 38 dev meshes at
# 10^5 points without normals (pointcloud_dense38): CD 0.6588 -> 0.6557, NC 0.9821 both, F1 0.9382 -> 0.9381.
SPLIT_POINTS = 60_000
# Each half takes the points up to this many octree cells past the cut. Against the surface solved whole (armadillo
# and fandisk, 10^5 points, depth 8), the halves' vertices lie at most 0.28-0.40 cells off it (0.07-0.10 at the 99th
# percentile) for a margin of 2, 4, 8 or 16 cells alike: the difference is the halves' own octree alignment, not the
# cut (at the cut 0.12-0.36). Whole reconstruct, 10^5 true-normal points, bunny / armadillo / fandisk / abc_00000005,
# CD whole 0.5951 / 0.4651 / 0.6683 / 0.6318; split with a margin of 4: 0.5918 / 0.4677 / 0.6675 / 0.6359; 8: 0.5941 /
# 0.4659 / 0.6665 / 0.6311; 16: 0.5914 / 0.4645 / 0.6649 / 0.6339 (NC within 0.0005 of whole's, F1 within 0.0012): any
# tiny change of the target moves the fit as much; the widest margin is safest where a hole crosses the cut.
SPLIT_MARGIN_CELLS = 16
# Thin walls sampled on both sides (preprocess.two_sheets, wall_points): where a plane fit spans both sides of a wall
# (at 20k points the cup abc_00000009's 16-neighbour fits are 27.8 degrees off the true normals, 1.0-1.2 with 6-8
# neighbours; bench_thin_walls), the plane of the 8 nearest gives the normal's axis and the noise. The far sheet needs
# TWO_SHEET_POINTS points and must stand TWO_SHEET_CLEARANCE times the near part's scatter off its plane (noisy clouds
# read two sheets at 6-7% of their points instead of 16-20% without it). A point counts only where WALL_VOTE of its 16
# nearest read two sheets too (a wall runs on; noise is speckle). Share of the points, 24-neighbour test alone -> with
# the vote, the 12 benchmark meshes without normals: 0.25-1% noise 1.2-13.3% -> 0-0.5%; clean 5k 12.8-29.7% ->
# 3.3-15.9%; clean 20k 5.2-24.5% -> 1.8-6.9%; range scans 1.4-23.4% -> 0.5-8.7%; the cup at 20k 71.3% -> 68.2%, the
# lid abc_00000007 34.3% -> 19.5%, a tube 2 spacings thick at 30k points (tests) 87.5% -> 85.6%.
TWO_SHEET_POINTS = 2
TWO_SHEET_CLEARANCE = 4.0
WALL_VOTE = 0.5
