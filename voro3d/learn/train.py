"""Two-stage training of :class:`~voro3d.learn.model.BandNet`, as in the paper.

Stage 1 trains the CNN and MLP1 (offsets) with VoroLoss plus ``reg_weight`` times the largest
offset norm; stage 2 freezes both and trains MLP2 (occupancy) with binary cross-entropy against
the true occupancy of every predicted cell: the shape's inside test at
:func:`voro3d.occupancy.cell_interior_points` of the predicted generators, with the fixed
fallback generators of :mod:`voro3d.infer` present as at inference.

Both stages see exactly the network input that :class:`voro3d.infer.Predictor` builds (the
model's ``network_input``). VoroLoss is
measured in voxel units (divided by the squared voxel size), so grids of every size weigh the
same. A batch is ``batch_size`` shapes, each at a grid size drawn with ``grid_weights`` and
(stage 1) a random axis permutation and flips; the network runs once on their band graphs joined
into one (:func:`voro3d.learn.batches.join_inputs`) and their losses are averaged before one step. ``workers``
processes prepare the batches (augmentation and band indices, numpy) while the network trains.

``device`` runs stage 1 and the validation VoroLoss on another torch device (``"cuda"``): the
kNN search then runs there too. ``stage1.time_budget_s`` trains for that many wall-clock seconds
instead of a number of epochs, annealing the learning rate over the time (a GPU machine lent for
a fixed time; the result then depends on the machine's speed). With ``validation.n_detail = 0``
no mesh-based metric is computed, so a stage-1 run needs neither Open3D nor the meshes
(:mod:`voro3d.learn.pack`); stage 2 always runs on the CPU.

Run ``python -m voro3d.learn.train models/voromesh_sdf.json`` (or :func:`train_main`). Relative
paths in the config resolve against the working directory. Everything random derives from
``seed`` and the epoch, so a run resumed from its last checkpoint ends where an uninterrupted
one would. Training time is counted in CPU seconds of the process (``time.process_time``), so a
run paused with SIGSTOP (or resumed in a later session) records only the time it computed;
nothing in training waits on the wall clock.
"""
from __future__ import annotations

import copy
import json
import sys
import time
from pathlib import Path

import numpy as np

from .._extras import require

# Before the modules below, which need torch too, so that the message names what was asked for.
torch = require("torch", "training (voro3d train)")

from ..infer import BAND, NetworkInput, assemble, fixed_generators, sdf_at
from ..io import atomic_path
from ..loss import voroloss
from . import machine_description
from .batches import Stage1Batches, as_batch, as_torch, batch_loss, generators_of
from .data import ShapeSet, build_dataset
from .model import build_model, load_checkpoint, save_checkpoint

__all__ = ["cell_labels", "load_config", "train_main"]

DEFAULTS = {
    "seed": 0,
    "threads": 1,
    # Torch device of stage 1 ("cpu", "cuda", ...) and processes preparing its batches (0: in the loop).
    "device": "cpu",
    "workers": 0,
    "run_dir": "runs/voromesh_sdf",
    # A checkpoint whose weights start the run (a new run continuing an earlier one), or None.
    "init": None,
    "data": {"train_dir": "runs/voromesh_sdf/data/train", "val_dir": "runs/voromesh_sdf/data/val",
             "n_train": 360, "n_val": 16, "train_seed": 7, "val_seed": 1001, "grids": [32, 64],
             "n_samples": 50_000, "mesh_dir": None, "n_organic": 0, "n_thin": 0, "n_cut": 0},
    # Keyword arguments of the network named by "arch" (voro3d.learn.model.build_model checks them).
    "model": {"arch": "band", "widths": [16, 32, 64], "head_width": 64, "context": 3.0},
    "near": 1.0,
    "band": BAND,
    "stage1": {"epochs": 20, "batch_size": 2, "lr": 3e-3, "final_lr_fraction": 0.05, "reg_weight": 2e-3,
               "samples_per_shape": 20_000, "grid_weights": [0.7, 0.3], "augment": True,
               "time_budget_s": None},
    "stage2": {"epochs": 12, "batch_size": 4096, "lr": 1e-3, "n_shapes": 80, "nodes_per_shape": 3000},
    "validation": {"n_detail": 4, "cd_points": 10_000},
}


def load_config(path) -> dict:
    """A training config: JSON (or YAML when PyYAML is installed) merged over ``DEFAULTS``.

    Raises
    ------
    FileNotFoundError
        No file at ``path``.
    ValueError
        Unparseable file, keys that ``DEFAULTS`` does not know (typos would be silently ignored), or
        a model config its network does not take.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"no config file at {path}")
    text = path.read_text()
    try:
        if path.suffix.lower() in (".yaml", ".yml"):
            try:
                import yaml
            except ImportError:
                raise ValueError(f"{path} is YAML but PyYAML is not installed; use a .json config") from None
            given = yaml.safe_load(text)
        else:
            given = json.loads(text)
    except (ValueError, TypeError) as error:
        raise ValueError(f"{path} is not a valid config: {error}") from error
    if not isinstance(given, dict):
        raise ValueError(f"{path} must hold a mapping, got {type(given).__name__}")
    config = copy.deepcopy(DEFAULTS)
    for key, value in given.items():
        if key not in config:
            raise ValueError(f"{path}: unknown config key {key!r}; known: {sorted(config)}")
        if key == "model" and isinstance(value, dict):
            # Each network has its own arguments: merge over the defaults of the same arch only.
            base = config["model"] if value.get("arch", "band") == config["model"]["arch"] else {}
            config["model"] = {**base, **value}
            try:
                build_model(config["model"])
            except ValueError as error:
                raise ValueError(f"{path}: {error}") from None
        elif isinstance(config[key], dict):
            unknown = set(value) - set(config[key])
            if unknown:
                raise ValueError(f"{path}: unknown keys {sorted(unknown)} in {key!r}; known: {sorted(config[key])}")
            config[key].update(value)
        else:
            config[key] = value
    return config


def cell_labels(mesh_queries, net_input: NetworkInput, generators: np.ndarray, sdf: np.ndarray, *,
                near: float, band: float) -> np.ndarray:
    """True occupancy of the predicted cells, with the fixed fallback generators present.

    Parameters
    ----------
    mesh_queries : voro3d.queries.InsideOutside
        Inside test of the ground-truth mesh (fit frame).
    net_input : NetworkInput
    generators : (n, 3) float64
        Predicted generators.
    sdf : (g, g, g) float32
    near, band : float
        Node threshold and outer edge of the fixed band, in voxels.

    Returns
    -------
    (n,) bool
        Whether the interior point of each predicted cell lies inside the mesh.
    """
    from ..occupancy import cell_interior_points

    fixed, _ = fixed_generators(sdf, near=near, band=band)
    points = cell_interior_points(np.concatenate([generators, fixed]))[: generators.shape[0]]
    return mesh_queries.occupancy(points)


class _Validation:
    """Fixed validation shapes, their labels' inputs, and the Marching Cubes scores to beat.

    Every shape gives a VoroLoss; the first ``n_detail`` also an occupancy accuracy and a Chamfer
    distance against the mesh, and Marching Cubes' on the same grid (these need Open3D and the
    meshes; with ``n_detail = 0`` they are NaN).
    """

    def __init__(self, shapes: ShapeSet, grids, n_detail: int, cd_points: int):
        self.shapes = [shapes[i] for i in range(len(shapes))]
        self.grids = list(grids)
        self.detail = list(range(min(n_detail, len(self.shapes))))
        self.cd_points = cd_points
        self.queries, self.mc = {}, {grid: float("nan") for grid in self.grids}
        if not self.detail:
            return
        from ..baselines import marching_cubes
        from ..metrics import evaluate
        from ..queries import InsideOutside

        self.queries = {i: InsideOutside((self.shapes[i]["vertices"], self.shapes[i]["triangles"]))
                        for i in self.detail}
        for grid in self.grids:
            scores = [evaluate(marching_cubes(self.shapes[i][f"sdf_{grid}"]), self._gt(i), n_samples=cd_points)
                      for i in self.detail]
            self.mc[grid] = float(np.mean([s["chamfer_x1e5"] for s in scores]))

    def _gt(self, i):
        return self.shapes[i]["vertices"], self.shapes[i]["triangles"]

    def run(self, model: torch.nn.Module, *, near: float, band: float, stage: int) -> dict:
        """Validation metrics; stage 1 labels cells by the SDF sign at the generator (MLP2 is untrained)."""
        if self.detail:
            from ..metrics import evaluate
        model.eval()
        device = next(model.parameters()).device
        result = {}
        for grid in self.grids:
            losses, correct, total, chamfers = [], 0, 0, []
            for i, shape in enumerate(self.shapes):
                sdf = shape[f"sdf_{grid}"]
                net_input = model.network_input(sdf, near=near)
                with torch.no_grad():
                    offsets, logits = model(**as_torch(net_input.arrays, device))
                    generators = generators_of(net_input, offsets)
                    losses.append(float(voroloss(torch.from_numpy(shape["samples"]), generators)) / net_input.step**2)
                if i not in self.detail:
                    continue
                offsets, logits, generators = offsets.cpu(), logits.cpu(), generators.cpu()
                if stage == 1:
                    logits = torch.from_numpy(-sdf_at(sdf, generators.double().numpy()))
                generators = generators.double().numpy()
                labels = cell_labels(self.queries[i], net_input, generators, sdf, near=near, band=band)
                correct += int(((logits.numpy() > 0) == labels).sum())
                total += labels.size
                voro = assemble(sdf, net_input, offsets.numpy(), logits.numpy(), near=near, fallback=True,
                                band=band)
                chamfers.append(evaluate(voro.to_open3d(), self._gt(i), n_samples=self.cd_points)["chamfer_x1e5"])
            result[f"val_voroloss_{grid}"] = float(np.mean(losses))
            result[f"val_occupancy_accuracy_{grid}"] = correct / total if total else float("nan")
            result[f"val_chamfer_x1e5_{grid}"] = float(np.mean(chamfers)) if chamfers else float("nan")
            result[f"val_mc_chamfer_x1e5_{grid}"] = self.mc[grid]
        return result


def _plot(history: list[dict], path: Path, grids) -> None:
    """Loss curves of both stages into a PNG."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    figure, axes = plt.subplots(1, 3, figsize=(15, 4))
    first = [h for h in history if h["stage"] == 1]
    second = [h for h in history if h["stage"] == 2]
    if first:
        epochs = [h["epoch"] + 1 for h in first]
        axes[0].plot(epochs, [h["train_loss"] for h in first], label="train loss (VoroLoss + reg)")
        for grid in grids:
            axes[0].plot(epochs, [h[f"val_voroloss_{grid}"] for h in first], label=f"val VoroLoss {grid}^3")
        axes[0].set(title="stage 1", xlabel="epoch", ylabel="voxel^2", yscale="log")
        axes[0].legend()
    if second:
        epochs = [h["epoch"] + 1 for h in second]
        axes[1].plot(epochs, [h["train_loss"] for h in second], label="train BCE")
        for grid in grids:
            axes[1].plot(epochs, [1 - h[f"val_occupancy_accuracy_{grid}"] for h in second],
                         label=f"val occupancy error {grid}^3")
        axes[1].set(title="stage 2", xlabel="epoch", yscale="log")
        axes[1].legend()
    step = list(range(1, len(history) + 1))
    for grid in grids:
        axes[2].plot(step, [h[f"val_chamfer_x1e5_{grid}"] for h in history], label=f"learned {grid}^3")
        axes[2].plot(step, [h[f"val_mc_chamfer_x1e5_{grid}"] for h in history], "--", label=f"MC {grid}^3")
    axes[2].set(title="validation CD x1e5 (stage 1 then 2)", xlabel="epoch (both stages)", yscale="log")
    axes[2].legend()
    figure.tight_layout()
    with atomic_path(path, suffix=".png") as tmp:
        figure.savefig(tmp, dpi=100)
    plt.close(figure)


def _stage1_epoch(model, optimizer, step_lr, shapes: ShapeSet, config: dict, epoch: int, progress) -> dict:
    """One pass over the training shapes; ``step_lr()`` runs after every optimizer step."""
    batches = Stage1Batches(shapes, config, epoch, model.context)
    workers = int(config["workers"])
    loader = torch.utils.data.DataLoader(batches, batch_size=None, shuffle=False, num_workers=workers,
                                         collate_fn=as_batch, prefetch_factor=4 if workers else None,
                                         persistent_workers=False)
    model.train()
    totals = []
    for batch in loader:
        optimizer.zero_grad()
        loss, _ = batch_loss(model, batch, reg_weight=config["stage1"]["reg_weight"])
        loss.backward()
        optimizer.step()
        step_lr()
        totals.append(loss.item())
        progress.update(len(batch))
        progress.set_postfix(loss=f"{totals[-1]:.4f}")
    return {"train_loss": float(np.mean(totals))}


def _occupancy_table(model: torch.nn.Module, shapes: ShapeSet, indices, grids, *, near: float, band: float,
                     nodes_per_shape: int, seed: int, progress) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Frozen features, offsets and true cell labels of up to ``nodes_per_shape`` nodes per shape and grid."""
    from ..queries import InsideOutside

    rng = np.random.default_rng([seed, 2])
    features, offsets, labels = [], [], []
    model.eval()
    for i in indices:
        shape = shapes[int(i)]
        queries = InsideOutside((shape["vertices"], shape["triangles"]))
        for grid in grids:
            sdf = shape[f"sdf_{grid}"]
            net_input = model.network_input(sdf, near=near)
            with torch.no_grad():
                feature = model.node_features(**as_torch(net_input.arrays))
                offset = model.offset_head(feature)
            generators = generators_of(net_input, offset).double().numpy()
            label = cell_labels(queries, net_input, generators, sdf, near=near, band=band)
            keep = rng.permutation(label.size)[:nodes_per_shape]
            features.append(feature[keep])
            offsets.append(offset[keep])
            labels.append(torch.from_numpy(label[keep]))
        progress.update(1)
    return torch.cat(features), torch.cat(offsets), torch.cat(labels).float()


def train_main(config_path) -> Path:
    """Train a model from a config file, resuming from ``run_dir/last.pt`` when it exists.

    A new run starts from random weights, or from those of the checkpoint ``init`` (an earlier
    run's ``final.pt``: a later session continues training with a new schedule). Writes to
    ``run_dir``: ``last.pt`` (after every epoch), ``final.pt`` (model, config, history, training
    record), ``history.json`` and ``loss_curve.png``.

    Parameters
    ----------
    config_path : str or os.PathLike
        JSON (or YAML) config; see ``DEFAULTS`` for the keys.

    Returns
    -------
    pathlib.Path
        ``run_dir/final.pt``.

    Raises
    ------
    ValueError
        A bad config, or an ``init`` checkpoint of another network than the configured one.
    """
    from tqdm import tqdm

    config = load_config(config_path)
    torch.set_num_threads(int(config["threads"]))
    torch.manual_seed(config["seed"])
    run_dir = Path(config["run_dir"])
    run_dir.mkdir(parents=True, exist_ok=True)
    data = config["data"]
    grids = [int(g) for g in data["grids"]]
    train = ShapeSet(build_dataset(data["train_dir"], data["n_train"], grid=grids, seed=data["train_seed"],
                                   n_samples=data["n_samples"], mesh_dir=data["mesh_dir"],
                                   n_organic=data["n_organic"], n_thin=data["n_thin"], n_cut=data["n_cut"]))
    validation = _Validation(ShapeSet(build_dataset(data["val_dir"], data["n_val"], grid=grids,
                                                    seed=data["val_seed"], n_samples=data["n_samples"])),
                             grids, config["validation"]["n_detail"], config["validation"]["cd_points"])

    model = build_model(config["model"])
    if config["init"] is not None:
        start, _ = load_checkpoint(config["init"])
        if start.config != model.config:
            raise ValueError(f"init checkpoint {config['init']} holds a {start.config} model, "
                             f"not the configured {model.config}")
        model = start
    model.to(config["device"])  # before any optimizer: its state follows the parameters' device
    s1, s2 = config["stage1"], config["stage2"]
    steps_per_epoch = -(-len(train) // s1["batch_size"])
    optimizer = torch.optim.Adam(list(model.parameters()), lr=s1["lr"])
    scheduler = torch.optim.lr_scheduler.CosineAnnealingLR(optimizer, T_max=s1["epochs"] * steps_per_epoch,
                                                           eta_min=s1["lr"] * s1["final_lr_fraction"])
    history, seconds = [], {"stage1": 0.0, "stage2": 0.0}
    stage, epoch = 1, 0
    last = run_dir / "last.pt"
    if last.is_file():
        model, state = load_checkpoint(last)
        model.to(config["device"])
        history, seconds, stage, epoch = state["history"], state["seconds"], state["stage"], state["epoch"]
        optimizer = torch.optim.Adam(list(model.parameters()), lr=s1["lr"])
        scheduler = torch.optim.lr_scheduler.CosineAnnealingLR(optimizer, T_max=s1["epochs"] * steps_per_epoch,
                                                               eta_min=s1["lr"] * s1["final_lr_fraction"])
        if stage == 1:
            optimizer.load_state_dict(state["optimizer"])
            scheduler.load_state_dict(state["scheduler"])
        tqdm.write(f"resuming {last}: stage {stage}, epoch {epoch}")

    def checkpoint(path, **extra):
        save_checkpoint(path, model, config=config, near=config["near"], history=history, seconds=seconds,
                        stage=stage, epoch=epoch, **extra)
        with atomic_path(run_dir / "history.json", suffix=".json") as tmp:
            Path(tmp).write_text(json.dumps(history, indent=1))
        _plot(history, run_dir / "loss_curve.png", grids)

    budget, clock, first_epoch = s1["time_budget_s"], time.monotonic(), epoch

    def step_lr():
        if budget is None:
            scheduler.step()
            return
        # Cosine annealing over the wall-clock budget instead of the steps.
        fraction = min(1.0, (time.monotonic() - clock) / budget)
        for group in optimizer.param_groups:
            group["lr"] = s1["lr"] * (s1["final_lr_fraction"] + (1 - s1["final_lr_fraction"])
                                      * 0.5 * (1 + np.cos(np.pi * fraction)))

    while stage == 1 and epoch < s1["epochs"]:
        started = time.process_time()
        with tqdm(total=len(train), desc=f"stage 1 epoch {epoch + 1}/{s1['epochs']}", unit="shape",
                  leave=False) as progress:
            metrics = _stage1_epoch(model, optimizer, step_lr, train, config, epoch, progress)
        seconds["stage1"] += time.process_time() - started
        metrics.update(validation.run(model, near=config["near"], band=config["band"], stage=1), stage=1, epoch=epoch)
        history.append(metrics)
        tqdm.write(json.dumps(metrics))
        epoch += 1
        checkpoint(last, optimizer=optimizer.state_dict(), scheduler=scheduler.state_dict())
        elapsed = time.monotonic() - clock
        if budget is not None and elapsed * (epoch - first_epoch + 1) / (epoch - first_epoch) > budget:
            break  # another epoch would overrun the budget
    if stage == 1:
        stage, epoch = 2, 0
    model.to("cpu")

    # Stage 2: the CNN and MLP1 are frozen, so their outputs are computed once per shape.
    for parameter in model.parameters():
        parameter.requires_grad_(False)
    head = model.occupancy_head
    for parameter in head.parameters():
        parameter.requires_grad_(True)
    optimizer = torch.optim.Adam(head.parameters(), lr=s2["lr"])
    if stage == 2 and epoch > 0:
        optimizer.load_state_dict(torch.load(last, map_location="cpu", weights_only=False)["optimizer"])
    if epoch < s2["epochs"]:
        started = time.process_time()
        indices = np.random.default_rng([config["seed"], 3]).permutation(len(train))[: s2["n_shapes"]]
        with tqdm(total=len(indices), desc="stage 2 labels", unit="shape", leave=False) as progress:
            features, offsets, labels = _occupancy_table(
                model, train, indices, grids, near=config["near"], band=config["band"],
                nodes_per_shape=s2["nodes_per_shape"], seed=config["seed"], progress=progress)
        seconds["stage2"] += time.process_time() - started
    while epoch < s2["epochs"]:
        started = time.process_time()
        order = torch.from_numpy(np.random.default_rng([config["seed"], 4, epoch]).permutation(labels.shape[0]))
        head.train()
        losses = []
        for start in tqdm(range(0, order.shape[0], s2["batch_size"]), desc=f"stage 2 epoch {epoch + 1}",
                          leave=False):
            rows = order[start:start + s2["batch_size"]]
            logits = model.occupancy(features[rows], offsets[rows])
            loss = torch.nn.functional.binary_cross_entropy_with_logits(logits, labels[rows])
            optimizer.zero_grad()
            loss.backward()
            optimizer.step()
            losses.append(loss.item())
        seconds["stage2"] += time.process_time() - started
        metrics = validation.run(model, near=config["near"], band=config["band"], stage=2)
        metrics.update(train_loss=float(np.mean(losses)), stage=2, epoch=epoch)
        history.append(metrics)
        tqdm.write(json.dumps(metrics))
        epoch += 1
        checkpoint(last, optimizer=optimizer.state_dict())

    final = run_dir / "final.pt"
    training = {"seconds_stage1": round(seconds["stage1"], 1), "seconds_stage2": round(seconds["stage2"], 1),
                "threads": int(config["threads"]), "machine": machine_description(),
                "torch": torch.__version__, "n_train_shapes": len(train), "grids": grids}
    checkpoint(final, training=training, validation=history[-1] if history else {})
    return final


if __name__ == "__main__":
    if len(sys.argv) != 2:
        sys.exit("usage: python -m voro3d.learn.train CONFIG.json")
    print(train_main(sys.argv[1]))
