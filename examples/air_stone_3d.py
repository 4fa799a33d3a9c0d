"""A bubble column, 3D: an air stone releasing a stream of bubbles that become foam at the surface (scene:
air_stone_3d.toml).

    python examples/air_stone_3d.py --device cpu --num-frames 12 --stage-path air_stone_3d.usdc
    warp-mpm-bubbles preview air_stone_3d.usdc
"""

import pathlib
import sys

from warp_mpm_bubbles.cli import run_example

if __name__ == "__main__":
    sys.exit(run_example(pathlib.Path(__file__).with_name("air_stone_3d.toml"), __doc__))
