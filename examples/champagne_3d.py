"""A glass of champagne, 3D: nucleation sites on the glass stream tiny bubbles of several sizes that rise
and gather at the surface as foam (scene: champagne_3d.toml).

    python examples/champagne_3d.py --device cpu --num-frames 12 --stage-path champagne_3d.usdc
    warp-mpm-bubbles preview champagne_3d.usdc
"""

import pathlib
import sys

from warp_mpm_bubbles.cli import run_example

if __name__ == "__main__":
    sys.exit(run_example(pathlib.Path(__file__).with_name("champagne_3d.toml"), __doc__))
