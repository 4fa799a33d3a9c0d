"""The Laplace jump of a resting bubble in a filled tank, per resolution (the rising bubble's 2D drift).

    python -m benchmarks.validation.static_bubble_laplace          # 5 / 10 / 20 / 40 cells per radius: about 4 min on 2 cores
    python -m benchmarks.validation.static_bubble_laplace --resolutions 20,40,80 --t-end 0.3
    python -m benchmarks.validation.static_bubble_laplace --quick  # 20 cells across, to t = 0.1 s

Hysing's test case 1 fluids (benchmarks/validation/convergence.py's hysing_2d, the same scaling by 10: liquid
rho 100, mu 1; incompressible gas rho 10, mu 0.1; sigma 2.45) with no gravity: a disc of radius 0.25
at rest in a 1 x 1 tank, no-slip walls, to t = 1.2 s (the capillary time sqrt(rho R^3 / sigma) is
0.8 s; the jump still swings by 0.5-1% between 0.2 and 0.3 s, so the settled value is the mean over
the second half of the run). Sampled every 0.05 s: the pressure jump, the mean pressure inside
(r < R - 2 dx) minus that outside (R + 2 dx < r < 0.45), over sigma / R, and the fastest particle
(the spurious currents). The jump's error should shrink with the grid; the rising
bubble's late drift (docs/convergence.md) is the reason to look. Writes
benchmarks/results/static_bubble_laplace/<device>.{json,md}. A measurement, not a test.
"""

from __future__ import annotations

import argparse
import tempfile
import time

import numpy as np

from warp_mpm_bubbles import Box, Domain, Material, Output, Scene, SolverSettings, Sphere
from warp_mpm_bubbles.core.simulation import Simulation

from benchmarks import harness

SCALE, R, SAMPLE_EVERY = 0.1, 0.25, 0.05
SIGMA = 24.5 * SCALE


def run(cells_across: int, device: str, t_end: float) -> dict:
    fluids = {"liquid": Material("liquid", density=1000 * SCALE, viscosity=10 * SCALE, surface_tension=SIGMA),
              "bubble": Material("bubble", kind="gas", density=100 * SCALE, viscosity=1 * SCALE, eos="incompressible")}
    with tempfile.TemporaryDirectory() as tmp:
        scene = Scene(domain=Domain(size=(1.0, 1.0), cell_size=1.0 / cells_across, walls="no_slip", gravity=(0.0, 0.0)),
                      materials=fluids, shapes=[Box("liquid", (0.0, 0.0), (1.0, 1.0)), Sphere("bubble", (0.5, 0.5), R)],
                      solver=SolverSettings(), output=Output(path=f"{tmp}/s.usdc"), name="static_bubble")
        sim = Simulation(scene, device)
        start, jumps, speeds = time.perf_counter(), [], []
        samples = max(2, round(t_end / SAMPLE_EVERY))
        for k in range(1, samples + 1):
            sim.advance_to(t_end * k / samples)
            centres = sim.grid.cell_centres()[sim.grid.interior_slice()][:, :, 0, :2]
            r = np.linalg.norm(centres - 0.5, axis=-1)
            p, dx = sim.pressure_numpy()[:, :, 0], sim.grid.dx
            jump = p[r < R - 2 * dx].mean() - p[(r > R + 2 * dx) & (r < 0.45)].mean()
            jumps.append(float(jump / (SIGMA / R) - 1.0))
            speeds.append(float(np.linalg.norm(sim.particles_numpy()["velocities"], axis=1).max()))
        return {"cells_across": cells_across, "cells_per_radius": cells_across * R, "steps": sim.stats.steps,
                "wall_s": time.perf_counter() - start, "jump_error": jumps, "max_speed": speeds,
                "t_end": t_end,  # the settled jump: the mean over the last half of the run, after the start-up
                "jump_error_settled": float(np.mean(jumps[samples // 2:])),
                "jump_error_spread": float(np.std(jumps[samples // 2:]))}


def cells_list(text: str) -> list[int]:
    try:
        values = [int(v) for v in text.split(",")]
    except ValueError:
        values = []
    if not values or min(values) < 8:
        raise argparse.ArgumentTypeError(f"{text!r}: expected whole numbers >= 8 separated by commas, e.g. 20,40,80")
    return values


def main(argv=None) -> int:
    ap = harness.parser(__doc__.split("\n")[0], quick="20 cells across the tank, to t = 0.1 s")
    ap.add_argument("--resolutions", default="20,40,80,160", type=cells_list,
                    help="cells across the tank, comma-separated whole numbers >= 8 (4x the cells per radius)")
    ap.add_argument("--t-end", type=float, default=1.2, help="simulated seconds (default 1.2; the settled jump is the mean of the second half)")
    args = ap.parse_args(argv)
    if args.quick:
        args.resolutions, args.t_end = [20], 0.1
    rows = []
    for n in args.resolutions:
        rows.append(run(n, args.device, args.t_end))
        row = rows[-1]
        print(f"{row['cells_per_radius']:g} cells per radius: jump error {100 * row['jump_error_settled']:+.2f}% "
              f"(std {100 * row['jump_error_spread']:.2f} over t >= {args.t_end / 2:g} s), "
              f"fastest particle {max(row['max_speed']):.4f} m/s, {row['steps']} steps, {row['wall_s']:.0f} s", flush=True)
    lines = [f"| cells per radius | jump error, settled (mean of t = {args.t_end / 2:g}-{args.t_end:g} s) | its std | fastest particle, m/s | steps |",
             "|---:|---:|---:|---:|---:|"]
    lines += [f"| {r['cells_per_radius']:g} | {100 * r['jump_error_settled']:+.2f}% | {100 * r['jump_error_spread']:.2f}% "
              f"| {max(r['max_speed']):.4f} | {r['steps']} |" for r in rows]
    harness.write_result("static_bubble_laplace", args, {"resolutions": args.resolutions, "t_end": args.t_end,
                                                         "rows": rows},
                         "\n".join(lines), title="Laplace jump of a resting bubble in a filled tank")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
