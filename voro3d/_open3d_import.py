"""Let ``import open3d`` skip its plotly/dash web viewer until something uses it.

Open3D's package always imports ``open3d.visualization.draw_plotly``, which imports plotly and
dash: 1-1.9 s of the 1.5-3 s an ``import open3d`` took here, paid by every ``voro3d`` command and
batch worker that only reads and writes meshes. :func:`defer_web_viewer` puts a stand-in module
in its place that loads the real one on first use of any of its names, so Open3D's API is
unchanged, only the cost moves to the first call of ``open3d.visualization.draw_plotly`` and
friends.
"""
from __future__ import annotations

import sys
import types
from importlib import import_module

__all__ = ["defer_web_viewer"]

_VIEWER = "open3d.visualization.draw_plotly"
# The names open3d.visualization imports from the viewer module.
_FORWARDED = ("get_plotly_fig", "draw_plotly", "draw_plotly_server")


def defer_web_viewer() -> None:
    """Install the stand-in, unless Open3D or its viewer is already imported (then nothing is saved)."""
    if "open3d" in sys.modules or _VIEWER in sys.modules:
        return
    stand_in = types.ModuleType(_VIEWER)

    def real():
        if sys.modules.get(_VIEWER) is stand_in:
            del sys.modules[_VIEWER]
            module = import_module(_VIEWER)
            # Importing a submodule binds it on its package, over the function of the same name
            # (open3d.visualization.draw_plotly); bind the functions back, as Open3D's own import does.
            package = sys.modules["open3d.visualization"]
            for name in _FORWARDED:
                setattr(package, name, getattr(module, name))
        return sys.modules[_VIEWER]

    def forward(name):
        def call(*args, **kwargs):
            return getattr(real(), name)(*args, **kwargs)

        call.__name__ = call.__qualname__ = name
        return call

    def attribute(name):
        # The import system probes modules for dunder names (__path__, __spec__ ...): those must
        # not load the viewer.
        if name.startswith("__"):
            raise AttributeError(name)
        return getattr(real(), name)

    for name in _FORWARDED:
        setattr(stand_in, name, forward(name))
    stand_in.__getattr__ = attribute
    sys.modules[_VIEWER] = stand_in
