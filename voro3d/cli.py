"""The ``voro3d`` command: a thin layer over the library.

Errors in the input become one line on stderr and exit status 2; outputs are written
atomically, so a failed run leaves no file behind.
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from ._extras import MissingExtra

__all__ = ["build_parser", "main"]


def _extract(args) -> None:
    from .voromesh import VoroMesh
    from .io import save_mesh

    shape = VoroMesh.load(args.generators)
    mesh = shape.to_open3d(clean=not args.no_clean)
    save_mesh(mesh, args.output)
    _maybe_save_polygons(args, shape)
    _maybe_render(args, [mesh], ["VoroMesh"])
    _say(args, f"wrote {args.output} ({len(mesh.triangles)} triangles, watertight)")


def _fit(args) -> None:
    from .fitting import fit
    from .io import load_mesh, save_mesh

    source = load_mesh(args.mesh)
    shape, _ = fit(source, grid=args.grid, steps=args.steps, seed=args.seed, device=args.device,
                   progress=not args.quiet)
    mesh = shape.to_open3d(clean=not args.no_clean, surface=None if args.no_clean else source)
    save_mesh(mesh, args.output)
    _maybe_save_polygons(args, shape)
    if args.save_generators:
        shape.save(args.save_generators)
    _maybe_render(args, [source, mesh], ["input", f"VoroMesh {args.grid}^3"])
    _say(args, f"wrote {args.output} ({len(shape.generators)} generators, {len(mesh.triangles)} triangles)")


def _predict(args) -> None:
    from .infer import Predictor
    from .io import save_mesh

    predictor = Predictor(args.model)
    source = Path(args.input)
    if source.suffix.lower() in (".npy", ".npz"):
        if args.grid is not None:
            raise ValueError(f"--grid applies to a mesh INPUT only; the SDF grid {source} has its own size")
        shape = predictor.predict(_load_sdf(source), fallback=not args.no_fallback)
        reference = None
    else:
        from .io import load_mesh

        reference = load_mesh(source)
        shape = predictor.predict_from_mesh(reference, 32 if args.grid is None else args.grid,
                                            fallback=not args.no_fallback)
    mesh = shape.to_open3d(clean=not args.no_clean, surface=None if args.no_clean else reference)
    save_mesh(mesh, args.output)
    _maybe_save_polygons(args, shape)
    panels = [mesh] if reference is None else [reference, mesh]
    _maybe_render(args, panels, ["learned VoroMesh"] if reference is None else ["input", "learned VoroMesh"])
    _say(args, f"wrote {args.output} ({len(shape.generators)} generators, {len(mesh.triangles)} triangles)")


def _reconstruct(args) -> None:
    from .io import save_mesh
    from .reconstruction import reconstruct

    mesh = reconstruct(args.input, args.grid, method=args.method, steps=args.steps, seed=args.seed,
                       device=args.device, denoise=args.denoise, clean=not args.no_clean, progress=not args.quiet)
    save_mesh(mesh, args.output)
    _maybe_render(args, [mesh], [f"VoroMesh ({args.method}) {args.grid}^3"])
    _say(args, f"wrote {args.output} ({len(mesh.triangles)} triangles, watertight)")


def _polygon_path(text: str) -> str:
    """Checked before anything runs, so that a bad suffix leaves no mesh behind either."""
    from .io import POLYGON_SUFFIXES

    if Path(text).suffix.lower() not in POLYGON_SUFFIXES:
        raise argparse.ArgumentTypeError(f"must end in one of {', '.join(POLYGON_SUFFIXES)}, got {text!r}")
    return text


def _grid_or_auto(text: str):
    if text == "auto":
        return text
    try:
        return int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"grid must be an integer or 'auto', got {text!r}") from None


def _load_sdf(path: Path):
    import numpy as np

    if path.suffix.lower() == ".npy":
        return np.load(path, allow_pickle=False)
    with np.load(path, allow_pickle=False) as data:
        if "sdf" not in data.files:
            raise ValueError(f"{path} has no array named 'sdf' (it holds {sorted(data.files)})")
        return data["sdf"]


def _train(args) -> None:
    from .learn.train import train_main

    _say(args, f"checkpoints in {train_main(args.config)}")


def _export(args) -> None:
    from .learn.export import export_onnx

    report = export_onnx(args.checkpoint, args.output)
    print(report)


def _eval(args) -> None:
    from .io import load_mesh
    from .metrics import evaluate
    from .watertight import check_watertight

    predicted = load_mesh(args.predicted, weld=False)
    result = evaluate(predicted, load_mesh(args.ground_truth), n_samples=args.n_samples, seed=args.seed)
    result["watertight"] = check_watertight(predicted, self_intersection=not args.no_self_intersection).as_dict()
    if args.json:
        print(json.dumps(result, indent=2))
        return
    rows = [(k, v) for k, v in result.items() if not isinstance(v, dict)]
    rows += [(f"watertight.{k}", v) for k, v in result["watertight"].items()]
    width = max(len(k) for k, _ in rows)
    for key, value in rows:
        print(f"{key:<{width}}  {value:.6g}" if isinstance(value, float) else f"{key:<{width}}  {value}")


def _render(args) -> None:
    from .io import load_mesh
    from .render import render_error_map, render_meshes

    meshes = [load_mesh(path, weld=False) for path in args.meshes]
    if args.error_against:
        render_error_map(meshes[0], load_mesh(args.error_against), args.output)
    else:
        render_meshes(meshes, args.output, titles=args.titles or [Path(p).stem for p in args.meshes])
    _say(args, f"wrote {args.output}")


def _maybe_render(args, meshes, titles) -> None:
    if getattr(args, "png", None):
        from .render import render_meshes

        render_meshes(meshes, args.png, titles=titles)


def _maybe_save_polygons(args, shape) -> None:
    if getattr(args, "polygons", None):
        from .io import save_polygons

        save_polygons(shape.to_polygons(), args.polygons)


def _say(args, message: str) -> None:
    if not getattr(args, "quiet", False):
        print(message, file=sys.stderr)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="voro3d", description=__doc__.splitlines()[0])
    parser.add_argument("--version", action="version", version=_version())
    commands = parser.add_subparsers(dest="command", required=True)

    extract = commands.add_parser("extract", help="watertight mesh from saved generators + occupancy (.npz)")
    extract.add_argument("generators", help=".npz with arrays 'generators' (n,3) and 'occupancy' (n,)")
    _mesh_output_options(extract, polygons=True)
    extract.set_defaults(run=_extract)

    fit = commands.add_parser("fit", help="fit a VoroMesh to a watertight mesh (direct optimisation)")
    fit.add_argument("mesh", help="input mesh (.ply, .obj, .off, .stl)")
    _mesh_output_options(fit, polygons=True)
    fit.add_argument("--grid", type=int, default=32, help="grid resolution g (g^3 nodes), default 32")
    fit.add_argument("--steps", type=int, default=400, help="Adam steps, default 400")
    fit.add_argument("--seed", type=int, default=0)
    fit.add_argument("--device", default="cpu", help="cpu or cuda")
    fit.add_argument("--save-generators", help="also save generators + occupancy (.npz)")
    fit.set_defaults(run=_fit)

    predict = commands.add_parser("predict", help="learned VoroMesh from an SDF grid or a mesh (ONNX, no torch)")
    predict.add_argument("input", help="SDF grid (.npy, or .npz with array 'sdf'; (g,g,g), negative inside, "
                                       "nodes spanning [-1,1]^3) or a mesh")
    _mesh_output_options(predict, polygons=True)
    predict.add_argument("--grid", type=int, help="SDF resolution when INPUT is a mesh, default 32 (an SDF grid "
                                                  "INPUT has its own)")
    predict.add_argument("--model", help="ONNX model (default: the shipped voro3d/models/voromesh_sdf.onnx)")
    predict.add_argument("--no-fallback", action="store_true", help="trust the network's occupancy everywhere")
    predict.set_defaults(run=_predict)

    rebuild = commands.add_parser("reconstruct", help="watertight mesh from a point cloud (or mesh) file")
    rebuild.add_argument("input", help="point cloud (.ply .pcd .xyz .xyzn .xyzrgb .pwn .pts; .npy (n,3)/(n,6)) or mesh")
    _mesh_output_options(rebuild)
    rebuild.add_argument("--grid", type=_grid_or_auto, default="auto",
                         help="grid resolution, or 'auto' (default: from the point spacing, 32-64; 32 for meshes)")
    rebuild.add_argument("--method", choices=("fit", "learned"), default="fit")
    # Fit options default to None: the fit's defaults apply, and --method learned refuses them.
    rebuild.add_argument("--steps", type=int, help="Adam steps of --method fit, default 400 for a mesh, 200 for a point cloud")
    rebuild.add_argument("--seed", type=int, help="seed of --method fit, default 0")
    rebuild.add_argument("--device", help="cpu or cuda, for --method fit (default cpu)")
    smoothing = rebuild.add_mutually_exclusive_group()
    smoothing.add_argument("--denoise", dest="denoise", action="store_const", const=True, default=None,
                           help="always smooth the points onto the IMLS surface (default: when noise is detected)")
    smoothing.add_argument("--no-denoise", dest="denoise", action="store_const", const=False,
                           help="never smooth the points")
    rebuild.set_defaults(run=_reconstruct)

    train = commands.add_parser("train", help="train the SDF -> generators network (needs torch)")
    train.add_argument("--config", required=True, help="JSON config, e.g. models/voromesh_sdf.json")
    train.add_argument("-q", "--quiet", action="store_true")
    train.set_defaults(run=_train)

    export = commands.add_parser("export-onnx", help="export a training checkpoint to ONNX, checked against torch")
    export.add_argument("checkpoint")
    export.add_argument("-o", "--output", required=True, help="output .onnx")
    export.set_defaults(run=_export)

    from .batch import add_batch_parser

    add_batch_parser(commands)

    evaluate = commands.add_parser("eval", help="Chamfer, F1, normal consistency and watertightness")
    evaluate.add_argument("predicted")
    evaluate.add_argument("ground_truth")
    evaluate.add_argument("--n-samples", "--n-points", dest="n_samples", type=int, default=100_000,
                          help="surface samples per mesh, default 100000")
    evaluate.add_argument("--seed", type=int, default=0)
    evaluate.add_argument("--json", action="store_true", help="print JSON instead of a table")
    evaluate.add_argument("--no-self-intersection", action="store_true",
                          help="skip the triangle-pair intersection test (slow on big meshes)")
    evaluate.set_defaults(run=_eval)

    render = commands.add_parser("render", help="PNG of meshes side by side, or an error map")
    render.add_argument("meshes", nargs="+")
    render.add_argument("-o", "--output", required=True, help="output .png")
    render.add_argument("--titles", nargs="*")
    render.add_argument("--error-against", help="colour the first mesh by its distance to this one")
    render.add_argument("-q", "--quiet", action="store_true")
    render.set_defaults(run=_render)
    return parser


def _mesh_output_options(parser, *, polygons: bool = False) -> None:
    """The options every command that writes a mesh shares; ``--polygons`` where a VoroMesh is made."""
    parser.add_argument("-o", "--output", required=True, help="output mesh (.ply, .obj, .off, .stl, .glb)")
    parser.add_argument("--png", help="also render a picture here (with the input beside it where there is one)")
    parser.add_argument("--no-clean", action="store_true",
                        help="keep the Voronoi faces as they are (default: cleaned, see voro3d.cleaning, then "
                        "fitted to the input mesh or the cloud's target surface, see voro3d.snapping)")
    if polygons:
        parser.add_argument("--polygons", type=_polygon_path,
                            help="also write the Voronoi faces as polygons, one per face, uncleaned (.ply, .obj, .off)")
    parser.add_argument("-q", "--quiet", action="store_true", help="no progress bar or messages")


def _version() -> str:
    from . import __version__

    return f"voro3d {__version__}"


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    try:
        status = args.run(args)
    except (ValueError, MissingExtra, FileNotFoundError, IsADirectoryError, PermissionError) as error:
        print(f"voro3d {args.command}: error: {error}", file=sys.stderr)
        return 2
    except RuntimeError as error:  # a failed internal check or worker: say it in one line too
        print(f"voro3d {args.command}: failed: {error}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print(f"voro3d {args.command}: interrupted", file=sys.stderr)
        return 130
    return status if isinstance(status, int) else 0


if __name__ == "__main__":
    sys.exit(main())
