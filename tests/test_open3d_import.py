"""voro3d keeps Open3D's plotly/dash web viewer out of `import open3d` until something uses it."""
import subprocess
import sys

_SCRIPT = """
import sys
{first}
import open3d as o3d
print("dash" in sys.modules or "plotly" in sys.modules)
box = o3d.geometry.TriangleMesh.create_box()
figure = o3d.visualization.get_plotly_fig([box])
viewer = sys.modules["open3d.visualization.draw_plotly"]
print(type(figure).__name__, "dash" in sys.modules, o3d.visualization.draw_plotly is viewer.draw_plotly,
      callable(o3d.visualization.draw_plotly_server), hasattr(viewer, "Dash"))
"""


def _run(first):
    result = subprocess.run([sys.executable, "-c", _SCRIPT.format(first=first)], capture_output=True, text=True,
                            timeout=120)
    assert result.returncode == 0, result.stderr
    return result.stdout.split()


def test_import_open3d_after_voro3d_skips_the_viewer_until_it_is_used():
    # After first use the viewer is the real module and open3d.visualization binds its functions.
    assert _run("import voro3d") == ["False", "Figure", "True", "True", "True", "True"]


def test_open3d_imported_first_is_left_as_it_is():
    assert _run("import open3d, voro3d") == ["True", "Figure", "True", "True", "True", "True"]
