"""A compact, lossy copy of a stage-1 training set, for moving it to a GPU machine.

A cached shape (:func:`voro3d.learn.data.build_dataset`) is about 1.4 MB; stage 1 needs only its
SDF grids near the surface and its surface samples, which pack into about 60 kB:

* each SDF grid in voxels, clipped to ``±clip`` (the network reads ``|sdf| < context``, 3 voxels),
  quantised to ``1 / SDF_LEVELS`` voxel, differenced along the last axis and LZMA-compressed;
* ``n_samples`` surface samples, quantised to ``SAMPLE_BITS`` bits per coordinate of the
  ``[-1, 1]^3`` frame (1/65 of a voxel at 64^3), sorted along the lattice of a 64^3 grid,
  differenced and LZMA-compressed.

The meshes are left out, so stage 2 (occupancy labels from the mesh's inside test) runs where the
full cache is. :func:`unpack_dataset` writes ordinary cache files (``sdf_<g>`` and ``samples``,
empty ``vertices`` and ``triangles``) with the source cache's ``index.json``, so that
:func:`~voro3d.learn.data.build_dataset` and :class:`~voro3d.learn.data.ShapeSet` read them as
they are.
"""
from __future__ import annotations

import json
import lzma
from pathlib import Path

import numpy as np

from .._validate import positive_int
from ..geometry import grid_voxel
from ..io import atomic_path

__all__ = ["SAMPLE_BITS", "SDF_LEVELS", "pack_dataset", "pack_shape", "unpack_dataset", "unpack_shape"]

# Quantisation steps per voxel of a packed SDF grid: 0.002 voxel, far below what the network sees.
SDF_LEVELS = 512
# Bits per coordinate of a packed sample in [-1, 1]: a step of 4.9e-4, 1/65 of a 64^3 voxel.
SAMPLE_BITS = 12
# A packed sample coordinate is round((x + 1) * _SAMPLE_SCALE).
_SAMPLE_SCALE = (2**SAMPLE_BITS - 1) / 2.0
_PRESET = 9 | lzma.PRESET_EXTREME


def _compress(array: np.ndarray) -> np.ndarray:
    return np.frombuffer(lzma.compress(np.ascontiguousarray(array).tobytes(), preset=_PRESET), np.uint8)


def _decompress(blob: np.ndarray, dtype, shape) -> np.ndarray:
    return np.frombuffer(lzma.decompress(blob.tobytes()), dtype).reshape(shape)


def pack_shape(record: dict, *, n_samples: int, clip: float = 3.25, seed: int = 0) -> dict:
    """The packed arrays of one cached shape.

    Parameters
    ----------
    record : dict
        A :class:`~voro3d.learn.data.ShapeSet` item: ``sdf_<g> (g, g, g)`` float32 and ``samples (m, 3)`` float32.
    n_samples : int
        Samples kept (a random subset, all when ``m`` is smaller).
    clip : float
        SDF clip in voxels; values beyond it come back as ``±clip``.
    seed : int
        Seed of the subset.

    Returns
    -------
    dict of str to numpy.ndarray
        ``sdf_<g>`` and ``samples`` as compressed byte arrays, ``clip`` and ``n_samples``.
    """
    n_samples = positive_int(n_samples, "n_samples")
    packed = {"clip": np.float64(clip)}
    for name in sorted(k for k in record if k.startswith("sdf_")):
        sdf = record[name]
        step = grid_voxel(sdf.shape[0])
        levels = np.round(np.clip(sdf / step, -clip, clip) * SDF_LEVELS).astype(np.int16)
        packed[name] = _compress(np.diff(levels, axis=2, prepend=0).astype(np.int16))
    samples = record["samples"]
    keep = np.random.default_rng(seed).permutation(samples.shape[0])[:n_samples]
    quantised = np.round((np.clip(samples[keep], -1.0, 1.0) + 1.0) * _SAMPLE_SCALE).astype(np.int32)
    cell = quantised >> (SAMPLE_BITS - 6)
    quantised = quantised[np.argsort((cell[:, 0] * 64 + cell[:, 1]) * 64 + cell[:, 2], kind="stable")]
    packed["samples"] = _compress(np.diff(quantised, axis=0, prepend=0).astype(np.int16).T)
    packed["n_samples"] = np.int64(quantised.shape[0])
    return packed


def unpack_shape(packed: dict) -> dict:
    """Inverse of :func:`pack_shape`: ``sdf_<g>`` and ``samples`` as float32, empty mesh arrays."""
    clip = float(packed["clip"])
    record = {"vertices": np.zeros((0, 3)), "triangles": np.zeros((0, 3), np.int32)}
    for name in (k for k in packed if k.startswith("sdf_")):
        g = int(name[4:])
        levels = np.cumsum(_decompress(packed[name], np.int16, (g, g, g)), axis=2, dtype=np.int32)
        record[name] = (np.clip(levels / SDF_LEVELS, -clip, clip) * grid_voxel(g)).astype(np.float32)
    n = int(packed["n_samples"])
    quantised = np.cumsum(_decompress(packed["samples"], np.int16, (3, n)).T, axis=0, dtype=np.int32)
    record["samples"] = (quantised / _SAMPLE_SCALE - 1.0).astype(np.float32)
    return record


def pack_dataset(cache_dir, out_path, *, n_samples: int, seed: int = 0) -> Path:
    """Pack every shape of a cache built by :func:`~voro3d.learn.data.build_dataset` into one ``.npz``.

    Returns
    -------
    pathlib.Path
        ``out_path``, holding each shape's packed arrays as ``<file stem>/<name>`` and the cache's index.

    Raises
    ------
    FileNotFoundError
        ``cache_dir`` holds no ``index.json``.
    """
    from tqdm import tqdm

    from .data import ShapeSet

    cache_dir = Path(cache_dir)
    index = cache_dir / "index.json"
    if not index.is_file():
        raise FileNotFoundError(f"{cache_dir} holds no index.json: not a dataset cache")
    spec = json.loads(index.read_text())
    shapes = ShapeSet([cache_dir / name for name in spec["files"]])
    arrays = {"index": np.frombuffer(json.dumps(spec).encode(), np.uint8)}
    for i in tqdm(range(len(shapes)), desc="packing", unit="shape", leave=False):
        stem = shapes.files[i].stem
        for name, value in pack_shape(shapes[i], n_samples=n_samples, seed=seed + i).items():
            arrays[f"{stem}/{name}"] = value
    with atomic_path(out_path, suffix=".npz") as tmp:
        np.savez(tmp, **arrays)
    return Path(out_path)


def unpack_dataset(pack_path, out_dir) -> list[Path]:
    """Write the shapes of a :func:`pack_dataset` file as an ordinary cache in ``out_dir``.

    Returns
    -------
    list of pathlib.Path
        The ``.npz`` files, in the source cache's order.
    """
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    files = []
    with np.load(pack_path) as data:
        spec = json.loads(data["index"].tobytes().decode())
        keys = {}  # file stem -> its packed array names
        for key in data.files:
            if "/" in key:
                keys.setdefault(key.split("/", 1)[0], []).append(key)
        for name in spec["files"]:
            packed = {key.split("/", 1)[1]: data[key] for key in keys[Path(name).stem]}
            target = out_dir / name
            with atomic_path(target, suffix=".npz") as tmp:
                np.savez(tmp, **unpack_shape(packed))
            files.append(target)
    with atomic_path(out_dir / "index.json", suffix=".json") as tmp:
        Path(tmp).write_text(json.dumps(spec, indent=1))
    return files
