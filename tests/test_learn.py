import json

import numpy as np
import pytest

torch = pytest.importorskip("torch")

from voro3d.infer import NEAR, Predictor, sdf_at  # noqa: E402
from voro3d.learn.data import ShapeSet, build_dataset, cad_shape, organic_shape, thin_shape  # noqa: E402
from voro3d.learn.export import TOLERANCE, check_grids, export_onnx  # noqa: E402
from voro3d.learn.model import BandNet, build_model, load_checkpoint  # noqa: E402
from voro3d.learn.pack import SDF_LEVELS, pack_dataset, unpack_dataset  # noqa: E402
from voro3d.learn.batches import augment, batch_loss, join_inputs  # noqa: E402
from voro3d.learn.train import load_config, train_main  # noqa: E402
from voro3d.queries import InsideOutside  # noqa: E402
from voro3d.sampling import grid_nodes  # noqa: E402

GRID = 16


@pytest.fixture(scope="module")
def tiny_run(tmp_path_factory):
    """Three CAD and one organic training shapes, two validation shapes at 16^3, two stage-1 epochs and one stage-2 epoch."""
    torch.set_num_threads(1)
    root = tmp_path_factory.mktemp("learn")
    config = {
        "run_dir": str(root / "run"),
        "data": {"train_dir": str(root / "train"), "val_dir": str(root / "val"), "n_train": 3, "n_val": 2,
                 "grids": [GRID], "n_samples": 4000, "n_organic": 1},
        "model": {"arch": "band", "widths": [4, 8, 8], "head_width": 16},
        "stage1": {"epochs": 2, "batch_size": 2, "samples_per_shape": 2000, "grid_weights": [1.0]},
        "stage2": {"epochs": 1, "n_shapes": 3, "nodes_per_shape": 400, "batch_size": 256},
        "validation": {"n_detail": 1, "cd_points": 2000},
    }
    path = root / "tiny.json"
    path.write_text(json.dumps(config))
    return root, path, train_main(path)


def test_cad_shape_is_deterministic_and_closed():
    vertices, triangles = cad_shape(3)
    again, _ = cad_shape(3)
    np.testing.assert_array_equal(vertices, again)
    other, _ = cad_shape(4)
    assert other.shape != vertices.shape or not np.array_equal(other, vertices)
    InsideOutside((vertices, triangles))  # raises on an open mesh


def test_organic_shape_is_deterministic_closed_and_outward():
    from voro3d.watertight import signed_volume

    vertices, triangles = organic_shape(5)
    again, _ = organic_shape(5)
    np.testing.assert_array_equal(vertices, again)
    InsideOutside((vertices, triangles))  # raises on an open mesh
    assert signed_volume(vertices, triangles) > 0


@pytest.mark.parametrize("make", [thin_shape, lambda seed: organic_shape(seed, cut=True)], ids=["thin", "cut"])
def test_thin_and_cut_shapes_are_deterministic_closed_and_outward(make):
    from voro3d.watertight import signed_volume

    vertices, triangles = make(11)
    again, _ = make(11)
    np.testing.assert_array_equal(vertices, again)
    InsideOutside((vertices, triangles))  # raises on an open mesh
    assert signed_volume(vertices, triangles) > 0


def test_cut_bodies_have_flat_faces():
    """A cut body has flat faces: many more of its triangles share one normal than in the plain body."""
    def most_common_normal(vertices, triangles):
        corners = vertices[triangles]
        normals = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
        normals /= np.linalg.norm(normals, axis=1, keepdims=True)
        return np.unique(np.round(normals, 3), axis=0, return_counts=True)[1].max()

    assert most_common_normal(*organic_shape(3, cut=True)) > 20 * most_common_normal(*organic_shape(3))


def test_dataset_cache_grows_without_rebuilding(tiny_run, tmp_path):
    import shutil

    root, _, _ = tiny_run
    cache = tmp_path / "train"
    shutil.copytree(root / "train", cache)
    before = {p.name: p.read_bytes() for p in cache.glob("*.npz")}
    files = build_dataset(cache, 3, grid=GRID, seed=7, n_samples=4000, n_organic=1, n_thin=1)
    assert [f.name for f in files] == ["shape_00000.npz", "shape_00001.npz", "shape_00002.npz", "organic_00000.npz",
                                       "thin_00000.npz"]
    assert {p.name: p.read_bytes() for p in cache.glob("*.npz") if p.name in before} == before
    assert [f.name for f in build_dataset(cache, 2, grid=GRID, seed=7, n_samples=4000)] == ["shape_00000.npz",
                                                                                          "shape_00001.npz"]
    with pytest.raises(ValueError, match="built with"):
        build_dataset(cache, 3, grid=GRID, seed=7, n_samples=3000)


def test_dataset_arrays_and_cache_spec(tiny_run):
    root, _, _ = tiny_run
    shapes = ShapeSet(sorted((root / "train").glob("shape_*.npz")))
    assert len(shapes) == 3
    assert len(list((root / "train").glob("organic_*.npz"))) == 1
    shape = shapes[0]
    assert shape[f"sdf_{GRID}"].shape == (GRID,) * 3 and shape[f"sdf_{GRID}"].dtype == np.float32
    assert shape["samples"].shape == (4000, 3)
    # The mesh is in the fit frame: bounding-box diagonal 2, centred.
    low, high = shape["vertices"].min(axis=0), shape["vertices"].max(axis=0)
    assert np.linalg.norm(high - low) == pytest.approx(2.0)
    np.testing.assert_allclose((low + high) / 2, 0, atol=1e-12)
    with pytest.raises(ValueError, match="built with"):
        build_dataset(root / "train", 3, grid=GRID, seed=0, n_samples=4000)


def test_loss_decreases_on_one_shape(tiny_run):
    root, _, _ = tiny_run
    shape = ShapeSet([root / "train" / "shape_00000.npz"])[0]
    torch.manual_seed(0)
    model = BandNet()
    optimizer = torch.optim.Adam(model.parameters(), lr=3e-3)
    losses = []
    batch = [(model.network_input(shape[f"sdf_{GRID}"], near=NEAR), shape["samples"])]
    for _ in range(50):  # 25 steps bring the loss to 0.85 of its first value, 50 to 0.50
        optimizer.zero_grad()
        loss, _ = batch_loss(model, batch, reg_weight=2e-3)
        loss.backward()
        optimizer.step()
        losses.append(loss.item())
    assert np.mean(losses[-5:]) < 0.8 * losses[0]


def test_joined_batch_equals_separate_shapes(tiny_run):
    root, _, _ = tiny_run
    torch.manual_seed(0)
    model = BandNet(widths=(4, 8, 8), head_width=16)
    shapes = [ShapeSet([root / "train" / f"shape_0000{i}.npz"])[0] for i in range(3)]
    inputs = [model.network_input(s[f"sdf_{GRID}"], near=NEAR) for s in shapes]
    arrays, bounds = join_inputs(inputs)
    with torch.no_grad():
        joined = model(**{k: torch.from_numpy(v) for k, v in arrays.items()})
        for s, net_input in enumerate(inputs):
            alone = model(**{k: torch.from_numpy(v) for k, v in net_input.arrays.items()})
            for a, b in zip(alone, joined):
                torch.testing.assert_close(a, b[bounds[s]:bounds[s + 1]], rtol=1e-5, atol=1e-6)
    # The batch loss is the mean of the shapes' losses.
    batch = [(x, s["samples"][:1500]) for x, s in zip(inputs, shapes)]
    mean = np.mean([batch_loss(model, [one], reg_weight=2e-3)[0].item() for one in batch])
    assert batch_loss(model, batch, reg_weight=2e-3)[0].item() == pytest.approx(mean, rel=1e-5)


def test_pack_round_trip_is_close_and_trains(tiny_run, tmp_path):
    root, path, _ = tiny_run
    pack = pack_dataset(root / "train", tmp_path / "train.npz", n_samples=1000)
    files = unpack_dataset(pack, tmp_path / "train")
    names = json.loads((root / "train" / "index.json").read_text())["files"]
    original = ShapeSet([root / "train" / name for name in names])
    unpacked = ShapeSet(files)
    assert len(unpacked) == len(original) == 4
    step = 2.0 / (GRID - 1)
    for i in range(4):
        a, b = original[i], unpacked[i]
        near = np.abs(a[f"sdf_{GRID}"]) < 3.25 * step
        assert np.abs(a[f"sdf_{GRID}"] - b[f"sdf_{GRID}"])[near].max() <= 0.5 / SDF_LEVELS * step * 1.001
        assert np.all(np.abs(b[f"sdf_{GRID}"])[~near] >= 3.25 * step * 0.999)
        assert b["samples"].shape == (1000, 3)
        gap = np.linalg.norm(b["samples"][:, None] - a["samples"][None], axis=2).min(axis=1)
        assert gap.max() < 2.0 / 4095  # within a quantisation step of an original sample
    # A stage-1 run on the unpacked set needs no mesh: no detail validation, stage 2 skipped.
    config = json.loads(path.read_text())
    config["data"].update(train_dir=str(tmp_path / "train"), val_dir=str(tmp_path / "train"), n_val=3, val_seed=7)
    config.update(run_dir=str(tmp_path / "run"), workers=1)
    config["stage1"].update(epochs=5, time_budget_s=0.01)
    config["stage2"]["epochs"] = 0
    config["validation"]["n_detail"] = 0
    (tmp_path / "packed.json").write_text(json.dumps(config))
    _, state = load_checkpoint(train_main(tmp_path / "packed.json"))
    assert [h["stage"] for h in state["history"]] == [1]  # the budget stopped it after one epoch
    assert np.isfinite(state["history"][0][f"val_voroloss_{GRID}"])
    assert np.isnan(state["history"][0][f"val_chamfer_x1e5_{GRID}"])
    assert (state["stage"], state["epoch"]) == (2, 0)


def test_train_main_writes_outputs_and_resumes(tiny_run):
    root, path, final = tiny_run
    run = root / "run"
    for name in ("final.pt", "last.pt", "history.json", "loss_curve.png"):
        assert (run / name).is_file(), name
    history = json.loads((run / "history.json").read_text())
    assert [h["stage"] for h in history] == [1, 1, 2]
    for key in ("train_loss", f"val_voroloss_{GRID}", f"val_occupancy_accuracy_{GRID}", f"val_chamfer_x1e5_{GRID}",
                f"val_mc_chamfer_x1e5_{GRID}"):
        assert np.isfinite(history[-1][key]), key
    _, state = load_checkpoint(final)
    assert state["training"]["threads"] == 1
    # A finished run resumes to nothing more to do and keeps its history.
    assert train_main(path) == final
    assert len(json.loads((run / "history.json").read_text())) == 3


def test_training_is_deterministic(tiny_run, tmp_path):
    root, path, final = tiny_run
    config = json.loads(path.read_text())
    config["run_dir"] = str(tmp_path / "again")
    again = tmp_path / "again.json"
    again.write_text(json.dumps(config))
    first, second = load_checkpoint(final)[0].state_dict(), load_checkpoint(train_main(again))[0].state_dict()
    for name in first:
        torch.testing.assert_close(first[name], second[name], rtol=0, atol=0, msg=name)


def test_init_starts_a_new_run_from_a_checkpoint(tiny_run, tmp_path):
    root, path, final = tiny_run
    config = json.loads(path.read_text())
    config.update(run_dir=str(tmp_path / "next"), init=str(final))
    config["stage1"]["epochs"] = 0
    config["stage2"]["epochs"] = 0
    following = tmp_path / "next.json"
    following.write_text(json.dumps(config))
    start, again = load_checkpoint(final)[0].state_dict(), load_checkpoint(train_main(following))[0].state_dict()
    for name in start:
        torch.testing.assert_close(start[name], again[name], rtol=0, atol=0, msg=name)
    config["model"]["head_width"] = 8
    following.write_text(json.dumps(config))
    with pytest.raises(ValueError, match="init checkpoint"):
        train_main(following)


def test_export_matches_torch(tiny_run, tmp_path):
    _, _, final = tiny_run
    report = export_onnx(final, tmp_path / "tiny.onnx")
    assert report.max_offset_diff <= TOLERANCE
    assert report.n_nodes > 0
    predictor = Predictor(report.path)
    assert predictor.near == NEAR
    voro = predictor.predict(check_grids()[1])
    assert voro.occupancy.any() and not voro.occupancy.all()


def test_augment_moves_grid_and_points_alike():
    g = 17
    p = grid_nodes(g)
    sdf = (np.linalg.norm((p - [0.2, -0.1, 0.3]) * [1.0, 1.5, 0.7], axis=1) - 0.5).reshape(g, g, g)
    points = np.random.default_rng(0).uniform(-0.8, 0.8, (50, 3))
    moved_sdf, moved_points = augment(sdf, points, np.random.default_rng(5))
    np.testing.assert_allclose(sdf_at(moved_sdf, moved_points), sdf_at(sdf, points), atol=1e-12)


def test_config_errors(tmp_path):
    with pytest.raises(FileNotFoundError, match="config"):
        load_config(tmp_path / "missing.json")
    bad = tmp_path / "bad.json"
    bad.write_text('{"stage1": {"epoch": 3}}')
    with pytest.raises(ValueError, match="epoch"):
        load_config(bad)
    bad.write_text('{"lr": 3}')
    with pytest.raises(ValueError, match="unknown config key 'lr'"):
        load_config(bad)
    bad.write_text("{not json")
    with pytest.raises(ValueError, match="not a valid config"):
        load_config(bad)


def test_checkpoint_errors(tmp_path):
    with pytest.raises(FileNotFoundError, match="checkpoint"):
        load_checkpoint(tmp_path / "missing.pt")
    corrupt = tmp_path / "corrupt.pt"
    corrupt.write_bytes(b"not a checkpoint")
    with pytest.raises(ValueError, match="not a voro3d.learn checkpoint"):
        load_checkpoint(corrupt)
    with pytest.raises(ValueError, match="not a voro3d.learn checkpoint"):
        export_onnx(corrupt, tmp_path / "out.onnx")


def _ball_sdf(g, centre, radius=0.4):
    return (np.linalg.norm(grid_nodes(g) - centre, axis=1) - radius).reshape(g, g, g).astype(np.float32)


def test_band_net_is_local_and_shift_equivariant():
    """A node's outputs depend on its neighbourhood only: moving the shape by 4 nodes (the coarsest
    stride, so every parity is kept) moves the outputs with it, and a far-away second shape changes nothing."""
    torch.manual_seed(2)
    model = BandNet(widths=(4, 8, 8), head_width=16).eval()
    g = 48
    step = 2 / (g - 1)
    one = _ball_sdf(g, [-0.3, -0.3, -0.3], 0.3)
    shifted = _ball_sdf(g, [-0.3 + 4 * step, -0.3, -0.3], 0.3)
    pair = np.minimum(one, _ball_sdf(g, [0.6, 0.6, 0.6], 0.25))

    def run(sdf):
        net_input = model.network_input(sdf, near=NEAR)
        with torch.no_grad():
            offsets, logits = model(**{k: torch.from_numpy(v) for k, v in net_input.arrays.items()})
        return net_input.ijk, offsets.numpy(), logits.numpy()

    ijk, offsets, logits = run(one)
    moved_ijk, moved_offsets, moved_logits = run(shifted)
    np.testing.assert_array_equal(moved_ijk, ijk + [4, 0, 0])
    np.testing.assert_allclose(moved_offsets, offsets, atol=1e-5)
    np.testing.assert_allclose(moved_logits, logits, atol=1e-5)
    pair_ijk, pair_offsets, _ = run(pair)
    flat = (pair_ijk * [g * g, g, 1]).sum(axis=1)
    first = np.isin(flat, (ijk * [g * g, g, 1]).sum(axis=1))
    assert first.sum() == ijk.shape[0] < pair_ijk.shape[0]
    np.testing.assert_allclose(pair_offsets[first], offsets, atol=1e-5)


def test_build_model_errors():
    with pytest.raises(ValueError, match="arch must be one of"):
        build_model({"arch": "transformer"})
    with pytest.raises(ValueError, match="bad model config"):
        build_model({"arch": "band", "width": 16})
