"""One large air bubble rising in a water tank (scene: rising_bubble.toml), written as USD with
water and air prototypes.

    python examples/rising_bubble.py --device cpu --num-frames 12 --stage-path rising_bubble.usdc
    warp-mpm-bubbles preview rising_bubble.usdc --frames 0,4,8,12

Known limitation (issue #3): the bubble's skirt sheds small gas pockets into the water (about 4%
of the gas in 0.5 s); see docs/physics.md, Bubbles.
"""

import pathlib
import sys

from warp_mpm_bubbles.cli import run_example

if __name__ == "__main__":
    sys.exit(run_example(pathlib.Path(__file__).with_name("rising_bubble.toml"), __doc__))
