"""An air stone releasing a stream of bubbles that become foam at the surface (scene: air_stone.toml).

    python examples/air_stone.py --device cpu --num-frames 12 --stage-path air_stone.usdc
    warp-mpm-bubbles preview air_stone.usdc
"""

import pathlib
import sys

from warp_mpm_bubbles.cli import run_example

if __name__ == "__main__":
    sys.exit(run_example(pathlib.Path(__file__).with_name("air_stone.toml"), __doc__))
