"""3D dam break: a water column collapses and spreads along a tank (scene: dam_break.toml).

    python examples/dam_break.py --device cpu --num-frames 12 --stage-path dam_break.usdc

Open the .usdc in Blender (File > Import > Universal Scene Description), usdview or Omniverse.
"""

import argparse
import pathlib
import sys

from warp_mpm_bubbles import SceneError
from warp_mpm_bubbles.cli import add_run_overrides, scene_with_overrides

SCENE = pathlib.Path(__file__).with_name("dam_break.toml")


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    add_run_overrides(parser)
    args = parser.parse_args(argv)
    try:
        scene = scene_with_overrides(SCENE, args)
    except SceneError as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    from warp_mpm_bubbles import run_scene

    run_scene(scene, device=args.device, progress=not args.quiet)
    return 0


if __name__ == "__main__":
    sys.exit(main())
