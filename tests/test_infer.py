import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from voro3d.baselines import marching_cubes
from voro3d.voromesh import VoroMesh
from voro3d.infer import BAND_INPUTS, DEFAULT_MODEL, NEAR, Predictor, band_input, check_sdf, predict, predict_from_mesh
from voro3d.frames import fit_frame
from voro3d.io import mesh_arrays
from voro3d.metrics import evaluate
from voro3d.queries import sdf_grid
from voro3d.sampling import grid_nodes
from voro3d.shapes import example_mesh
from voro3d.watertight import check_watertight


def _sphere_sdf(g=32, radius=0.6):
    return (np.linalg.norm(grid_nodes(g), axis=1) - radius).reshape(g, g, g).astype(np.float32)


@pytest.fixture(scope="module")
def predictor():
    return Predictor(threads=1)


@pytest.fixture(scope="module")
def bracket():
    """A CAD-like bundled part (not in the training set) in its fit frame, and its 32^3 SDF."""
    vertices, triangles = mesh_arrays(example_mesh("bracket"))
    vertices = fit_frame((vertices, triangles)).apply(vertices)
    return (vertices, triangles), sdf_grid((vertices, triangles), 32)


def test_shipped_model_is_package_data_small_and_documented():
    import voro3d

    assert DEFAULT_MODEL.is_file() and DEFAULT_MODEL.parent == Path(voro3d.__file__).parent / "models"
    assert DEFAULT_MODEL.stat().st_size < 20 * 2**20
    card = Path(__file__).resolve().parents[1] / "models" / "README.md"
    assert f"`{DEFAULT_MODEL.name}`" in card.read_text()
    assert not (card.parent / DEFAULT_MODEL.name).exists()  # one copy, in the package


def test_bracket_is_watertight_and_beats_marching_cubes(predictor, bracket):
    gt, sdf = bracket
    voro = predictor.predict(sdf)
    mesh = voro.to_open3d()
    assert check_watertight(mesh).watertight
    learned = evaluate(mesh, gt, n_samples=30_000)
    mc = evaluate(marching_cubes(sdf), gt, n_samples=30_000)
    # Shipped model: CD 4.5 vs Marching Cubes 6.3 (x1e5, 30k points), F1 0.33 vs 0.31.
    assert learned["chamfer_x1e5"] < mc["chamfer_x1e5"]
    assert learned["chamfer_x1e5"] < 6.0
    assert learned["f1"] > 0.8 * mc["f1"]


def test_predict_from_mesh_returns_generators_in_mesh_units(predictor):
    mesh = example_mesh("sphere")
    vertices, triangles = mesh_arrays(mesh)
    scaled = (vertices * 40.0 + [100.0, -5.0, 3.0], triangles)
    voro = predictor.predict_from_mesh(scaled, grid=32)
    out = np.asarray(voro.to_open3d().vertices)
    np.testing.assert_allclose(out.min(axis=0), scaled[0].min(axis=0), atol=0.05 * 80)
    np.testing.assert_allclose(out.max(axis=0), scaled[0].max(axis=0), atol=0.05 * 80)
    assert evaluate(voro.to_open3d(), scaled, n_samples=20_000)["chamfer_x1e5"] < 5.0


def test_fallback_adds_fixed_generators_only(predictor):
    sdf = _sphere_sdf()
    with_fallback, without = predictor.predict(sdf), predictor.predict(sdf, fallback=False)
    n = without.generators.shape[0]
    assert with_fallback.generators.shape[0] > n
    np.testing.assert_array_equal(with_fallback.generators[:n], without.generators)
    # The fixed generators carry the SDF sign of their nodes.
    fixed = with_fallback.generators[n:]
    np.testing.assert_array_equal(with_fallback.occupancy[n:], np.linalg.norm(fixed, axis=1) < 0.6)


def test_module_functions_cache_the_session(tmp_path):
    sdf = _sphere_sdf(24)
    first = predict(sdf)
    second = predict(sdf, model=DEFAULT_MODEL)
    np.testing.assert_array_equal(first.generators, second.generators)
    assert isinstance(predict_from_mesh(example_mesh("sphere"), 24), VoroMesh)


def test_band_input_structure():
    g, context = 40, 3.0
    sdf = check_sdf((np.linalg.norm(grid_nodes(g) - 0.1, axis=1) - 0.45).reshape(g, g, g))
    net_input = band_input(sdf, near=NEAR, context=context)
    arrays = net_input.arrays
    assert tuple(sorted(arrays)) == tuple(sorted(BAND_INPUTS))
    step = 2 / (g - 1)
    band = np.argwhere(np.abs(sdf) < np.float32(context * step))
    n0 = band.shape[0]
    np.testing.assert_allclose(arrays["band_sdf"][:, 0] * step, sdf[tuple(band.T)], rtol=1e-6)
    # The targets are the generator nodes, in the order of ijk.
    np.testing.assert_array_equal(band[arrays["targets"]], net_input.ijk)
    np.testing.assert_array_equal(net_input.ijk, np.argwhere(np.abs(sdf) < np.float32(step) * NEAR))
    # Tap 13 is the node itself; every other tap is the node's neighbour or the absent row n0.
    neighbours = arrays["neighbours0"]
    np.testing.assert_array_equal(neighbours[:, 13], np.arange(n0))
    taps = np.stack(np.meshgrid(*[np.arange(-1, 2)] * 3, indexing="ij"), axis=-1).reshape(-1, 3)
    present = neighbours < n0
    np.testing.assert_array_equal(band[neighbours[present]], (band[:, None, :] + taps[None])[present])
    expected = {tuple(p) for p in band}
    assert present.sum() == sum(tuple(p) in expected for p in (band[:, None, :] + taps[None]).reshape(-1, 3))
    # Each node's parent holds it among its children, at its parity.
    up, children = arrays["up1"], arrays["children1"]
    np.testing.assert_array_equal(children[up // 8, up % 8], np.arange(n0))
    assert (children < n0).sum() == n0 and arrays["neighbours1"].shape == (children.shape[0], 27)
    up2, children2 = arrays["up2"], arrays["children2"]
    np.testing.assert_array_equal(children2[up2 // 8, up2 % 8], np.arange(children.shape[0]))
    np.testing.assert_array_equal(np.unique(band // 4, axis=0).shape[0], children2.shape[0])
    for name, array in arrays.items():
        assert array.dtype == (np.float32 if name == "band_sdf" else np.int64), name


@pytest.mark.parametrize("sdf, match", [
    (np.zeros((32, 32), np.float32), r"shape \(g, g, g\)"),
    (np.zeros((32, 32, 30), np.float32), r"shape \(g, g, g\)"),
    (np.zeros((3, 3, 3), np.float32), r"g >= 4"),
    (np.full((16, 16, 16), "a"), "floating-point or integer"),
    (np.ones((16, 16, 16), bool), "floating-point or integer"),
    (np.full((16, 16, 16), 0.5, np.float32), r"no zero crossing: values span \[0.5, 0.5\], no node is inside"),
    (np.full((16, 16, 16), -0.5, np.float32), "no zero crossing.*no node is outside"),
    (np.minimum(np.arange(16.0) - 3, 0)[:, None, None] * np.ones((16, 16, 16)), "no node is outside"),
])
def test_bad_grids(predictor, sdf, match):
    with pytest.raises(ValueError, match=match):
        predictor.predict(sdf)


def test_nan_in_grid(predictor):
    sdf = _sphere_sdf(16)
    sdf[3, 4, 5] = np.nan
    with pytest.raises(ValueError, match="1 NaN or inf"):
        predictor.predict(sdf)


def test_grid_that_is_not_a_distance(predictor):
    sdf = np.where(_sphere_sdf(16) < 0, -100.0, 100.0).astype(np.float32)
    with pytest.raises(ValueError, match="no node within"):
        predictor.predict(sdf)


def test_predict_from_mesh_bad_grid(predictor):
    with pytest.raises(ValueError, match="grid"):
        predictor.predict_from_mesh(example_mesh("sphere"), grid=3)


def test_missing_model(tmp_path):
    with pytest.raises(FileNotFoundError, match="no ONNX model"):
        Predictor(tmp_path / "missing.onnx")


def test_corrupt_model(tmp_path):
    corrupt = tmp_path / "corrupt.onnx"
    corrupt.write_bytes(DEFAULT_MODEL.read_bytes()[:1000])
    with pytest.raises(ValueError, match="not a loadable ONNX model"):
        Predictor(corrupt)


def test_model_with_other_inputs(tmp_path):
    onnx = pytest.importorskip("onnx")
    from onnx import TensorProto, helper

    graph = helper.make_graph([helper.make_node("Identity", ["x"], ["y"])], "identity",
                              [helper.make_tensor_value_info("x", TensorProto.FLOAT, [1])],
                              [helper.make_tensor_value_info("y", TensorProto.FLOAT, [1])])
    path = tmp_path / "identity.onnx"
    onnx.save(helper.make_model(graph, opset_imports=[helper.make_opsetid("", 17)]), path)
    with pytest.raises(ValueError, match="must take inputs"):
        Predictor(path)


def test_inference_never_imports_torch():
    code = ("import sys, numpy as np\n"
            "import voro3d.infer as infer\n"
            "from voro3d.sampling import grid_nodes\n"
            "sdf = (np.linalg.norm(grid_nodes(24), axis=1) - 0.5).reshape(24, 24, 24).astype(np.float32)\n"
            "infer.predict(sdf).to_open3d()\n"
            "assert 'torch' not in sys.modules, 'torch was imported'\n")
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stderr
