"""A column of air bubbles released together from near a tank's floor (scene: bubble_column.toml).

    python examples/bubble_column.py --device cpu --num-frames 12 --stage-path bubble_column.usdc
    warp-mpm-bubbles preview bubble_column.usdc
"""

import pathlib
import sys

from warp_mpm_bubbles.cli import run_example

if __name__ == "__main__":
    sys.exit(run_example(pathlib.Path(__file__).with_name("bubble_column.toml"), __doc__))
