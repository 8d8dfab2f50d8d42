"""Figures the benchmarks share."""
from __future__ import annotations

import tempfile
from pathlib import Path


def render_rows(rows, out_png, *, size=(360, 300), view=None) -> None:
    """One PNG with one rendered row per entry: ``rows`` is a list of ``(meshes, titles)``,
    each row drawn side by side by :func:`voro3d.render.render_meshes` (from ``view``), rows stacked
    top to bottom. Nothing is written when ``rows`` is empty."""
    from PIL import Image

    from voro3d.render import render_meshes

    images = []
    with tempfile.TemporaryDirectory() as scratch:
        for index, (meshes, titles) in enumerate(rows):
            path = Path(scratch) / f"{index}.png"
            render_meshes(meshes, path, titles=titles, size=size, view=view)
            images.append(Image.open(path).convert("RGB"))
    if not images:
        return
    sheet = Image.new("RGB", (max(i.width for i in images), sum(i.height for i in images)), "white")
    top = 0
    for image in images:
        sheet.paste(image, (0, top))
        top += image.height
    sheet.save(out_png)
