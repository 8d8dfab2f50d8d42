"""Debris in a fitted VoroMesh: small groups of cells cut off from their kind, relabelled."""
from __future__ import annotations

import numpy as np

from .tuning import STRAY_CELL_SHARE

__all__ = ["drop_stray_cells"]


def drop_stray_cells(shape):
    """The VoroMesh with specks of debris relabelled: small groups of cells cut off from their kind.

    Inside cells joined by Voronoi faces (Delaunay edges) form groups; a group of fewer than
    ``STRAY_CELL_SHARE`` of the largest group's cells (and at most 8) is a speck: cells whose
    label the samples nearby could not settle, turned outside. Likewise a group of outside cells
    that does not reach the exterior (the bounding corners) and is that small against the
    exterior's group (or has at most 8 cells) is a bubble in the solid, turned inside: no scan
    sees into a closed cavity. Flipping whole cells keeps the surface closed: it is extracted
    again from the labels.
    """
    from ..geometry import components

    if shape.occupancy.sum() < 2:
        return shape
    triangulation = shape.triangulated()
    n = triangulation.n_sites
    inside = triangulation.site_occupancy(shape.occupancy)  # the 8 bounding corners are outside
    tets = triangulation.tets
    edges = tets[:, [0, 0, 0, 1, 1, 2, 1, 2, 3, 2, 3, 3]].reshape(-1, 2, 6).transpose(0, 2, 1).reshape(-1, 2)
    same = edges[inside[edges[:, 0]] == inside[edges[:, 1]]]
    groups, group = components(n + 8, same)
    size = np.bincount(group, minlength=groups)
    kind = np.zeros(groups, bool)
    kind[group[inside]] = True
    largest_inside = size[kind].max()
    stray = kind & (size < STRAY_CELL_SHARE * largest_inside) & (size <= 8)
    exterior = np.unique(group[n:])
    bubble = ~kind & ((size < STRAY_CELL_SHARE * size[exterior].max()) | (size <= 8))
    bubble[exterior] = False
    flip = (stray | bubble)[group[:n]]
    if not flip.any():
        return shape
    return shape.relabelled((inside[:n] ^ flip)[triangulation.site])
