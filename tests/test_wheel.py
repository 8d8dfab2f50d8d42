"""The binary wheel, built and repaired as `make wheels` builds it, then installed into a fresh virtual
environment with no compiler on PATH, the system's GMP and MPFR hidden and no torch: there the
`voro3d` command reconstructs a cloud, fits a mesh, predicts, extracts and runs a batch."""
import importlib.metadata
import json
import os
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import numpy as np
import pytest

import voro3d

ROOT = Path(__file__).resolve().parents[1]
# What scripts/build_wheels.sh needs of a checkout (a copy, so that the test builds nothing in it).
SOURCES = ("pyproject.toml", "setup.py", "README.md", "LICENSE", "licenses", "scripts", "src", "voro3d")
LIBRARY_DIRS = ("/lib", "/lib64", "/usr/lib", "/usr/lib64", "/usr/local/lib", "/lib/x86_64-linux-gnu",
                "/usr/lib/x86_64-linux-gnu")
COMPILERS = ("cc", "c++", "gcc", "g++", "clang", "clang++")


@pytest.fixture(scope="module")
def dependencies(tmp_path_factory):
    """A fresh virtual environment, its installing of voro3d's dependencies begun (from pip's cache or
    PyPI), or None where the isolation cannot be had: started before the wheel is built, so the two overlap."""
    if _isolation_missing():
        yield None
        return
    venv = tmp_path_factory.mktemp("venv") / "env"
    subprocess.run([sys.executable, "-m", "venv", str(venv)], check=True, timeout=120)
    requires = [line for line in importlib.metadata.requires("voro3d") if "extra ==" not in line]
    install = subprocess.Popen([str(venv / "bin" / "python"), "-m", "pip", "install", "-q", "--disable-pip-version-check",
                                *requires], stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    yield venv, install
    install.kill()
    install.communicate()


@pytest.fixture(scope="module")
def wheel(dependencies, tmp_path_factory) -> Path:
    """One wheel, for this interpreter, from scripts/build_wheels.sh (offline: the dev extra has the tools)."""
    folder = tmp_path_factory.mktemp("wheel")
    skip = shutil.ignore_patterns("__pycache__", "*.so", "*.egg-info", "*.pyc")
    (folder / "source").mkdir()
    for name in SOURCES:
        if (ROOT / name).is_dir():
            shutil.copytree(ROOT / name, folder / "source" / name, ignore=skip)
        else:
            shutil.copy2(ROOT / name, folder / "source" / name)
    result = subprocess.run(["bash", "scripts/build_wheels.sh", sys.executable], cwd=folder / "source",
                            env={**os.environ, "OUT": str(folder / "wheelhouse")}, capture_output=True, text=True,
                            timeout=600)
    assert result.returncode == 0, result.stdout + result.stderr
    (built,) = (folder / "wheelhouse").glob("voro3d-*.whl")
    return built


def test_wheel_is_manylinux_and_carries_gmp_mpfr_the_model_and_the_licences(wheel):
    assert wheel.name.endswith("-manylinux_2_34_x86_64.whl")
    show = subprocess.run([sys.executable, "-m", "auditwheel", "show", str(wheel)], capture_output=True, text=True,
                          check=True).stdout
    assert 'consistent with\nthe following platform tag: "manylinux_2_34_x86_64"' in show.replace(" \n", "\n")
    # The system libraries the wheel still needs: glibc, libstdc++ and libgcc_s, never GMP or MPFR.
    assert "gmp" not in show and "mpfr" not in show
    with zipfile.ZipFile(wheel) as archive:
        names = archive.namelist()
        metadata = archive.read(next(name for name in names if name.endswith(".dist-info/METADATA"))).decode()
    bundled = sorted(Path(name).name.split("-")[0] for name in names if name.startswith("voro3d.libs/lib"))
    assert bundled == ["libgmp", "libmpfr"]
    assert "voro3d/models/voromesh_sdf.onnx" in names
    licences = {Path(name).name for name in names if ".dist-info/licenses/" in name}
    assert {"LICENSE", "GPL-3.0.txt", "LGPL-3.0.txt", "CGAL-copyright.txt", "GMP-copyright.txt",
            "MPFR-copyright.txt", "NOTICE.md"} <= licences
    assert "License-Expression: MIT AND GPL-3.0-or-later AND LGPL-3.0-or-later" in metadata
    requires = [line for line in metadata.splitlines() if line.startswith("Requires-Dist: torch")]
    assert requires and all("extra == \"torch\"" in line for line in requires)


def _isolation_missing() -> str | None:
    if not sys.platform.startswith("linux"):
        return "hiding the system's GMP and MPFR needs Linux mount namespaces"
    if os.geteuid() != 0:
        return "hiding the system's GMP and MPFR needs root (unshare -m, bind mounts)"
    if shutil.which("unshare") is None:
        return "hiding the system's GMP and MPFR needs unshare (util-linux)"
    probe = subprocess.run(["unshare", "-m", "true"], capture_output=True, text=True)
    if probe.returncode != 0:
        return f"unshare -m does not work here: {probe.stderr.strip()}"
    return None


@pytest.fixture(scope="module")
def fresh_venv(wheel, dependencies) -> Path:
    """The fresh virtual environment holding the wheel and its dependencies, no torch."""
    if dependencies is None:
        pytest.skip(_isolation_missing())
    venv, started = dependencies
    output, _ = started.communicate(timeout=600)
    assert started.returncode == 0, output
    # With its dependencies (all there now), so that the wheel's own metadata is what pip resolves.
    install = subprocess.run([str(venv / "bin" / "python"), "-m", "pip", "install", "-q", "--disable-pip-version-check",
                              str(wheel)], capture_output=True, text=True, timeout=600)
    assert install.returncode == 0, install.stderr
    return venv


# Run by the fresh environment's interpreter inside the namespace: checks the isolation holds, runs
# the commands and prints what came out, as JSON.
_FROM_THE_WHEEL = """
import ctypes, json, os, shutil, subprocess, sys

compilers, folder = sys.argv[1].split(","), sys.argv[2]
hidden = {}
for name in ("libgmp.so.10", "libmpfr.so.6"):
    try:
        ctypes.CDLL(name)
        hidden[name] = False
    except OSError:
        hidden[name] = True
try:
    import torch
    torch_missing = False
except ModuleNotFoundError:
    torch_missing = True
import voro3d, voro3d._cgal
with open("/proc/self/maps") as maps:
    linked = sorted({line.split()[-1] for line in maps if "libgmp" in line or "libmpfr" in line})
command = os.path.join(os.path.dirname(sys.executable), "voro3d")
statuses = {}
for name, argv in {
        "help": ["--help"],
        "reconstruct": ["reconstruct", "cloud.npy", "-o", "cloud.ply", "--grid", "16", "--steps", "40", "-q"],
        "fit": ["fit", "meshes/torus.ply", "-o", "fit.ply", "--grid", "16", "--steps", "40", "--save-generators",
                "fit.npz", "-q"],
        "predict": ["predict", "meshes/torus.ply", "-o", "predict.ply", "-q"],
        "extract": ["extract", "fit.npz", "-o", "extract.ply", "-q"],
        "batch": ["batch", "meshes", "batch", "--grid", "8", "--steps", "20", "--workers", "1", "-q"],
        "cuda": ["fit", "meshes/torus.ply", "-o", "cuda.ply", "--device", "cuda"]}.items():
    run = subprocess.run([command, *argv], cwd=folder, capture_output=True, text=True)
    statuses[name] = [run.returncode, run.stderr.strip().splitlines()[-1:] if run.returncode else []]
watertight = {name: voro3d.check_watertight(voro3d.load_mesh(os.path.join(folder, name), weld=False)).watertight
              for name in ("cloud.ply", "fit.ply", "predict.ply", "extract.ply", "batch/torus.ply")}
print(json.dumps(dict(compilers=[shutil.which(name) for name in compilers], hidden=hidden, torch_missing=torch_missing,
                      torch_loaded="torch" in sys.modules, package=voro3d.__file__, linked=linked, statuses=statuses,
                      watertight=watertight)))
"""


def _system_libraries() -> list:
    """The system's GMP and MPFR shared-library files (each once, symbolic links resolved)."""
    found = set()
    for folder in LIBRARY_DIRS:
        for pattern in ("libgmp*.so*", "libmpfr*.so*"):
            found.update(path.resolve() for path in Path(folder).glob(pattern))
    return sorted(path for path in found if path.is_file())


def test_wheel_runs_without_compiler_system_gmp_mpfr_or_torch(fresh_venv, tmp_path):
    from voro3d.sampling import sample_surface
    from voro3d.shapes import example_mesh

    (tmp_path / "work" / "meshes").mkdir(parents=True)
    torus = example_mesh("torus")
    voro3d.save_mesh(torus, tmp_path / "work" / "meshes" / "torus.ply")
    np.save(tmp_path / "work" / "cloud.npy", np.hstack(sample_surface(torus, 5000, seed=0)))
    libraries = _system_libraries()
    assert libraries, "no system libgmp/libmpfr found to hide"
    empty = tmp_path / "empty.so"
    empty.touch()
    # A private mount namespace: the empty file is bound over each library here only; the
    # environment keeps only the fresh venv on PATH, so no compiler can be found; the folder is not
    # the checkout's, whose voro3d `python -c` would import first.
    mounts = " && ".join(f"mount --bind {empty} {library}" for library in libraries)
    env = {"PATH": str(fresh_venv / "bin"), "HOME": str(tmp_path), "LANG": "C.UTF-8", "OMP_NUM_THREADS": "2"}
    result = subprocess.run(["unshare", "-m", "sh", "-c", f'{mounts} && exec "$@"', "sh",
                             shutil.which("env"), "-i", *(f"{key}={value}" for key, value in env.items()),
                             str(fresh_venv / "bin" / "python"), "-c", _FROM_THE_WHEEL, ",".join(COMPILERS),
                             str(tmp_path / "work")], cwd=tmp_path, capture_output=True, text=True, timeout=600)
    assert result.returncode == 0, result.stderr
    report = json.loads(result.stdout.splitlines()[-1])
    assert report["compilers"] == [None] * len(COMPILERS)
    assert report["hidden"] == {"libgmp.so.10": True, "libmpfr.so.6": True}
    assert report["torch_missing"] and not report["torch_loaded"]
    assert Path(report["package"]).is_relative_to(fresh_venv)
    assert len(report["linked"]) == 2 and all("/voro3d.libs/" in path for path in report["linked"])
    assert report["statuses"] == {
        **{name: [0, []] for name in ("help", "reconstruct", "fit", "predict", "extract", "batch")},
        "cuda": [2, ["voro3d fit: error: device='cuda' needs torch: pip install 'voro3d[torch]'"]]}
    assert all(report["watertight"].values()), report["watertight"]
