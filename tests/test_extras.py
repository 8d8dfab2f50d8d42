"""Without an extra, what needs it says in one line which one to install; the rest works."""
import json
import subprocess
import sys

import pytest

from voro3d._extras import MissingExtra, require

# Run in a fresh interpreter where torch, onnx and Ray cannot be imported, as after a plain
# `pip install voro3d`: prints each command's exit status and stderr, and what voroloss raised, as JSON.
_WITHOUT_EXTRAS = """
import contextlib, io, json, sys

class Missing:
    def find_spec(self, name, path=None, target=None):
        if name.split(".")[0] in ("torch", "onnx", "ray"):
            raise ModuleNotFoundError(f"No module named {name!r}", name=name)

sys.meta_path.insert(0, Missing())
import voro3d
from voro3d.cli import main
from voro3d.shapes import example_mesh

voro3d.save_mesh(example_mesh("torus"), "torus.ply")
outcome = {}
for name, argv in {"fit cuda": ["fit", "torus.ply", "-o", "a.ply", "--device", "cuda"],
                   "reconstruct cuda": ["reconstruct", "torus.ply", "-o", "b.ply", "--device", "cuda"],
                   "train": ["train", "--config", "none.json"],
                   "export": ["export-onnx", "none.pt", "-o", "c.onnx"],
                   "batch ray": ["batch", ".", "out", "--engine", "ray", "-q"],
                   "fit cpu": ["fit", "torus.ply", "-o", "d.ply", "--grid", "8", "--steps", "5", "-q"]}.items():
    err = io.StringIO()
    with contextlib.redirect_stderr(err):
        outcome[name] = [main(argv), err.getvalue()]
try:
    voro3d.voroloss
except ImportError as error:
    outcome["voroloss"] = [type(error).__name__, str(error)]
outcome["torch loaded"] = "torch" in sys.modules
print(json.dumps(outcome))
"""


@pytest.fixture(scope="module")
def without_extras(tmp_path_factory):
    folder = tmp_path_factory.mktemp("extras")
    result = subprocess.run([sys.executable, "-c", _WITHOUT_EXTRAS], cwd=folder, capture_output=True, text=True,
                            timeout=300)
    assert result.returncode == 0, result.stderr
    return json.loads(result.stdout.splitlines()[-1])


@pytest.mark.parametrize("name, message", [
    ("fit cuda", "voro3d fit: error: device='cuda' needs torch: pip install 'voro3d[torch]'"),
    ("reconstruct cuda", "voro3d reconstruct: error: device='cuda' needs torch: pip install 'voro3d[torch]'"),
    ("train", "voro3d train: error: training (voro3d train) needs torch: pip install 'voro3d[torch]'"),
    ("export", "voro3d export-onnx: error: ONNX export (voro3d export-onnx) needs torch: "
               "pip install 'voro3d[torch,onnx]'"),
    ("batch ray", "voro3d batch: error: engine='ray' needs ray: pip install 'voro3d[ray]'"),
])
def test_a_missing_extra_is_named_in_one_line(without_extras, name, message):
    assert without_extras[name] == [2, message + "\n"]


def test_the_library_names_the_extra_and_the_cpu_fit_needs_none(without_extras):
    assert without_extras["voroloss"] == ["MissingExtra", "VoroLoss (voro3d.loss) needs torch: pip install 'voro3d[torch]'"]
    assert without_extras["fit cpu"] == [0, ""]
    assert without_extras["torch loaded"] is False


def test_require():
    assert require("json", "a test") is json
    with pytest.raises(MissingExtra, match=r"^a test needs voro3d_no_such_module: pip install 'voro3d\[x,y\]'$"):
        require("voro3d_no_such_module", "a test", "x,y")
    assert issubclass(MissingExtra, ImportError)
