"""Water poured into a glass: entrained bubbles rise and foam gathers on top (scene: pour_glass.toml).

    python examples/pour_glass.py --device cpu --num-frames 12 --stage-path pour_glass.usdc
    warp-mpm-bubbles preview pour_glass.usdc
"""

import pathlib
import sys

from warp_mpm_bubbles.cli import run_example

if __name__ == "__main__":
    sys.exit(run_example(pathlib.Path(__file__).with_name("pour_glass.toml"), __doc__))
