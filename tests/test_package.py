"""The package surface: light import, every public name resolves, CLI errors are one line."""
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import voro3d
from voro3d.cli import main


@pytest.mark.parametrize("name", voro3d.__all__)
def test_public_names_resolve(name):
    assert getattr(voro3d, name) is not None


PACKAGE = Path(voro3d.__file__).parent
SOURCES = sorted(PACKAGE.rglob("*.py"))
# Modules a user may import: every one whose dotted path has no part starting with "_".
PUBLIC_MODULES = [name for name in (".".join(path.relative_to(PACKAGE.parent).with_suffix("").parts).removesuffix(".__init__")
                                    for path in SOURCES) if not any(part.startswith("_") for part in name.split("."))]


@pytest.mark.parametrize("module", PUBLIC_MODULES)
def test_public_modules_declare_all(module):
    import importlib

    imported = importlib.import_module(module)
    assert isinstance(imported.__all__, list) and len(set(imported.__all__)) == len(imported.__all__)
    assert [name for name in imported.__all__ if not hasattr(imported, name)] == []


@pytest.mark.parametrize("path", SOURCES, ids=lambda path: path.relative_to(PACKAGE).as_posix())
def test_no_module_over_500_lines(path):
    assert len(path.read_text().splitlines()) <= 500


def test_import_is_light():
    code = "import sys, voro3d; heavy = {'torch', 'open3d', 'onnxruntime'} & set(sys.modules); print(sorted(heavy))"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "[]"


def test_cli_extract_roundtrip(tmp_path, capsys):
    rng = np.random.default_rng(0)
    points = rng.uniform(-1, 1, (300, 3))
    voro3d.VoroMesh(points, np.linalg.norm(points, axis=1) < 0.6).save(tmp_path / "g.npz")
    assert main(["extract", str(tmp_path / "g.npz"), "-o", str(tmp_path / "out.ply"), "-q"]) == 0
    mesh = voro3d.load_mesh(tmp_path / "out.ply", weld=False)
    assert voro3d.check_watertight(mesh).watertight


def test_cli_errors_are_one_line_and_leave_no_file(tmp_path, capsys):
    assert main(["extract", str(tmp_path / "missing.npz"), "-o", str(tmp_path / "out.ply")]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "missing.npz" in err
    bad = tmp_path / "bad.npz"
    np.savez(bad, generators=np.zeros((3, 3)), occupancy=np.ones(3, bool))
    assert main(["extract", str(bad), "-o", str(tmp_path / "out.ply")]) == 2
    assert "at least 4 distinct" in capsys.readouterr().err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bad.npz"]


def test_cli_fit_bad_mesh(tmp_path, capsys):
    corrupt = tmp_path / "corrupt.ply"
    corrupt.write_bytes(b"ply\nformat garbage\n")
    assert main(["fit", str(corrupt), "-o", str(tmp_path / "out.ply"), "-q"]) == 2
    assert "could not be read" in capsys.readouterr().err
    assert not (tmp_path / "out.ply").exists()


def test_cli_fit_eval_render(tmp_path, capsys):
    import json

    from voro3d.shapes import example_mesh

    voro3d.save_mesh(example_mesh("torus"), tmp_path / "torus.ply")
    out, png, gens = tmp_path / "fit.ply", tmp_path / "fit.png", tmp_path / "g.npz"
    assert main(["fit", str(tmp_path / "torus.ply"), "-o", str(out), "--grid", "16", "--steps", "60",
                 "--png", str(png), "--save-generators", str(gens), "-q"]) == 0
    assert out.is_file() and png.stat().st_size > 10_000 and gens.is_file()
    capsys.readouterr()
    assert main(["eval", str(out), str(tmp_path / "torus.ply"), "--json", "--n-samples", "20000"]) == 0
    result = json.loads(capsys.readouterr().out)
    # 20k samples put the F1 floor low (see test_metrics); CD is the meaningful bound here.
    assert result["watertight"]["watertight"] and result["chamfer_x1e5"] < 10 and result["f1"] > 0.2
    assert main(["render", str(out), str(tmp_path / "torus.ply"), "-o", str(tmp_path / "r.png"), "-q"]) == 0
    assert main(["render", str(out), "--error-against", str(tmp_path / "torus.ply"),
                 "-o", str(tmp_path / "e.png"), "-q"]) == 0


def test_cli_predict_from_mesh_and_sdf(tmp_path, capsys):
    from voro3d.frames import fit_frame
    from voro3d.queries import sdf_grid
    from voro3d.shapes import example_mesh

    source = example_mesh("bracket")
    voro3d.save_mesh(source, tmp_path / "bracket.ply")
    assert main(["predict", str(tmp_path / "bracket.ply"), "-o", str(tmp_path / "a.ply"), "-q"]) == 0
    assert voro3d.check_watertight(voro3d.load_mesh(tmp_path / "a.ply", weld=False)).watertight
    np.save(tmp_path / "sdf.npy", sdf_grid(fit_frame(source).apply_mesh(source), 32))
    assert main(["predict", str(tmp_path / "sdf.npy"), "-o", str(tmp_path / "b.ply"), "-q"]) == 0
    np.save(tmp_path / "bad.npy", np.zeros((32, 32, 31), np.float32))
    assert main(["predict", str(tmp_path / "bad.npy"), "-o", str(tmp_path / "c.ply")]) == 2
    assert "sdf" in capsys.readouterr().err.lower() and not (tmp_path / "c.ply").exists()
    # An SDF grid has its own size: a --grid for it would be ignored, so it is refused.
    assert main(["predict", str(tmp_path / "sdf.npy"), "-o", str(tmp_path / "d.ply"), "--grid", "32"]) == 2
    assert "--grid applies to a mesh INPUT only" in capsys.readouterr().err and not (tmp_path / "d.ply").exists()


def test_cli_reconstruct_point_cloud(tmp_path, capsys):
    from voro3d.sampling import sample_surface
    from voro3d.shapes import example_mesh

    points, normals = sample_surface(example_mesh("torus"), 5000, seed=0)
    np.save(tmp_path / "cloud.npy", np.hstack([points, normals]))
    for method, extra in (("fit", ["--steps", "40"]), ("learned", []), ("fit", ["--steps", "40", "--denoise", "on"])):
        out = tmp_path / f"{method}{len(extra)}.ply"
        assert main(["reconstruct", str(tmp_path / "cloud.npy"), "-o", str(out), "--grid", "16",
                     "--method", method, "-q", *extra]) == 0
        assert voro3d.check_watertight(voro3d.load_mesh(out, weld=False), self_intersection=False).watertight
    capsys.readouterr()
    assert main(["reconstruct", str(tmp_path / "cloud.npy"), "-o", str(tmp_path / "x.ply"), "--method", "learned",
                 "--steps", "40"]) == 2
    assert "--method learned takes no --steps" in capsys.readouterr().err and not (tmp_path / "x.ply").exists()


def test_public_functions_survive_submodule_imports():
    import importlib

    for name, module in voro3d._PUBLIC.items():
        importlib.import_module(f"voro3d.{module}")
    assert callable(voro3d.fit) and callable(voro3d.reconstruct) and callable(voro3d.evaluate)
    assert not any(isinstance(getattr(voro3d, name), type(voro3d)) for name in voro3d.__all__)
