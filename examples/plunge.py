"""A ball plunged into a pool: splash, cavity, entrained sub-grid bubbles and foam (scene: plunge.toml).

    python examples/plunge.py --device cpu --num-frames 12 --stage-path plunge.usdc
    warp-mpm-bubbles preview plunge.usdc
"""

import pathlib
import sys

from warp_mpm_bubbles.cli import run_example

if __name__ == "__main__":
    sys.exit(run_example(pathlib.Path(__file__).with_name("plunge.toml"), __doc__))
