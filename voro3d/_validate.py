"""One place that checks arrays at the public boundary and names what is wrong.

Validation happens once per call, at the boundary: a pipeline (``reconstruct``, ``fit``,
``VoroMesh.to_open3d``, ...) checks what it was given, then runs its stages inside
:func:`trusted`, where the array checks of the public functions it calls only convert.
"""
from __future__ import annotations

import contextlib
from contextvars import ContextVar

import numpy as np

# True inside a pipeline whose inputs were checked at its boundary.
_TRUSTED = ContextVar("voro3d_trusted", default=False)


@contextlib.contextmanager
def trusted():
    """Inputs inside are already checked: :func:`as_points`, :func:`as_mask` and ``io.mesh_arrays`` only convert."""
    token = _TRUSTED.set(True)
    try:
        yield
    finally:
        _TRUSTED.reset(token)


def is_trusted() -> bool:
    """Whether the caller runs inside :func:`trusted`."""
    return _TRUSTED.get()


def as_points(value, name: str, *, min_count: int = 1, dtype=np.float64) -> np.ndarray:
    """Return ``value`` as a finite ``(n, 3)`` array of ``dtype`` (inside :func:`trusted`: converted only).

    Raises
    ------
    ValueError
        If ``value`` is not numeric, the shape is not ``(n, 3)``, fewer than ``min_count`` rows arrive,
        or any coordinate is NaN or infinite.
    """
    if _TRUSTED.get():
        return np.ascontiguousarray(value, dtype=dtype)
    array = np.asarray(value)
    if array.dtype == object or not (np.issubdtype(array.dtype, np.floating) or np.issubdtype(array.dtype, np.integer)):
        raise ValueError(f"{name} must be a numeric array, got dtype {array.dtype}")
    if array.ndim != 2 or array.shape[1] != 3:
        raise ValueError(f"{name} must have shape (n, 3), got {array.shape}")
    if array.shape[0] < min_count:
        raise ValueError(f"{name} must hold at least {min_count} points, got {array.shape[0]}")
    array = np.ascontiguousarray(array, dtype=dtype)
    bad = ~np.isfinite(array).all(axis=1)
    if bad.any():
        raise ValueError(f"{name} holds {int(bad.sum())} rows with NaN or inf (first at row {int(np.flatnonzero(bad)[0])})")
    return array


def finite_rows(points, name: str, *, stacklevel: int = 3) -> np.ndarray | None:
    """The rows of an ``(n, 3)`` array whose coordinates are all finite, as a bool mask, or None
    when all are (or none is: the caller's own check then names the problem). Rows that are not
    are left out with a warning: an organized scan (PCL's ``.pcd``, a depth image) writes its empty
    pixels as NaN."""
    import warnings

    keep = np.isfinite(points).all(axis=1)
    if keep.all() or not keep.any():
        return None
    warnings.warn(f"{name}: {int((~keep).sum()):,} of {len(keep):,} points have NaN or inf coordinates (empty "
                  "pixels of an organized scan?); they are left out", stacklevel=stacklevel)
    return keep


def as_mask(value, name: str, length: int) -> np.ndarray:
    """Return ``value`` as a ``(length,)`` bool array; 0/1 integers are accepted.

    Inside :func:`trusted`: converted only.
    """
    if _TRUSTED.get():
        return np.asarray(value, dtype=bool)
    array = np.asarray(value)
    if array.ndim != 1 or array.shape[0] != length:
        raise ValueError(f"{name} must have shape ({length},), got {array.shape}")
    if array.dtype == bool:
        return array
    if np.issubdtype(array.dtype, np.integer) or np.issubdtype(array.dtype, np.floating):
        if not np.isin(array, (0, 1)).all():
            raise ValueError(f"{name} must be boolean (or 0/1), got values outside {{0, 1}}")
        return array.astype(bool)
    raise ValueError(f"{name} must be a boolean array, got dtype {array.dtype}")


def as_sdf_grid(value, name: str = "sdf", *, min_size: int = 2, dtype=np.float64) -> np.ndarray:
    """Return ``value`` as a finite ``(g, g, g)`` grid of ``dtype`` with a zero crossing.

    Raises
    ------
    ValueError
        Not a floating-point or integer array, not a cube with ``g >= min_size``, NaN or inf
        values, or no sign change (a negative node, inside, and a positive one, outside, are both
        needed).
    """
    array = np.asarray(value)
    if array.dtype == bool or not (np.issubdtype(array.dtype, np.floating) or np.issubdtype(array.dtype, np.integer)):
        raise ValueError(f"{name} must be a floating-point or integer array, got dtype {array.dtype}")
    if array.ndim != 3 or len(set(array.shape)) != 1 or array.shape[0] < min_size:
        raise ValueError(f"{name} must have shape (g, g, g) with g >= {min_size}, got {array.shape}")
    array = array.astype(dtype, copy=False)
    bad = int((~np.isfinite(array)).sum())
    if bad:
        raise ValueError(f"{name} holds {bad} NaN or inf values")
    low, high = array.min(), array.max()
    if not low < 0 < high:
        missing = "inside (negative)" if low >= 0 else "outside (positive)"
        raise ValueError(f"{name} has no zero crossing: values span [{low:.4g}, {high:.4g}], no node is {missing}")
    return array


def positive_int(value, name: str, *, minimum: int = 1) -> int:
    """Return ``value`` as an int ``>= minimum``."""
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
        raise TypeError(f"{name} must be an integer, got {type(value).__name__}")
    if value < minimum:
        raise ValueError(f"{name} must be >= {minimum}, got {value}")
    return int(value)


MIN_GRID = 4
# A mesh has no point spacing to choose a grid from: grid="auto" is this for a mesh.
MESH_AUTO_GRID = 32


def grid_option(grid, *, allow_auto: bool = True):
    """``grid`` checked by the one rule of every entry point: ``"auto"`` or an integer >= ``MIN_GRID``.

    Raises
    ------
    ValueError
        Any other string (``"auto"`` too where ``allow_auto`` is False), or an integer under ``MIN_GRID``.
    TypeError
        Neither a string nor an integer.
    """
    if isinstance(grid, str):
        if grid == "auto" and allow_auto:
            return grid
        expected = "'auto' or an integer" if allow_auto else "an integer"
        raise ValueError(f"grid must be {expected} >= {MIN_GRID}, got {grid!r}")
    return positive_int(grid, "grid", minimum=MIN_GRID)


def mesh_grid(grid) -> int:
    """A mesh's grid: :func:`grid_option`, with ``"auto"`` as ``MESH_AUTO_GRID`` (a mesh has no point spacing)."""
    grid = grid_option(grid)
    return MESH_AUTO_GRID if grid == "auto" else grid


def method_options(method: str, owner: str, **options) -> dict:
    """The ``options`` given (not None), refused unless ``method`` is ``owner``, the method that uses them.

    Another method would ignore them, so they are refused instead of dropped: a caller who sets
    ``steps`` for the learned model expects it to matter.

    Raises
    ------
    ValueError
        An option given for a method other than ``owner``, naming both.
    """
    given = {name: value for name, value in options.items() if value is not None}
    if given and method != owner:
        raise ValueError(f"method={method!r} takes no {' or '.join(given)} (only method={owner!r} uses "
                         f"{'it' if len(given) == 1 else 'them'})")
    return given
