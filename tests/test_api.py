"""The public API's conventions (voro3d/__init__.py, "API conventions"), checked over every public name."""
import argparse
import dataclasses
import importlib
import inspect
import pkgutil

import numpy as np
import open3d as o3d
import pytest

import voro3d
from voro3d.shapes import example_mesh

# Other names for a concept that has one name in voro3d (the value).
SYNONYMS = {
    "n": "n_samples", "n_points": "n_samples", "num_samples": "n_samples", "num_points": "n_samples",
    "quiet": "progress", "verbose": "progress", "show_progress": "progress",
    "model_path": "model", "onnx_path": "model",
    "random_state": "seed", "rng_seed": "seed",
    "res": "grid", "grid_size": "grid", "grid_resolution": "grid",
    "tol": "tolerance", "eps": "tolerance",
    "torch_device": "device",
}


def _public_modules():
    for info in pkgutil.walk_packages(voro3d.__path__, "voro3d."):
        if not any(part.startswith("_") for part in info.name.split(".")):
            yield importlib.import_module(info.name)


def _public_callables():
    """(qualified name, function) for every public function, class constructor and public method.

    Dataclasses are records, not functions with options: their fields are left out.
    """
    seen = set()
    for module in [voro3d, *_public_modules()]:
        for name in getattr(module, "__all__", ()):
            value = getattr(module, name)
            if inspect.isfunction(value):
                found = [(f"{value.__module__}.{name}", value)]
            elif inspect.isclass(value) and value.__module__.startswith("voro3d"):
                found = [] if dataclasses.is_dataclass(value) else [(f"{value.__module__}.{name}", value.__init__)]
                found += [(f"{value.__module__}.{name}.{attribute}", method) for attribute, method in vars(value).items()
                          if inspect.isfunction(method) and not attribute.startswith("_")]
            else:
                continue
            for qualified, function in found:
                if function not in seen and function is not object.__init__:
                    seen.add(function)
                    yield qualified, function


PUBLIC = sorted(_public_callables(), key=lambda item: item[0])


def _parameters(function):
    parameters = list(inspect.signature(function).parameters.values())
    if parameters and parameters[0].name in ("self", "cls"):
        parameters = parameters[1:]
    return [p for p in parameters if not p.name.startswith("_") and p.kind not in (p.VAR_POSITIONAL, p.VAR_KEYWORD)]


def test_the_walk_finds_the_entry_points():
    names = {name for name, _ in PUBLIC}
    assert {"voro3d.fitting.fit", "voro3d.reconstruction.reconstruct", "voro3d.infer.predict",
            "voro3d.infer.predict_from_mesh", "voro3d.batch.runner.run_batch", "voro3d.metrics.evaluate"} <= names
    assert len(PUBLIC) > 80


@pytest.mark.parametrize("name, function", PUBLIC, ids=[name for name, _ in PUBLIC])
def test_options_after_the_first_two_arguments_are_keyword_only(name, function):
    late = [p.name for i, p in enumerate(_parameters(function))
            if i >= 2 and p.default is not p.empty and p.kind == p.POSITIONAL_OR_KEYWORD]
    assert not late, f"{name}: {late} should be keyword-only"


@pytest.mark.parametrize("name, function", PUBLIC, ids=[name for name, _ in PUBLIC])
def test_one_name_per_concept(name, function):
    for parameter in _parameters(function):
        assert parameter.name not in SYNONYMS, f"{name}({parameter.name}=...) should be {SYNONYMS[parameter.name]}"
        # A flag that changes what comes back (return_info=True) is what this API does not have.
        assert not parameter.name.startswith("return_"), f"{name}({parameter.name}=...)"


@pytest.mark.parametrize("name, function", [(n, f) for n, f in PUBLIC if "progress" in inspect.signature(f).parameters],
                         ids=lambda value: value if isinstance(value, str) else "")
def test_progress_is_off_by_default(name, function):
    assert inspect.signature(function).parameters["progress"].default is False, name


def test_the_command_line_uses_the_same_names():
    parser = voro3d.cli.build_parser()
    commands = next(action for action in parser._actions if isinstance(action, argparse._SubParsersAction))
    for command, subparser in commands.choices.items():
        for action in subparser._actions:
            assert action.dest not in SYNONYMS or action.dest == "quiet", (command, action.dest)
    # The flag's old spelling still parses, into the new name.
    assert parser.parse_args(["eval", "a.ply", "b.ply", "--n-points", "5"]).n_samples == 5


def test_batch_default_steps_are_the_fits():
    from voro3d.batch.runner import FIT_STEPS

    assert FIT_STEPS == inspect.signature(voro3d.fit).parameters["steps"].default


def test_entry_points_return_their_documented_types():
    sphere = example_mesh("sphere")
    result = voro3d.fit(sphere, 6, steps=2)
    assert isinstance(result, tuple) and len(result) == 2
    assert isinstance(result[0], voro3d.VoroMesh) and isinstance(result[1], voro3d.FitInfo)
    assert isinstance(voro3d.predict_from_mesh(sphere, 16), voro3d.VoroMesh)
    assert isinstance(voro3d.reconstruct(sphere, grid=6, steps=2), o3d.geometry.TriangleMesh)
    assert isinstance(voro3d.reconstruct(sphere, grid=16, method="learned"), o3d.geometry.TriangleMesh)


CLOUD = np.random.default_rng(0).normal(size=(500, 3))


@pytest.mark.parametrize("call, match", [
    (lambda: voro3d.reconstruct(example_mesh("sphere"), method="learned", steps=10),
     r"method='learned' takes no steps \(only method='fit' uses it\)"),
    (lambda: voro3d.reconstruct(CLOUD, method="learned", seed=1), "method='learned' takes no seed"),
    (lambda: voro3d.reconstruct(CLOUD, method="learned", device="cpu"), "method='learned' takes no device"),
    (lambda: voro3d.reconstruct(CLOUD, method="learned", steps=10, seed=1),
     r"takes no steps or seed \(only method='fit' uses them\)"),
    (lambda: voro3d.VoroMeshStage(method="learned", steps=10), "method='learned' takes no steps"),
    (lambda: voro3d.reconstruct(example_mesh("sphere"), plan={"denoise": "on"}), "plan applies to point clouds only"),
    (lambda: voro3d.pointcloud.reconstruct_points(CLOUD, method="learned", device="cuda"),
     "method='learned' takes no device"),
    (lambda: voro3d.pointcloud.reconstruct_points(CLOUD, method="poisson"), "method must be one of"),
])
def test_options_a_method_ignores_are_refused(call, match):
    with pytest.raises(ValueError, match=match):
        call()
