"""Point clouds in: outlier removal, normals, a smooth target surface, the VoroLoss fit to it.

io -> pointcloud.preprocess (outliers, spacing, noise) -> pointcloud.normals -> pointcloud.poisson
(closed clouds; pointcloud.denoise filters it where the noise is heavy) or pointcloud.surface
(IMLS + winding-number field for one-sided scans) -> pointcloud.reconstruct (samples, fit, the mesh
fitted to the target) -> pointcloud.colors (a coloured cloud's colours on the mesh).
"""
from .normals import estimate_normals, orient_normals, repair_normals, sign_disagreement
from .preprocess import cloud_stats, fill_ratio, local_dimension, merge_duplicates, outlier_mask, separate_objects
from .colors import transfer_colors
from .reconstruct import PointCloudInfo, SnapTarget, auto_grid, cloud_mesh, max_supported_grid, reconstruct_points
from .poisson import PoissonSurface, poisson_surface
from .surface import TargetSurface, imls, target_surface

__all__ = ["estimate_normals", "orient_normals", "repair_normals", "sign_disagreement", "cloud_stats", "fill_ratio",
           "local_dimension", "merge_duplicates", "outlier_mask", "separate_objects", "PointCloudInfo", "SnapTarget",
           "auto_grid", "cloud_mesh", "max_supported_grid", "reconstruct_points", "transfer_colors", "TargetSurface", "imls",
           "target_surface", "PoissonSurface", "poisson_surface"]
