"""Voids per frame of examples/pour_glass.toml (diagnostics.void_cells): at the frame's end and the most
over the frame's steps; and, apart, the bubble gaps (particle-free cells beside the compressible air,
connected to a gas region: VoidPass.gap_mask); and the fastest particle of each phase (liquid, gas,
foam, sub-grid bubble) over each frame's steps: a pour's stream moves at a few m/s, so a particle far
faster than that is a defect. Prints them and writes benchmarks/results/pour_voids/<device>.{json,md}
(another --scene: <device>_<scene name>.*).

    python -m benchmarks.validation.pour_voids --frames 90      # the whole example, 3-8 min on 2 CPU cores
    python -m benchmarks.validation.pour_voids --quick          # 2 frames

Measured 2026-12-02: before the void pass (b8f0711) 22 of 30 frames had void cells at
their end, at most 146, 1,192 in all; after it 7 frames, at most 7, 17 in all, all of them gaps
beside the air. 2026-12-04, voids and gaps apart, 90 frames: no void at any frame's end; within a
frame at most 61 (a trapped pocket's one step before its gas), in 13 frames; gaps at most 66 cells.
2026-12-05, at e72e2a6 (a pocket still EMPTY for its first step): voids within 21 of the first 87
frames, at most 1,045 cells at one step (frame 83; 61 in the first 30 frames), gaps up to 1,708
cells, and the run diverged at frame 88. Trapped air made gas in the step it is found (the step
splats again): no void at any step of the 90 frames; gaps at most 96 cells (68 in the first 30),
2,216 in all (the per-frame maxima summed). docs/design.md, #voids. Then, with the sub-grid drag's
reaction spread by mass and capped (effects/subgrid.py; the run differs from frame 9 on): no void
at any step; gaps at most 164 cells, 3,676 in all; fastest particles over the run liquid 3.5 m/s,
foam 6.8, sub-grid bubbles 18.0 (8.7 km/s before the cap), gas 241.5 (over 20 m/s in 23 frames: a
lone gas particle among empty cells, its cell's whole volume change on a sliver of gas). With a gas
cell's compressibility the gas's share of the cell (docs/design.md, #gas-system; 89 s): no void at
any step; fastest liquid 2.6 m/s, gas 4.2, foam 2.1, sub-grid 2.0; gaps at most 314 cells, 5,291 in all.
"""

import pathlib
import tempfile
import time

import numpy as np
import warp as wp

from warp_mpm_bubbles.core.grid import PHASE_FOAM, PHASE_GAS, PHASE_LIQUID, PHASE_SUBGRID
from warp_mpm_bubbles.core.simulation import Simulation
from warp_mpm_bubbles.diagnostics import gap_cells, void_cells
from warp_mpm_bubbles.scene.model import load_scene

from benchmarks import harness

PHASES = {"liquid": PHASE_LIQUID, "gas": PHASE_GAS, "foam": PHASE_FOAM, "subgrid": PHASE_SUBGRID}
DEFAULT_SCENE = "examples/pour_glass.toml"


class FrameWatch:
    """The most void and gap cells and the fastest particle of each phase over one frame's steps."""

    def __init__(self, sim):
        self.sim = sim
        self.reset()

    def reset(self):
        self.voids = self.gaps = 0
        self.fastest = dict.fromkeys(PHASES, 0.0)  # m/s

    def voids_now(self) -> int:
        sim = self.sim
        return void_cells(sim.fields.types.numpy(), sim.grid.ghost, sim.up, sim.voids.gap_mask())

    def on_step(self, dt, remaining):
        sim = self.sim
        self.voids = max(self.voids, self.voids_now())
        self.gaps = max(self.gaps, gap_cells(sim))
        n = sim.particles.count
        active = sim.particles.numpy("active")[:n] == 1
        phase = sim.particles.numpy("phase")[:n]
        speed = np.linalg.norm(sim.particles.numpy("v")[:n], axis=1)
        for name, code in PHASES.items():
            chosen = active & (phase == code)
            if chosen.any():
                self.fastest[name] = max(self.fastest[name], float(speed[chosen].max()))


def main(argv=None) -> int:
    ap = harness.parser(__doc__.split("\n")[0], quick="2 frames")
    ap.add_argument("--frames", type=int, default=30)
    ap.add_argument("--scene", default=DEFAULT_SCENE, help=f"a scene file (default {DEFAULT_SCENE})")
    a = ap.parse_args(argv)
    if a.quick:
        a.frames = 2
    if a.scene != DEFAULT_SCENE and a.label is None:
        a.label = pathlib.Path(a.scene).stem
    wp.config.quiet = True
    path = pathlib.Path(a.scene)
    scene = load_scene(path if path.is_absolute() or path.exists() else harness.ROOT / path)
    scene = scene.replace_output(path=pathlib.Path(tempfile.mkdtemp()) / "pour.usdc", frames=a.frames)
    sim = Simulation(scene, a.device)
    watch = FrameWatch(sim)
    t0 = time.perf_counter()
    ends, maxes, gaps, speeds = [], [], [], {name: [] for name in PHASES}
    for _ in range(a.frames):
        watch.reset()
        sim.advance_frame(on_step=watch.on_step)
        ends.append(watch.voids_now())
        maxes.append(watch.voids)
        gaps.append(watch.gaps)
        for name in PHASES:
            speeds[name].append(round(watch.fastest[name], 3))
        print(f"frame {sim.frame}: voids at end {ends[-1]}, most in frame {maxes[-1]}, bubble gaps most {gaps[-1]}, "
              f"fastest (m/s) " + ", ".join(f"{name} {watch.fastest[name]:.2f}" for name in PHASES)
              + f" ({time.perf_counter() - t0:.0f}s)", flush=True)
    print("end-of-frame:", ends)
    print("max-in-frame:", maxes)
    print("gap cells, most in frame:", gaps)
    print(f"frames with voids {sum(e > 0 for e in maxes)}/{a.frames}, largest {max(maxes)}, sum of frame ends {sum(ends)}")
    print("fastest over the run (m/s): " + ", ".join(f"{name} {max(v):.2f}" for name, v in speeds.items()))
    table = harness.markdown_table(
        ["frames", "frames with voids", "most voids at a step", "voids at frame ends, summed", "most gap cells",
         *(f"fastest {name} (m/s)" for name in PHASES)],
        [[a.frames, sum(e > 0 for e in maxes), max(maxes), sum(ends), max(gaps),
          *(f"{max(v):.2f}" for v in speeds.values())]])
    harness.write_result("pour_voids", a, {"scene": a.scene, "frames": a.frames, "voids_at_frame_end": ends,
                                           "voids_most_in_frame": maxes, "gaps_most_in_frame": gaps,
                                           "fastest_in_frame_m_s": speeds,
                                           "seconds": round(time.perf_counter() - t0, 1)},
                         table, title=f"Voids per frame of {a.scene}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
