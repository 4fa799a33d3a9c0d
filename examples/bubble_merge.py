"""Two air bubbles merging: the lower one catches the upper one in its wake (scene: bubble_merge.toml).

    python examples/bubble_merge.py --device cpu --num-frames 12 --stage-path bubble_merge.usdc
    warp-mpm-bubbles preview bubble_merge.usdc
"""

import pathlib
import sys

from warp_mpm_bubbles.cli import run_example

if __name__ == "__main__":
    sys.exit(run_example(pathlib.Path(__file__).with_name("bubble_merge.toml"), __doc__))
