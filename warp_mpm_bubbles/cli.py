"""Command line: `warp-mpm-bubbles run SCENE.toml` and `warp-mpm-bubbles check SCENE.toml`."""

from __future__ import annotations

import argparse
import sys

from .scene.quality import PRESETS
from .scene.model import SceneError, load_scene
from .io.wedge import add_wedge_arguments


def add_run_overrides(parser: argparse.ArgumentParser):
    """The flags every example and `run` share (Warp's and Newton's example convention)."""
    parser.add_argument("--device", default=None, help='Warp device, e.g. "cpu" or "cuda:0" (default: Warp\'s)')
    parser.add_argument("--num-frames", type=int, default=None, help="frames to simulate (overrides the scene)")
    parser.add_argument("--stage-path", default=None, help="output .usd/.usdc/.usda path (overrides the scene)")
    parser.add_argument("--quality", choices=tuple(PRESETS), default=None,
                        help="quality preset; replaces the scene's particles_per_cell, cfl, cg_tolerance and refine "
                             "(README: error and cost per preset)")
    parser.add_argument("--quiet", action="store_true", help="no progress bar or summary")
    parser.add_argument("--resume", action="store_true",
                        help="continue a killed run from its last checkpoint, keeping its frames")


def scene_with_overrides(path, args) -> "object":
    """Load and validate a scene, applying --quality, --stage-path and --num-frames; raises SceneError."""
    scene = load_scene(path)
    if args.quality is not None:
        scene = scene.with_quality(args.quality)
    if args.num_frames is not None or args.stage_path is not None:
        scene = scene.replace_output(path=args.stage_path, frames=args.num_frames)
    return scene.validate()


def run_example(scene_path, description: str, argv=None) -> int:
    """Body of every example script: the shared flags, then run the scene next to the script."""
    parser = argparse.ArgumentParser(description=description, formatter_class=argparse.RawDescriptionHelpFormatter)
    add_run_overrides(parser)
    args = parser.parse_args(argv)
    try:
        scene = scene_with_overrides(scene_path, args)
    except SceneError as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    return _run(scene, args)


def _run(scene, args) -> int:
    import warp as wp  # deferred: `check` and bad scenes never start Warp

    wp.config.quiet = True
    from .io.runner import run_scene
    from .core.simulation import SimulationError

    try:
        run_scene(scene, device=args.device, progress=not args.quiet, resume=args.resume)
    except SimulationError as err:
        print(f"error: {err}", file=sys.stderr)
        return 1
    return 0


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="warp-mpm-bubbles", description=__doc__)
    sub = parser.add_subparsers(dest="command", required=True)
    run_p = sub.add_parser("run", help="simulate a scene and write its USD animation")
    run_p.add_argument("scene", help="scene file (.toml)")
    add_run_overrides(run_p)
    check_p = sub.add_parser("check", help="validate a scene file without simulating")
    check_p.add_argument("scene", help="scene file (.toml)")
    preview_p = sub.add_parser("preview", help="render chosen frames of a written animation to a PNG")
    preview_p.add_argument("stage", help="a .usd/.usdc/.usda written by `run`")
    preview_p.add_argument("--frames", default=None, help="comma-separated frame numbers (default: four, spread)")
    preview_p.add_argument("--png", default=None, help="output image (default: next to the stage, .png)")
    wedge_p = sub.add_parser("wedge", help="run variations of a scene (a wedge) as Dask tasks, one output per member")
    add_wedge_arguments(wedge_p)
    args = parser.parse_args(argv)

    if args.command == "wedge":
        from .io.wedge import wedge_command

        return wedge_command(args)

    if args.command == "preview":
        from pathlib import Path

        from .io.preview import render_preview

        frames = [int(f) for f in args.frames.split(",")] if args.frames else None
        png = args.png or str(Path(args.stage).with_suffix(".png"))
        print(render_preview(args.stage, png, frames, title=Path(args.stage).stem))
        return 0
    try:
        if args.command == "check":
            return _check(args.scene)
        scene = scene_with_overrides(args.scene, args)
    except SceneError as err:
        print(f"error: {err}", file=sys.stderr)
        return 2

    return _run(scene, args)


def _check(path) -> int:
    from .core.seeding import seed_particles

    scene = load_scene(path).validate()
    seeds = seed_particles(scene)
    d = scene.domain
    print(f"{path}: OK")
    print(f"  {d.dim}D domain {' x '.join(f'{s:g}' for s in d.size)} m, cells {d.cells[:d.dim]}, dx {d.dx:g} m"
          + (f" (cell_size {d.cell_size:g} refined {d.refine}x, quality {scene.solver.quality})" if d.refine > 1 else ""))
    print(f"  materials: {', '.join(f'{m.name} ({m.kind}, {m.density:g} kg/m^3)' for m in scene.materials.values())}")
    print(f"  {len(scene.shapes)} shapes, {len(seeds['positions']):,} particles (before colliders carve them)"
          if scene.colliders else f"  {len(scene.shapes)} shapes, {len(seeds['positions']):,} particles")
    print(f"  effects: {', '.join(scene.effect_names) or 'none (liquid only)'}"
          + (f"; {len(scene.emitters)} emitters" if scene.emitters else "")
          + (f"; {len(scene.colliders)} colliders" if scene.colliders else ""))
    print(f"  output: {scene.output.path}, {scene.output.frames} frames at {scene.output.fps:g} fps ({scene.output.format})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
