"""A beer poured into a glass, 3D: the pour builds a foam head that then drains and collapses (scene:
beer_3d.toml).

    python examples/beer_3d.py --device cpu --num-frames 12 --stage-path beer_3d.usdc
    warp-mpm-bubbles preview beer_3d.usdc
"""

import pathlib
import sys

from warp_mpm_bubbles.cli import run_example

if __name__ == "__main__":
    sys.exit(run_example(pathlib.Path(__file__).with_name("beer_3d.toml"), __doc__))
