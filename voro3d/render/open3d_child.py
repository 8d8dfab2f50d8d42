"""One Open3D panel in a process of its own: ``python -m voro3d.render.open3d_child JOB.npz OUT.npy``.

One fresh Filament renderer, one frame, then exit, so that a stall or an abort (a broken GPU
driver can abort a process instead of raising) costs only this child; the parent
(:mod:`voro3d.render.open3d_backend`) gives it a time limit. Reusing a renderer, or a second one in
the same process, made stalls on Mesa llvmpipe far more likely, and two live renderers abort at
exit. With the single argument ``device`` it only starts the engine, which prints the device it
chose. It prints ``VORO3D-PANEL-DONE`` when it has finished.

``JOB.npz`` holds ``size (2,)``, ``vertices (v, 3) float64``, ``triangles (t, 3) int32``,
``normals (v, 3)``, ``light (3,)``, ``fov``, ``center``, ``eye``, ``up`` and either ``colors (v, 3)``
(linear RGB per vertex) or ``base_color (3,)``; ``OUT.npy`` gets the ``(height, width, 3)`` uint8
picture.
"""
from __future__ import annotations

import sys

__all__ = ["DONE", "main"]

DONE = "VORO3D-PANEL-DONE"


def main(argv: list[str]) -> int:
    """Run the child with its command-line arguments; returns the exit status."""
    if argv not in (["device"],) and len(argv) != 2:
        print("usage: python -m voro3d.render.open3d_child (device | JOB.npz OUT.npy)", file=sys.stderr)
        return 2
    import numpy as np
    import open3d as o3d

    rendering = o3d.visualization.rendering
    if argv == ["device"]:
        renderer = rendering.OffscreenRenderer(16, 16)
        del renderer
        print(DONE, flush=True)
        return 0
    job_path, image_path = argv
    job = dict(np.load(job_path))
    o3d.utility.set_verbosity_level(o3d.utility.VerbosityLevel.Error)
    width, height = (int(x) for x in job["size"])
    renderer = rendering.OffscreenRenderer(width, height)
    scene = renderer.scene
    scene.set_background([1.0, 1.0, 1.0, 1.0])
    scene.show_skybox(False)
    scene.set_lighting(rendering.Open3DScene.LightingProfile.NO_SHADOWS, job["light"].astype(np.float32))
    scene.view.set_sample_count(4)
    mesh = o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(job["vertices"]),
                                     o3d.utility.Vector3iVector(job["triangles"]))
    mesh.vertex_normals = o3d.utility.Vector3dVector(job["normals"])
    material = rendering.MaterialRecord()
    material.shader = "defaultLit"
    if "colors" in job:
        mesh.vertex_colors = o3d.utility.Vector3dVector(job["colors"])
        material.base_color = [1.0, 1.0, 1.0, 1.0]
    else:
        material.base_color = [*job["base_color"].tolist(), 1.0]
    material.base_roughness = 0.7
    material.base_reflectance = 0.3
    scene.add_geometry("mesh", mesh, material)
    renderer.setup_camera(float(job["fov"]), job["center"].astype(np.float32), job["eye"].astype(np.float32),
                          job["up"].astype(np.float32))
    image = np.asarray(renderer.render_to_image())[:, :, :3].copy()
    scene.clear_geometry()  # geometry still attached when the engine goes away aborts the process
    del scene, renderer
    np.save(image_path, image)
    print(DONE, flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
