"""The ``voro3d`` command: a thin layer over the library.

Errors in the input become one line on stderr, naming the command-line flags, and exit status 2
(a warning is one line too); output paths are checked before any work, and outputs are written
atomically, so a failed run leaves no file behind.
"""
from __future__ import annotations

import argparse
import json
import os
import re
import sys
import warnings
from pathlib import Path

from ._extras import MissingExtra

# The choices of a cloud's plan (voro3d.pointcloud.CloudPlan; a test keeps them equal), written out
# so that --help need not import the point-cloud package; "auto" lets the analysis decide.
PLAN_FIELDS = {"normals": ("auto", "check", "trust", "estimate"), "denoise": ("auto", "on", "off"),
               "filter": ("auto", "on", "off"), "target": ("auto", "poisson", "imls", "sheet"), "hull": ("auto", "on", "off"),
               "thin": ("auto", "on", "off")}

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
                   allow_open=args.allow_open, progress=not args.quiet)
    mesh = shape.to_open3d(clean=not args.no_clean, surface=None if args.no_clean else source)
    save_mesh(mesh, args.output)
    _maybe_save_polygons(args, shape)
    if args.save_generators:
        shape.save(args.save_generators)
    _maybe_render(args, [source, mesh], ["input", f"VoroMesh {shape.grid}^3"])
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
        shape = predictor.predict_from_mesh(reference, "auto" if args.grid is None else args.grid,
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

    source = args.input
    if args.sample is not None:
        import numpy as np

        from .io import load_mesh
        from .sampling import sample_surface

        source = np.hstack(sample_surface(load_mesh(args.input), args.sample, seed=0 if args.seed is None else args.seed))
    chosen = {name: getattr(args, name) for name in PLAN_FIELDS if getattr(args, name) != "auto"}
    mesh = reconstruct(source, args.grid, method=args.method, steps=args.steps, seed=args.seed,
                       device=args.device, plan=chosen or None, allow_open=args.allow_open, clean=not args.no_clean,
                       engine=args.engine, workers=args.workers, progress=not args.quiet)
    save_mesh(mesh, args.output)
    _maybe_render(args, [mesh], [f"VoroMesh ({args.method}, grid {args.grid})"])
    _say(args, f"wrote {args.output} ({len(mesh.triangles)} triangles, watertight)")


def output_path(*suffixes: str):
    """An argparse type for a file to write: its suffix and its folder checked before any work runs."""

    def check(text: str) -> str:
        path = Path(text)
        if path.suffix.lower() not in suffixes:
            expected = " or ".join(suffixes) if len(suffixes) < 3 else "one of " + " ".join(suffixes)
            raise argparse.ArgumentTypeError(f"must end in {expected}, got {text!r}")
        folder = path.parent
        if not folder.is_dir():
            raise argparse.ArgumentTypeError(f"folder {str(folder)!r} of {text!r} does not exist")
        if not os.access(folder, os.W_OK):
            raise argparse.ArgumentTypeError(f"folder {str(folder)!r} of {text!r} is not writable")
        if path.is_dir():
            raise argparse.ArgumentTypeError(f"{text!r} is a folder")
        return text

    check.__name__ = "path"
    return check


def grid_argument(text: str):
    """``--grid``: ``auto`` or an integer >= 4, the rule of every subcommand (``_validate.grid_option``)."""
    from ._validate import MIN_GRID, grid_option

    try:
        return grid_option(text if text == "auto" else int(text))
    except ValueError as error:
        raise argparse.ArgumentTypeError(f"must be 'auto' or an integer >= {MIN_GRID}, got {text!r}") from error


def positive_argument(text: str) -> int:
    """An integer >= 1 (``--steps``)."""
    try:
        value = int(text)
    except ValueError:
        value = 0
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be an integer >= 1, got {text!r}")
    return value


# Python spellings in the library's messages, as the flags that set them.
_FLAG_NAMES = [
    (re.compile(r"allow_open=True"), "--allow-open"),
    (re.compile(r"plan applies to point clouds only; a mesh input takes plan=None"),
     "--normals, --denoise, --filter, --target and --hull apply to point clouds only"),
    (re.compile(r"\bplan (normals|denoise|filter|target|hull|thin)\b"), r"--\1"),
    (re.compile(r"reconstruct points sampled on it as a point cloud"), "reconstruct points sampled on it (--sample N)"),
    (re.compile(r"method='(\w+)'"), r"--method \1"),
    (re.compile(r"\b(steps|seed|device|grid|allow_open)\b(?= (must|applies|or|\())"),
     lambda match: "--" + match.group(1).replace("_", "-")),
]


def flag_names(message: str) -> str:
    """``message`` with the Python names of options written as the command's flags."""
    for pattern, replacement in _FLAG_NAMES:
        message = pattern.sub(replacement, message)
    return message


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


def _example(args) -> None:
    from .io import MESH_SUFFIXES, POINT_WRITE_SUFFIXES, save_mesh, save_points
    from .sampling import sample_surface
    from .shapes import example_mesh

    mesh = example_mesh(args.name)
    allowed = MESH_SUFFIXES if args.points is None else POINT_WRITE_SUFFIXES
    if Path(args.output).suffix.lower() not in allowed:
        raise ValueError(f"-o {args.output}: {'a mesh' if args.points is None else '--points'} is written as one of "
                         f"{' '.join(allowed)}")
    if args.points is None:
        save_mesh(mesh, args.output)
        _say(args, f"wrote {args.output} (the {args.name} mesh, {len(mesh.triangles)} triangles)")
        return
    points, normals = sample_surface(mesh, args.points, seed=args.seed)
    save_points(points, args.output, normals=None if args.no_normals else normals)
    _say(args, f"wrote {args.output} ({args.points} points of the {args.name}"
               f"{'' if args.no_normals else ', with normals'})")


def _command(commands, name: str, help_text: str, example: str, run):
    """A subcommand with its one-line help, a description and one example that runs as pasted."""
    parser = commands.add_parser(name, help=help_text, description=help_text[0].upper() + help_text[1:] + ".",
                                 epilog=f"example:\n  {example}", formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.set_defaults(run=run)
    return parser


def build_parser() -> argparse.ArgumentParser:
    from .io import MESH_SUFFIXES, POINT_SUFFIXES, POINT_WRITE_SUFFIXES
    from .shapes import example_names

    parser = argparse.ArgumentParser(
        prog="voro3d", description="Watertight, self-intersection-free surface meshes (VoroMesh) from point "
                                   "clouds, meshes and SDF grids. 'voro3d COMMAND --help' shows a command's options.",
        epilog="start here:\n  voro3d example bracket --points 20000 -o cloud.ply\n"
               "  voro3d reconstruct cloud.ply -o mesh.ply --png mesh.png",
        formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--version", action="version", version=_version())
    commands = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")

    example = _command(commands, "example", "write a bundled shape as a mesh, or sampled as a point cloud",
                       "voro3d example bracket --points 20000 -o cloud.ply", _example)
    example.add_argument("name", choices=example_names(), help="the shape")
    example.add_argument("-o", "--output", required=True, type=output_path(*MESH_SUFFIXES, *POINT_WRITE_SUFFIXES),
                         help=f"output mesh ({' '.join(MESH_SUFFIXES)}), or point cloud with --points "
                              f"({' '.join(POINT_WRITE_SUFFIXES)})")
    example.add_argument("--points", type=positive_argument, help="sample this many surface points instead")
    example.add_argument("--no-normals", action="store_true", help="leave the points' normals out")
    example.add_argument("--seed", type=int, default=0, help="seed of the sampling, default 0")
    example.add_argument("-q", "--quiet", action="store_true", help="no message")

    rebuild = _command(commands, "reconstruct", "watertight mesh from a point cloud or mesh file",
                       "voro3d reconstruct cloud.ply -o mesh.ply --png mesh.png", _reconstruct)
    rebuild.add_argument("input", help=f"point cloud ({' '.join(POINT_SUFFIXES)}; .npy (n,3) or (n,6)) or mesh "
                                       f"({' '.join(MESH_SUFFIXES)})")
    _mesh_output_options(rebuild)
    rebuild.add_argument("--grid", type=grid_argument, default="auto",
                         help="grid resolution g (g^3 nodes), an integer >= 4, or 'auto' (default: from the point "
                              "spacing, up to 128 where the surface has detail; 32 for a mesh)")
    rebuild.add_argument("--method", choices=("fit", "learned"), default="fit",
                         help="direct VoroLoss fit (default) or the shipped learned model (ONNX)")
    # Fit options default to None: the fit's defaults apply, and --method learned refuses them.
    rebuild.add_argument("--steps", type=positive_argument,
                         help="Adam steps of --method fit, default 400 for a mesh, 120 for a point cloud")
    rebuild.add_argument("--seed", type=int, help="seed of --method fit, default 0")
    rebuild.add_argument("--device", help="cpu or cuda, for --method fit (default cpu)")
    rebuild.add_argument("--normals", choices=PLAN_FIELDS["normals"], default="auto",
                         help="point clouds: check the given normals (re-orient inconsistent signs, flip inward "
                              "ones), trust them as they are, or estimate new ones (default: check if given)")
    rebuild.add_argument("--denoise", choices=PLAN_FIELDS["denoise"], default="auto",
                         help="point clouds: smooth the points onto their IMLS surface (default: when noise is "
                              "detected, and for sparse one-sided scans)")
    rebuild.add_argument("--filter", choices=PLAN_FIELDS["filter"], default="auto",
                         help="point clouds: bilateral-filter a Poisson target (default: for heavy noise)")
    rebuild.add_argument("--target", choices=PLAN_FIELDS["target"], default="auto",
                         help="point clouds: the surface fitted to: screened Poisson, IMLS (open scans) or a shell "
                              "around the points (thin walls) (default: from the cloud; the plan chosen is printed)")
    rebuild.add_argument("--hull", choices=PLAN_FIELDS["hull"], default="auto",
                         help="point clouds: cut the target back to the points' convex hull, for range scans from a "
                              "few viewpoints (default: on for one-sided scans, whose solid is also held a thin shell deep "
                              "where their rim is a crop, a terrain or a map; off for clouds that enclose a volume)")
    rebuild.add_argument("--thin", choices=PLAN_FIELDS["thin"], default="auto",
                         help="point clouds: thin points sampled along scan lines far apart for their spacing along "
                              "them (a LiDAR's) until their neighbourhoods are two-dimensional (default: when they "
                              "are not)")
    _allow_open_option(rebuild)
    rebuild.add_argument("--engine", choices=("local", "ray"), default="local",
                         help="where a large cloud's tiles are fitted (over 2 million points): a local process pool "
                              "(default) or Ray tasks (pip install 'voro3d[ray]'); the same mesh either way")
    rebuild.add_argument("--workers", type=positive_argument, help="tiles fitted at once (default: one per CPU)")
    rebuild.add_argument("--sample", type=positive_argument, metavar="N",
                         help="mesh input: reconstruct N points sampled on it (with its normals) as a point cloud, "
                              "for an open or broken mesh")

    fit = _command(commands, "fit", "fit a VoroMesh to a watertight mesh (direct optimisation)",
                   "voro3d example knot -o knot.ply && voro3d fit knot.ply -o knot_voromesh.ply --png knot.png", _fit)
    fit.add_argument("mesh", help=f"input mesh ({' '.join(MESH_SUFFIXES)})")
    _mesh_output_options(fit, polygons=True)
    fit.add_argument("--grid", type=grid_argument, default="auto",
                     help="grid resolution g (g^3 nodes), an integer >= 4, or 'auto' (default: 32)")
    fit.add_argument("--steps", type=positive_argument, default=400, help="Adam steps, default 400")
    fit.add_argument("--seed", type=int, default=0, help="seed of the samples and batches, default 0")
    fit.add_argument("--device", default="cpu", help="cpu (default) or cuda (needs torch)")
    fit.add_argument("--save-generators", type=output_path(".npz"), help="also save the VoroMesh (.npz)")
    _allow_open_option(fit)

    predict = _command(commands, "predict", "learned VoroMesh from an SDF grid or a mesh (ONNX, no torch)",
                       "voro3d example blob -o blob.ply && voro3d predict blob.ply -o blob_learned.ply", _predict)
    predict.add_argument("input", help="SDF grid (.npy, or .npz with array 'sdf'; (g,g,g), negative inside, "
                                       "nodes spanning [-1,1]^3) or a mesh")
    _mesh_output_options(predict, polygons=True)
    predict.add_argument("--grid", type=grid_argument,
                         help="SDF resolution when INPUT is a mesh, an integer >= 4 or 'auto' (default: 32); an SDF "
                              "grid INPUT has its own")
    predict.add_argument("--model", help="ONNX model (default: the shipped voro3d/models/voromesh_sdf.onnx)")
    predict.add_argument("--no-fallback", action="store_true", help="trust the network's occupancy everywhere")

    extract = _command(commands, "extract", "watertight mesh from a saved VoroMesh (.npz)",
                       "voro3d fit knot.ply -o knot_voromesh.ply --save-generators knot.npz && "
                       "voro3d extract knot.npz -o knot_again.ply", _extract)
    extract.add_argument("generators", help=".npz with arrays 'generators' (n,3) and 'occupancy' (n,) "
                                            "(and 'grid', 'frame_center', 'frame_scale' where known)")
    _mesh_output_options(extract, polygons=True)

    from .batch import add_batch_parser

    add_batch_parser(commands)

    evaluate = _command(commands, "eval", "Chamfer, F1, normal consistency and watertightness of a mesh",
                        "voro3d eval knot_voromesh.ply knot.ply", _eval)
    evaluate.add_argument("predicted", help="the mesh to score")
    evaluate.add_argument("ground_truth", help="the mesh it should match")
    evaluate.add_argument("--n-samples", "--n-points", dest="n_samples", type=positive_argument, default=100_000,
                          help="surface samples per mesh, default 100000")
    evaluate.add_argument("--seed", type=int, default=0, help="seed of the samples, default 0")
    evaluate.add_argument("--json", action="store_true", help="print JSON instead of a table")
    evaluate.add_argument("--no-self-intersection", action="store_true",
                          help="skip the triangle-pair intersection test (slow on big meshes)")

    render = _command(commands, "render", "PNG of meshes side by side, or an error map",
                      "voro3d render knot.ply knot_voromesh.ply -o side_by_side.png", _render)
    render.add_argument("meshes", nargs="+", help="meshes to draw, one panel each")
    render.add_argument("-o", "--output", required=True, type=output_path(".png"), help="output .png")
    render.add_argument("--titles", nargs="*", help="one title per mesh (default: the file names)")
    render.add_argument("--error-against", help="colour the first mesh by its distance to this one")
    render.add_argument("-q", "--quiet", action="store_true", help="no message")

    train = _command(commands, "train", "train the SDF -> generators network (needs torch)",
                     "voro3d train --config models/voromesh_sdf.json", _train)
    train.add_argument("--config", required=True, help="JSON config, e.g. models/voromesh_sdf.json")
    train.add_argument("-q", "--quiet", action="store_true", help="no message")

    export = _command(commands, "export-onnx", "export a training checkpoint to ONNX, checked against torch",
                      "voro3d export-onnx runs/voromesh/best.pt -o model.onnx", _export)
    export.add_argument("checkpoint", help="a checkpoint written by voro3d train")
    export.add_argument("-o", "--output", required=True, type=output_path(".onnx"), help="output .onnx")
    return parser


def _allow_open_option(parser) -> None:
    parser.add_argument("--allow-open", action="store_true",
                        help="mesh input: accept boundary edges, inside decided by generalized winding number")


def _mesh_output_options(parser, *, polygons: bool = False) -> None:
    """The options every command that writes a mesh shares; ``--polygons`` where a VoroMesh is made."""
    from .io import MESH_SUFFIXES, POLYGON_SUFFIXES

    parser.add_argument("-o", "--output", required=True, type=output_path(*MESH_SUFFIXES),
                        help=f"output mesh ({' '.join(MESH_SUFFIXES)})")
    parser.add_argument("--png", type=output_path(".png"),
                        help="also render a picture here (with the input beside it where there is one)")
    parser.add_argument("--no-clean", action="store_true",
                        help="keep the Voronoi faces as they are (default: cleaned, see voro3d.cleaning, then "
                        "fitted to the input mesh or the cloud's target surface, see voro3d.snapping)")
    if polygons:
        parser.add_argument("--polygons", type=output_path(*POLYGON_SUFFIXES),
                            help="also write the Voronoi faces as polygons, one per face, uncleaned "
                                 f"({' '.join(POLYGON_SUFFIXES)})")
    parser.add_argument("-q", "--quiet", action="store_true", help="no progress bar or messages")


def _version() -> str:
    from . import __version__

    return f"voro3d {__version__}"


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    try:
        with warnings.catch_warnings():
            # One line each, as the errors below: a user of the command needs what, not where in voro3d.
            warnings.showwarning = lambda message, category, *rest, **options: print(
                f"voro3d {args.command}: warning: {flag_names(str(message))}", file=sys.stderr)
            status = args.run(args)
    except (ValueError, MissingExtra, FileNotFoundError, IsADirectoryError, PermissionError) as error:
        print(f"voro3d {args.command}: error: {flag_names(str(error))}", file=sys.stderr)
        return 2
    except RuntimeError as error:  # a failed internal check or worker: say it in one line too
        print(f"voro3d {args.command}: failed: {flag_names(str(error))}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print(f"voro3d {args.command}: interrupted", file=sys.stderr)
        return 130
    return status if isinstance(status, int) else 0


if __name__ == "__main__":
    sys.exit(main())
