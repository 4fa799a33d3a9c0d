"""One large air bubble rising in a water tank (scene: rising_bubble.toml), written as USD with
water and air prototypes.

    python examples/rising_bubble.py --device cpu --num-frames 12 --stage-path rising_bubble.usdc
    warp-mpm-bubbles preview rising_bubble.usdc --frames 0,4,8,12

Known limitation (issue #3): after about one diameter of rise the water under the bubble breaks
through it and some gas is lost; see the README's status.
"""

import pathlib
import sys

from warp_mpm_bubbles.cli import run_example

if __name__ == "__main__":
    sys.exit(run_example(pathlib.Path(__file__).with_name("rising_bubble.toml"), __doc__))
