"""Command line: `warp-mpm-bubbles run SCENE.toml`, `check SCENE.toml`, `preview OUT.usdc`, `blender OUT.usdc`.

Exit codes: 0 done; 1 the simulation stopped (a NaN, a frame needing too many steps); 2 bad input
(a scene, an argument, a device or memory this machine lacks, a --resume that would mix settings);
3 a bug (an unexpected exception: one line saying so and where to report it;
WARP_MPM_BUBBLES_DEBUG=1 prints the traceback); 130 interrupted. A closed stdout or stderr
(`| head`) changes neither: `run` also writes its summary or error to <stem>_frames/run.log.
"""

from __future__ import annotations

import argparse
import io
import os
import sys
import traceback

from .scene.limits import MAX_FRAMES, check_colliders_leave_fluid, check_memory
from .scene.quality import PRESETS
from .scene.model import SceneError, load_scene
from .io.paths import output_path_problem
from .io.streams import guarded_std_streams
from .io.wedge import add_wedge_arguments
from .validate import add_validate_arguments

DEBUG_ENV = "WARP_MPM_BUBBLES_DEBUG"
REPORT_TO = "the warp_mpm_bubbles issue tracker (the project's GitHub issues)"


def num_frames(text: str) -> int:
    """--num-frames: a whole number from 1 to MAX_FRAMES (argparse turns the ValueError into exit 2)."""
    t = text.strip()
    if not (t.isascii() and t.isdigit()) or len(t) > 30:
        raise argparse.ArgumentTypeError(f"{text!r} is not a whole number of frames; give 1 to {int(MAX_FRAMES):,}")
    n = int(t)
    if not 1 <= n <= MAX_FRAMES:
        raise argparse.ArgumentTypeError(f"{text} frames: give 1 to {int(MAX_FRAMES):,} ({MAX_FRAMES.why})")
    return n


def device_name(text: str) -> str:
    if not text.strip() or len(text) > 64:
        raise argparse.ArgumentTypeError(f"{text!r}: give a Warp device name such as cpu or cuda:0")
    return text.strip()


def add_run_overrides(parser: argparse.ArgumentParser):
    """The flags every example and `run` share (Warp's and Newton's example convention)."""
    parser.add_argument("--device", type=device_name, default=None,
                        help='Warp device, e.g. "cpu" or "cuda:0" (default: Warp\'s: the first GPU if any)')
    parser.add_argument("--num-frames", type=num_frames, default=None,
                        help=f"frames to simulate after the initial one, 1 to {int(MAX_FRAMES):,} (overrides the "
                             f"scene; writes N+1 samples)")
    parser.add_argument("--stage-path", default=None, help="output .usd/.usdc/.usda path (overrides the scene)")
    parser.add_argument("--quality", choices=tuple(PRESETS), default=None,
                        help="quality preset; replaces the scene's particles_per_cell, cfl, cg_tolerance and refine "
                             "(docs/physics.md: error and cost per preset)")
    talk = parser.add_mutually_exclusive_group()
    talk.add_argument("--quiet", action="store_true",
                      help="print nothing but errors (the summary still goes to <stem>_frames/run.log)")
    talk.add_argument("--verbose", action="store_true",
                      help="also show Warp's own messages: its banner, the CUDA driver warning, each module load")
    parser.add_argument("--resume", action="store_true",
                        help="continue a killed run from its last checkpoint, keeping its frames")
    parser.add_argument("--overwrite", action="store_true",
                        help="replace an existing output (only files this project wrote are deleted)")
    parser.add_argument("--surface", action="store_true",
                        help="also write the liquid's surface mesh per frame (sets [output].surface = true)")


def scene_with_overrides(path, args) -> "object":
    """Load and validate a scene, applying --quality, --stage-path and --num-frames; raises SceneError."""
    scene = load_scene(path)
    if args.quality is not None:
        scene = scene.with_quality(args.quality)
    if getattr(args, "surface", False):
        scene.output.surface = True
    too_long = output_path_problem(args.stage_path) if args.stage_path is not None else None
    if too_long:  # named as the user gave it, not as the [output].path it replaces
        raise SceneError(f"--stage-path {args.stage_path!r}: {too_long}", "--stage-path", args.stage_path, too_long)
    if args.num_frames is not None or args.stage_path is not None:
        scene = scene.replace_output(path=args.stage_path, frames=args.num_frames)
    return scene.validate()


def run_example(scene_path, description: str, argv=None) -> int:
    """Body of every example script: the shared flags, then run the scene next to the script."""
    parser = argparse.ArgumentParser(description=description, formatter_class=argparse.RawDescriptionHelpFormatter)
    add_run_overrides(parser)

    def body():
        try:
            scene = scene_with_overrides(scene_path, args)
        except SceneError as err:
            print(f"error: {err}", file=sys.stderr)
            return 2
        return _run(scene, args)

    with guarded_std_streams():
        args = parser.parse_args(argv)
        return guarded(body)


def guarded(body) -> int:
    """Run body(); an exception nobody expected is a bug: say so in one line, where to report it,
    exit 3 (the traceback with WARP_MPM_BUBBLES_DEBUG=1). Ctrl-C: exit 130."""
    try:
        return body()
    except KeyboardInterrupt:
        print("interrupted; a run's finished frames are kept: --resume continues it", file=sys.stderr)
        return 130
    except Exception as err:  # noqa: BLE001 (the point: no traceback for a user)
        if os.environ.get(DEBUG_ENV, "") not in ("", "0"):
            traceback.print_exc()
        detail = " ".join(str(err).split())[:300]
        print(f"internal error (a bug in warp_mpm_bubbles, not in your input): {type(err).__name__}: {detail}. "
              f"Please report it on {REPORT_TO} with the command and the scene file; set {DEBUG_ENV}=1 to "
              f"print the traceback.", file=sys.stderr)
        return 3


def start_warp(verbose: bool = False, quiet: bool = False) -> None:
    """Import and initialise Warp (deferred: `check` and bad scenes never start it), showing its own
    messages only when verbose: its banner and "Module ... load took ... ms" lines (Warp's log
    level; quiet keeps only its errors) and the CUDA driver warning, which Warp's native library
    prints straight to the stderr descriptor while it initialises: that descriptor is silenced
    then, while what Warp's Python side writes (a warning its log level lets through) is kept."""
    import warp as wp

    wp.config.log_level = wp.LOG_INFO if verbose else (wp.LOG_ERROR if quiet else wp.LOG_WARNING)
    if verbose:
        wp.init()
        return
    sys.stderr.flush()
    try:
        saved, devnull = os.dup(2), os.open(os.devnull, os.O_WRONLY)
    except OSError:  # no stderr descriptor at all: nothing to silence
        wp.init()
        return
    stream, sys.stderr = sys.stderr, io.StringIO()
    try:
        os.dup2(devnull, 2)
        wp.init()  # raises, with its message, if Warp cannot start
    finally:
        os.dup2(saved, 2)
        os.close(saved)
        os.close(devnull)
        kept, sys.stderr = sys.stderr.getvalue(), stream
        sys.stderr.write(kept)


def _run(scene, args) -> int:
    start_warp(verbose=getattr(args, "verbose", False), quiet=args.quiet)
    from .io.runner import run_scene
    from .core.simulation import SimulationError

    try:  # run_scene claims the output, then checks the device and the memory, before any work
        run_scene(scene, device=args.device, progress=not args.quiet, resume=args.resume,
                  overwrite=args.overwrite)
    except SceneError as err:  # refused before the run (the memory the scene needs)
        print(f"error: {err}", file=sys.stderr)
        return 2
    except SimulationError as err:
        print(f"error: {err}", file=sys.stderr)
        return getattr(err, "exit_code", 1)  # 2: refused before any work (output, device); 1: the run stopped
    return 0


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="warp-mpm-bubbles", description=__doc__)
    sub = parser.add_subparsers(dest="command", required=True)
    run_p = sub.add_parser("run", help="simulate a scene and write its USD animation")
    run_p.add_argument("scene", help="scene file (.toml)")
    add_run_overrides(run_p)
    check_p = sub.add_parser("check", help="validate a scene file without simulating")
    check_p.add_argument("scene", help="scene file (.toml)")
    check_p.add_argument("--device", type=device_name, default=None,
                         help="check the scene fits this device (default: a CPU run, all arrays in host memory)")
    preview_p = sub.add_parser("preview", help="render chosen frames of a written animation to a PNG")
    preview_p.add_argument("stage", help="a .usd/.usdc/.usda written by `run`")
    preview_p.add_argument("--frames", default=None, help="comma-separated frame numbers (default: four, spread)")
    preview_p.add_argument("--png", default=None, help="output image (default: next to the stage, .png)")
    _add_blender_parser(sub)
    wedge_p = sub.add_parser("wedge", help="run variations of a scene (a wedge) as Dask tasks, one output per member")
    add_wedge_arguments(wedge_p)
    validate_p = sub.add_parser("validate", help="run the validation cases against their references and print a "
                                                 "table; exit 1 if any fails")
    add_validate_arguments(validate_p)
    with guarded_std_streams():  # `--help | head` too
        args = parser.parse_args(argv)
        return guarded(lambda: _main(args))


def _main(args) -> int:
    if args.command == "blender":
        return _blender(args)
    if args.command == "wedge":
        from .io.wedge import wedge_command

        return wedge_command(args)
    if args.command == "preview":
        return _preview(args)
    if args.command == "validate":
        from .validate import validate_command

        return validate_command(args)
    try:
        if args.command == "check":
            return _check(args.scene, args.device)
        scene = scene_with_overrides(args.scene, args)
    except SceneError as err:
        print(f"error: {err}", file=sys.stderr)
        return 2

    return _run(scene, args)


def _add_blender_parser(sub):
    blender_p = sub.add_parser("blender", help="open a written animation in Blender (needs bpy) and save a .blend "
                                              "with fps, frame range, materials, a camera and a light; "
                                              "--render FRAME also renders one frame to a PNG")
    blender_p.add_argument("stage", help="a .usd/.usdc/.usda written by `run`")
    blender_p.add_argument("--blend", default=None, help="output .blend (default: next to the stage)")
    blender_p.add_argument("--render", type=frame_number, default=None, metavar="FRAME",
                           help="also render this frame with Cycles on the CPU to a PNG (a quick look: a few samples)")
    blender_p.add_argument("--png", default=None, help="the rendered frame's path (default: next to the stage, "
                                                       "<stem>_<FRAME>.png)")
    blender_p.add_argument("--samples", type=render_samples, default=16,
                           help="Cycles samples per pixel for --render, 1 to 4096 (default 16)")


def frame_number(text: str) -> int:
    t = text.strip()
    if not (t.isascii() and t.isdigit()) or len(t) > 9:
        raise argparse.ArgumentTypeError(f"{text!r} is not a frame number; give a whole number such as 0 or 12")
    return int(t)


def render_samples(text: str) -> int:
    t = text.strip()
    if not (t.isascii() and t.isdigit()) or len(t) > 9 or not 1 <= int(t) <= 4096:
        raise argparse.ArgumentTypeError(f"{text!r}: give a whole number of samples from 1 to 4096")
    return int(t)


def _blender(args) -> int:
    from .io.blender import BlenderInputError, BlenderUnavailable, open_in_blender

    try:
        done = open_in_blender(args.stage, args.blend, render=args.render, png=args.png, samples=args.samples)
    except (BlenderUnavailable, BlenderInputError, FileNotFoundError, OSError) as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    print(f"{done['blend']}: {done['fps']:g} fps, frames {done['frames'][0]}-{done['frames'][1]}, "
          f"{len(done['objects'])} objects" + (f"; hidden (the surface stands for them): {', '.join(done['hidden'])}"
                                                if done["hidden"] else ""))
    if "png" in done:
        print(f"{done['png']}: frame {args.render}, Cycles on the CPU, {args.samples} samples")
    return 0


def _preview(args) -> int:
    from pathlib import Path

    from .io.preview import PreviewError, parse_frames, render_preview

    try:
        frames = parse_frames(args.frames)
        if not Path(args.stage).name:
            raise PreviewError(f"{args.stage!r}: give the .usdc (.usd, .usda) file that `run` wrote")
        png = args.png or str(Path(args.stage).with_suffix(".png"))
        print(render_preview(args.stage, png, frames, title=Path(args.stage).stem))
    except PreviewError as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    return 0


def _check(path, device=None) -> int:
    from .core.seeding import seed_particles

    scene = load_scene(path).validate()
    if device is not None:  # the GPU's memory too; Warp starts only for this
        start_warp()
        from .core.simulation import SimulationError
        from .io.devices import check_memory as check_device_memory

        try:
            estimate = check_device_memory(scene, device)
        except SimulationError as err:
            print(f"error: {err}", file=sys.stderr)
            return 2
    else:
        estimate = check_memory(scene)  # before seeding: a scene too big for the host is refused here
    seeds = seed_particles(scene)
    check_colliders_leave_fluid(scene, seeds["positions"])
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
    o = scene.output
    print(f"  output: {o.path}, {o.frames} frames at {o.fps:g} fps ({o.format})"
          + (f"; surface mesh, {o.surface_resolution}x finer grid, smoothing {o.surface_smoothing:g} cells"
             if o.surface else ""))
    print(f"  memory: about {(estimate['particles'] + estimate['grid']) / 1e9:.2g} GB on the device "
          f"(particles {estimate['particles'] / 1e9:.2g}, grid {estimate['grid'] / 1e9:.2g}), "
          f"{estimate['host'] / 1e9:.2g} GB more on the host while seeding")
    return 0


if __name__ == "__main__":
    sys.exit(main())
