"""The wheels of `make wheels`: tags and sizes, ``auditwheel show``, install time and size with and
without the torch extra, import and ``--help`` times, and the fit from the wheel against the
editable build (``.venv``), interleaved. Writes ``<out>/wheels.{md,json}``.

    python benchmarks/bench_wheels.py [--wheelhouse wheelhouse] [--repeats 3] [--out benchmarks/results]

The installs go into fresh virtual environments of this interpreter's version; pip's cache is
warm after ``scripts/install.sh`` (so the times are of resolving and unpacking, not of
downloading). torch is installed as ``torch==2.13.0`` first (the CPU build this machine holds), so
that the torch extra's ``torch>=2.2`` is already met and no CUDA build is fetched.
"""
from __future__ import annotations

import argparse
import hashlib
import json
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

_FIT = """
import json, time
import voro3d
from voro3d.shapes import example_mesh
mesh = example_mesh()
start = time.perf_counter()
shape, info = voro3d.fit(mesh, 32)
# Which voro3d ran, without a path of this machine: an installed wheel or the repository's editable one.
package = "wheel (site-packages)" if "site-packages" in voro3d.__file__ else "editable (repository)"
print(json.dumps(dict(package=package, seconds=time.perf_counter() - start,
                      optimisation=info.optimisation_seconds, loss=info.final_loss)))
"""


def _run(argv, **kwargs) -> float:
    start = time.perf_counter()
    subprocess.run(argv, check=True, capture_output=True, text=True, **kwargs)
    return time.perf_counter() - start


def _size_mb(folder: Path) -> float:
    return sum(path.stat().st_size for path in folder.rglob("*") if path.is_file() and not path.is_symlink()) / 2**20


def _venv(folder: Path, wheel: Path, torch: bool) -> dict:
    """A fresh venv with ``wheel`` (and the torch extra): seconds of pip, MiB of the venv."""
    subprocess.run([sys.executable, "-m", "venv", str(folder)], check=True)
    python = str(folder / "bin" / "python")
    empty = _size_mb(folder)
    pip = [python, "-m", "pip", "install", "-q", "--disable-pip-version-check"]
    seconds = _run([*pip, "torch==2.13.0"]) if torch else 0.0
    seconds += _run([*pip, f"{wheel}[torch]" if torch else str(wheel)])
    version = subprocess.run([python, "-c", "import importlib.metadata as m\ntry: print(m.version('torch'))\n"
                              "except m.PackageNotFoundError: print('none')"], capture_output=True, text=True).stdout
    return dict(pip_seconds=round(seconds, 1), installed_mb=round(_size_mb(folder) - empty, 1), torch=version.strip())


def _sha256(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def _median_seconds(argv, repeats: int, cwd) -> float:
    _run(argv, cwd=cwd)  # page cache and .pyc files warm
    return round(statistics.median(_run(argv, cwd=cwd) for _ in range(repeats)), 3)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--wheelhouse", type=Path, default=ROOT / "wheelhouse")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "results")
    args = parser.parse_args(argv)
    tag = f"cp{sys.version_info[0]}{sys.version_info[1]}"
    wheels = sorted(args.wheelhouse.glob("voro3d-*.whl"))
    (wheel,) = [path for path in wheels if f"-{tag}-" in path.name]
    auditwheel = [sys.executable, "-m", "auditwheel", "show", str(wheel)]
    env = {**os.environ, "PATH": f"{Path(sys.executable).parent}:{os.environ['PATH']}"}
    record = dict(wheels={path.name: round(path.stat().st_size / 2**20, 2) for path in wheels},
                  auditwheel_show=subprocess.run(auditwheel, capture_output=True, text=True, env=env, check=True).stdout)
    with tempfile.TemporaryDirectory() as scratch:
        scratch = Path(scratch)
        record["install"] = {"without torch": _venv(scratch / "plain", wheel, torch=False),
                             "with the torch extra": _venv(scratch / "torch", wheel, torch=True)}
        plain = scratch / "plain" / "bin"
        record["import_seconds"] = _median_seconds([str(plain / "python"), "-c", "import voro3d"], args.repeats, scratch)
        record["help_seconds"] = _median_seconds([str(plain / "voro3d"), "--help"], args.repeats, scratch)
        fits = {"wheel": [], "editable": []}
        for _ in range(args.repeats):
            for name, python in (("wheel", plain / "python"), ("editable", ROOT / ".venv" / "bin" / "python")):
                out = subprocess.run([str(python), "-c", _FIT], cwd=scratch, capture_output=True, text=True, check=True)
                fits[name].append(json.loads(out.stdout.splitlines()[-1]))
        installed = next((scratch / "plain" / "lib").glob("python*/site-packages/voro3d/_fitkernel*.so"))
        editable = next((ROOT / "voro3d").glob(f"_fitkernel.cpython-{tag[2:]}-*.so"))
        record["same_kernel"] = _sha256(installed) == _sha256(editable)
        shutil.rmtree(scratch / "torch")
    record["fit"] = fits
    record["machine"] = f"{os.cpu_count()} CPUs, load average {os.getloadavg()[0]:.2f} at the end"
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "wheels.json").write_text(json.dumps(record, indent=2) + "\n")
    (args.out / "wheels.md").write_text(_markdown(record, tag))
    print((args.out / "wheels.md").read_text())
    return 0


def _markdown(record: dict, tag: str) -> str:
    lines = ["# Wheels (`make wheels`, `benchmarks/bench_wheels.py`)", "",
             "| wheel | MiB |", "|---|---|"]
    lines += [f"| `{name}` | {size} |" for name, size in record["wheels"].items()]
    lines += ["", f"`auditwheel show` of the {tag} wheel:", "", "```", record["auditwheel_show"].strip(), "```", "",
              "Install into a fresh venv (pip's cache warm; torch as `torch==2.13.0` first, the CPU build):", "",
              "| | pip install, s | installed, MiB | torch |", "|---|---|---|---|"]
    lines += [f"| {name} | {row['pip_seconds']} | {row['installed_mb']} | {row['torch']} |"
              for name, row in record["install"].items()]
    lines += ["", f"From the wheel's venv, median of {len(record['fit']['wheel'])} after one warm-up run: "
              f"`python -c \"import voro3d\"` {record['import_seconds']} s, `voro3d --help` {record['help_seconds']} s.",
              "", "`voro3d.fit(example_mesh(), 32)`, wheel and editable build interleaved, one fresh process each "
              f"(`voro3d._fitkernel` byte-identical in the two: {'yes' if record['same_kernel'] else 'no'}):", "",
              "| build | fit, s | optimisation, s | final loss |", "|---|---|---|---|"]
    for name, runs in record["fit"].items():
        lines += [f"| {name} | {run['seconds']:.2f} | {run['optimisation']:.2f} | {run['loss']:.6g} |" for run in runs]
    lines += ["", f"Machine: {record['machine']}.", ""]
    return "\n".join(lines)


if __name__ == "__main__":
    sys.exit(main())
