"""Voids per frame of examples/pour_glass.py (diagnostics.void_cells): at the frame's end and the most
over the frame's steps.

    python benchmarks/pour_voids.py --frames 30

Measured 2026-12-02 (issue #12): before the void pass (b8f0711) 22 of 30 frames had void cells at
their end, at most 146, 1,192 in all; after it 7 frames, at most 7, 17 in all (voids beside the
compressible air keep the old rule: docs/design.md, #voids).
"""
import argparse
import pathlib
import tempfile
import time

import warp as wp

from warp_mpm_bubbles.core.simulation import Simulation
from warp_mpm_bubbles.diagnostics import void_cells
from warp_mpm_bubbles.scene.model import load_scene

ap = argparse.ArgumentParser()
ap.add_argument("--frames", type=int, default=30)
ap.add_argument("--scene", default="examples/pour_glass.toml")
a = ap.parse_args()
wp.config.quiet = True
scene = load_scene(pathlib.Path(a.scene)).replace_output(path=pathlib.Path(tempfile.mkdtemp()) / "pour.usdc", frames=a.frames)
sim = Simulation(scene, "cpu")
worst = [0]


def on_step(dt, remaining):
    worst[0] = max(worst[0], void_cells(sim.fields.types.numpy(), sim.grid.ghost, sim.up))


t0 = time.perf_counter()
ends, maxes = [], []
for f in range(a.frames):
    worst[0] = 0
    sim.advance_frame(on_step=on_step)
    ends.append(void_cells(sim.fields.types.numpy(), sim.grid.ghost, sim.up))
    maxes.append(worst[0])
    print(f"frame {sim.frame}: voids at end {ends[-1]}, most in frame {maxes[-1]} ({time.perf_counter() - t0:.0f}s)",
          flush=True)
print("end-of-frame:", ends)
print("max-in-frame:", maxes)
print(f"frames with voids {sum(e > 0 for e in maxes)}/{a.frames}, largest {max(maxes)}, sum of frame ends {sum(ends)}")
