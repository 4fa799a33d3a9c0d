"""3D dam break: a water column collapses and spreads along a tank (scene: dam_break.toml).

    python examples/dam_break.py --device cpu --num-frames 12 --stage-path dam_break.usdc

Open the .usdc in Blender (File > Import > Universal Scene Description), usdview or Omniverse;
keep it next to its dam_break_frames/ folder, which holds one layer per frame.
"""

import pathlib
import sys

from warp_mpm_bubbles.cli import run_example

if __name__ == "__main__":
    sys.exit(run_example(pathlib.Path(__file__).with_name("dam_break.toml"), __doc__))
