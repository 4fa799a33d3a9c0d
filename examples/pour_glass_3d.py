"""The 3D flagship: water poured into a glass, with entrained bubbles and foam (scene: pour_glass_3d.toml).

    python examples/pour_glass_3d.py --device cpu --num-frames 6 --stage-path pour_glass_3d.usdc
    warp-mpm-bubbles preview pour_glass_3d.usdc
"""

import pathlib
import sys

from warp_mpm_bubbles.cli import run_example

if __name__ == "__main__":
    sys.exit(run_example(pathlib.Path(__file__).with_name("pour_glass_3d.toml"), __doc__))
