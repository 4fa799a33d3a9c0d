"""A stage from outside the package, the smallest real one (docs/new_effect.md walks through it):
linear drag that damps every face velocity at `rate` per second, u* <- u* exp(-rate dt), as a force
before the pressure solve. A scene turns it on with an [effects.damping] table:

    [effects.damping]
    rate = 2.0      # 1/s: velocities fall by e in half a second (without other forces)

    python examples/damping_stage.py --device cpu --num-frames 12 --stage-path damped.usdc
"""

from __future__ import annotations

import math
import pathlib
import sys
from dataclasses import dataclass
from typing import ClassVar

import warp as wp

from warp_mpm_bubbles.core.stage import Stage, register_stage


@dataclass
class Damping:
    """[effects.damping]: its keys, with their checks (one SceneError naming key and fix)."""

    rate: float = 1.0  # 1/s
    key: ClassVar[str] = "damping"

    def _validate(self, c, table, scene):
        self.rate = c.number(f"{table}.rate", self.rate, ge=0)


@wp.kernel(enable_backward=False)
def scale_faces(factor: float, vel: wp.array3d(dtype=float)):
    i, j, k = wp.tid()
    vel[i, j, k] = factor * vel[i, j, k]


@register_stage
class DampingStage(Stage):
    name = "damping"
    Settings = Damping

    def force(self, sim, dt: float):
        factor = math.exp(-self.settings.rate * dt)
        for a in sim.grid.axes:
            sim.launch(scale_faces, sim.grid.face_shape(a), [factor, sim.fields.vel[a]])


if __name__ == "__main__":
    from warp_mpm_bubbles.cli import run_example

    sys.exit(run_example(pathlib.Path(__file__).with_name("damped_tank.toml"), __doc__))
