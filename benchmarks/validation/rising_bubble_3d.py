"""Rise speed of a 3D air bubble in water against Davies & Taylor (1950): U = 0.711 sqrt(g d_e).

    python -m benchmarks.validation.rising_bubble_3d              # 5 cells per radius, CPU: ~4 min
    python -m benchmarks.validation.rising_bubble_3d --cells-per-radius 10 --device cuda:0
    python -m benchmarks.validation.rising_bubble_3d --quick      # 3 cells per radius, 0.05 s

A 2 cm bubble (Eotvos number 54: the spherical-cap regime the correlation covers) with water's
surface tension starts at rest near the bottom of a 6 x 14 x 6 cm tank. The speed is the slope of
the gas centroid's height over the second half of the run. Prints a Markdown table and writes
benchmarks/results/rising_bubble_3d/<device>_r<cells per radius>.{json,md}. A measurement, not a test.
"""

from __future__ import annotations

import math
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import warp as wp

from warp_mpm_bubbles import Box, Domain, Material, Output, Scene, SolverSettings, Sphere
from warp_mpm_bubbles.diagnostics import gas_centroid_and_diameter
from warp_mpm_bubbles.core.simulation import Simulation

from benchmarks import harness

RADIUS = 0.01


def main(argv=None) -> int:
    parser = harness.parser(__doc__, quick="3 cells per radius, 0.05 simulated seconds")
    parser.add_argument("--cells-per-radius", type=int, default=5)
    parser.add_argument("--duration", type=float, default=0.3, help="simulated seconds")
    parser.add_argument("--interface", default="sharp", choices=("sharp", "baseline"))
    args = parser.parse_args(argv)
    if args.quick:
        args.cells_per_radius, args.duration = 3, 0.05
    args.label = f"r{args.cells_per_radius}" + (f"_{args.label}" if args.label else "")
    wp.config.quiet = True
    dev = wp.get_device(args.device)

    dx = RADIUS / args.cells_per_radius
    scene = Scene(
        domain=Domain(size=(0.06, 0.14, 0.06), cell_size=dx),
        materials={"water": Material("water", surface_tension=0.072), "air": Material("air", kind="gas")},
        shapes=[Box("water", (0.0, 0.0, 0.0), (0.06, 0.12, 0.06)), Sphere("air", (0.03, 0.025, 0.03), RADIUS)],
        solver=SolverSettings(particles_per_cell=8, interface=args.interface),
        output=Output(path=str(Path(tempfile.gettempdir()) / "rising_bubble_3d_unused.usdc"), fps=60),
    )
    sim = Simulation(scene, dev)
    start = time.perf_counter()
    rows = []
    while sim.time < args.duration - 1e-9:
        sim.advance_frame()
        p = sim.particles_numpy()
        centroid, d_e = gas_centroid_and_diameter(p["positions"], p["material"] == 1, p["volume"], 3)
        rows.append((sim.time, float(centroid[1]), d_e))
        print(f"t = {sim.time:.3f} s  centroid y = {centroid[1]:.4f} m  d_e = {d_e:.4f} m", file=sys.stderr, flush=True)
    wall = time.perf_counter() - start
    r = np.array(rows)
    half = len(r) // 2
    speed = float(np.polyfit(r[half:, 0], r[half:, 1], 1)[0])
    reference = 0.711 * math.sqrt(9.81 * r[0, 2])
    out = {
        "cells_per_radius": args.cells_per_radius, "interface": args.interface, "particles": sim.num_particles,
        "steps": sim.stats.steps, "wall_seconds": wall, "rise_speed": speed, "davies_taylor": reference,
        "relative_error": speed / reference - 1.0, "gas_vented_fraction": sim.gas_budget()["vented"] /
        sim.gas_budget()["total"], "d_e_start_end": [float(r[0, 2]), float(r[-1, 2])],
    }
    md = "\n".join([
        "| cells per radius | interface | particles | steps | wall s | rise speed | 0.711 sqrt(g d_e) | error |",
        "|---:|---|---:|---:|---:|---:|---:|---:|",
        f"| {args.cells_per_radius} | {args.interface} | {sim.num_particles:,} | {sim.stats.steps} | {wall:.0f} | "
        f"{speed:.3f} m/s | {reference:.3f} m/s | {100 * out['relative_error']:+.0f}% |", ""])
    print(md)
    harness.write_result("rising_bubble_3d", args, out, md,
                         title=f"3D rising bubble vs Davies & Taylor on {harness.describe_device(args.device)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
