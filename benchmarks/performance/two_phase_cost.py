"""What the gas and surface tension cost next to the liquid alone (the bar: the two-phase step costs
at most 1.5x the liquid-only step), at the same particle count.

    python -m benchmarks.performance.two_phase_cost                 # 32^3 grid, a 16^3-cell block
    python -m benchmarks.performance.two_phase_cost --grid 48 --steps 5
    python -m benchmarks.performance.two_phase_cost --quick         # 12^3 grid, 1 step, 1 round

Two scenes, the same N^3 closed box (free-slip) and the same centred block at 8 particles per cell:
"liquid": all water; "two-phase": a sphere of air (radius a quarter of the block) inside the water,
with surface tension 0.072 N/m. The sphere's cells are seeded with air instead of water, so the
particle counts match. Both are stepped with the same fixed dt (the smaller of their stable steps
at the start), so the cost per step compares like with like. Rounds alternate the order; medians
of ms per step and per stage (PhaseTimer). Writes benchmarks/results/two_phase_cost/<device>.{json,md}
(other grids: <device>_g<N>.{json,md}).
"""

from __future__ import annotations

import statistics
import sys
import tempfile
import time
from pathlib import Path

import warp as wp

from warp_mpm_bubbles import Box, Domain, Material, Output, Scene, Sphere
from warp_mpm_bubbles.core.simulation import Simulation

from benchmarks import harness


def scene(grid: int, two_phase: bool, out: str) -> Scene:
    dx = 1.0 / grid
    lo, hi = 0.25, 0.75
    water = Material("water", surface_tension=0.072 if two_phase else 0.0)
    materials = {"water": water}
    shapes = [Box("water", (lo,) * 3, (hi,) * 3)]
    if two_phase:
        materials["air"] = Material("air", kind="gas")
        shapes.append(Sphere("air", (0.5,) * 3, (hi - lo) / 4))
    return Scene(name="two_phase" if two_phase else "liquid",
                 domain=Domain(size=(1.0, 1.0, 1.0), cell_size=dx, walls="free_slip"),
                 materials=materials, shapes=shapes, output=Output(path=str(Path(out) / "x.usdc")))


def timed(sim: Simulation, dt: float, steps: int) -> tuple[float, dict]:
    sim.timer.seconds.clear()
    t0 = time.perf_counter()
    for _ in range(steps):
        sim.step(dt)
    wall = 1e3 * (time.perf_counter() - t0) / steps
    return wall, {k: 1e3 * v / steps for k, v in sim.timer.seconds.items()}


def main(argv=None):
    ap = harness.parser(__doc__.split("\n\n")[0], quick="a 12^3 grid, 1 timed step, 1 round")
    ap.add_argument("--grid", type=int, default=32, help="N for the N^3 grid (default 32)")
    ap.add_argument("--steps", type=int, default=5, help="timed steps per scene and round (default 5)")
    ap.add_argument("--rounds", type=int, default=3, help="alternating rounds (default 3)")
    args = ap.parse_args(argv)
    if args.quick:
        args.grid, args.steps, args.rounds = 12, 1, 1
    if args.grid != 32 and args.label is None:  # 32: the default's file
        args.label = f"g{args.grid}"
    if args.grid < 8 or args.steps < 1 or args.rounds < 1:
        ap.error("--grid must be >= 8, --steps and --rounds >= 1")
    wp.config.quiet = True
    out = tempfile.mkdtemp()
    sims = {name: Simulation(scene(args.grid, name == "two_phase", out), args.device) for name in ("liquid", "two_phase")}
    counts = {name: sim.num_particles for name, sim in sims.items()}
    dt = min(sim.stable_dt() for sim in sims.values())
    for sim in sims.values():  # compile / cache load, untimed
        sim.step(dt)
    per_step = {name: [] for name in sims}
    stages = {name: [] for name in sims}
    for r in range(args.rounds):
        order = list(sims) if r % 2 == 0 else list(reversed(sims))
        for name in order:
            wall, st = timed(sims[name], dt, args.steps)
            per_step[name].append(wall)
            stages[name].append(st)
            print(f"round {r + 1}: {name} {wall:.1f} ms/step")
    med = {name: statistics.median(v) for name, v in per_step.items()}
    ratio = med["two_phase"] / med["liquid"]
    stage_med = {name: {k: statistics.median(s.get(k, 0.0) for s in stages[name]) for k in stages[name][0]}
                 for name in sims}
    result = {"grid": args.grid, "dt": dt, "particles": counts,
              "ms_per_step": med, "ratio": ratio, "stages_ms": stage_med, "rounds": per_step}
    lines = [f"{args.grid}^3 grid, particles {counts}, fixed dt {dt:.3g} s, medians over {args.rounds} rounds.", "",
             "| scene | ms / step | " + " | ".join(stage_med["two_phase"]) + " |",
             "|---|---:|" + "---:|" * len(stage_med["two_phase"])]
    for name in sims:
        lines.append(f"| {name} | {med[name]:.1f} | "
                     + " | ".join(f"{stage_med[name].get(k, 0.0):.1f}" for k in stage_med["two_phase"]) + " |")
    lines += ["", f"two-phase / liquid: **{ratio:.2f}x** per step (the bar: 1.5x)."]
    print("\n".join(lines))
    harness.write_result("two_phase_cost", args, result, "\n".join(lines),
                         title=f"Two-phase step against liquid only ({harness.describe_device(args.device)})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
