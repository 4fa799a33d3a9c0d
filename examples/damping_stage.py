"""A stage from outside the package, the smallest real one (docs/new_effect.md walks through it):
linear drag that damps every face velocity at `rate` per second, u* <- u* exp(-rate dt), as a force
before the pressure solve. A scene turns it on with an [effects.damping] table:

    [effects.damping]
    rate = 2.0      # 1/s: velocities fall by e in half a second (without other forces)

Run as a script it simulates SCENE below, water sloshing in a tank, damped:

    python examples/damping_stage.py --device cpu --num-frames 12 --stage-path damped.usdc
"""

from __future__ import annotations

import math
import pathlib
import sys
from dataclasses import dataclass
from typing import ClassVar

import warp as wp

from warp_mpm_bubbles import Stage, register_stage


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

    def force(self, ctx, dt: float):
        factor = math.exp(-self.settings.rate * dt)
        for a in ctx.grid.axes:
            ctx.launch(scale_faces, ctx.grid.face_shape(a), [factor, ctx.fields.vel[a]])


SCENE = """
name = "damped_tank"
[domain]
size = [0.4, 0.2]
cell_size = 0.01
gravity = [0.0, -9.81]
[solver]
particles_per_cell = 4
[materials.water]
kind = "liquid"
[[shapes]]
type = "box"
material = "water"
min = [0.0, 0.0]
max = [0.15, 0.15]
[effects.damping]
rate = 2.0
[output]
path = "damped_tank.usdc"
fps = 30
frames = 24
"""

if __name__ == "__main__":
    import tempfile

    from warp_mpm_bubbles.cli import run_example

    # The scene file is written here (examples/*.toml are scenes every install can load; this one
    # needs the stage above registered first, which importing this module has just done).
    with tempfile.TemporaryDirectory() as tmp:
        scene_file = pathlib.Path(tmp) / "damped_tank.toml"
        scene_file.write_text(SCENE)
        sys.exit(run_example(scene_file, __doc__))
