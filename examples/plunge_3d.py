"""A ball plunged into a pool, 3D: splash, cavity, entrained sub-grid bubbles and foam (scene: plunge_3d.toml).

    python examples/plunge_3d.py --device cpu --num-frames 12 --stage-path plunge_3d.usdc
    warp-mpm-bubbles preview plunge_3d.usdc
"""

import pathlib
import sys

from warp_mpm_bubbles.cli import run_example

if __name__ == "__main__":
    sys.exit(run_example(pathlib.Path(__file__).with_name("plunge_3d.toml"), __doc__))
