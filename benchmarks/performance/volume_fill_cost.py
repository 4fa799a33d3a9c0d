"""What the volume correction's variants cost a step against moving velocities (the cell fill, its
divergence asked of the pressure solve; the default before 2026-12-07): the variants run alternately
on the same scene, so each ratio is measured side by side (docs/design.md, #volume-correction).

- `volume_correction_moves = "positions"` (the default) adds a second solve of the pressure system
  a step (to a relative residual of 1e-2, warm started: 2-3 iterations) and one interpolation per
  particle.
- `[solver].volume_fill = "smoothed"` reads each enclosed cell's 3^dim block and, for each
  neighbour, whether it is enclosed: in 3D 27 cells and 6 faces of each, in 2D 9 and 4. Only the
  pressure system's assembly changes, so in 2D it is lost in the step; in 3D it shows.

    python -m benchmarks.performance.volume_fill_cost            # hysing_2d 80 and adelsberger_3d 27 to 0.3 s, 3 rounds
    python -m benchmarks.performance.volume_fill_cost --quick    # hysing_2d 20 and adelsberger_3d 12 to 0.1 s, 1 round

Measured 2026-12-07 (2-core AMD EPYC) with the cell fill moving velocities as the default, seconds a
step over its, per round: smoothed
0.886 / 0.954 / 0.807 (hysing_2d at 80 cells: the noise) and 0.991 / 1.023 / 0.942 (adelsberger_3d at
27 cells, with each cell's enclosed flag from one pass; 1.05-1.17 before); smoothed moving positions
1.110 / 1.294 / 0.984 and 1.328 / 1.210 / 1.188.
"""

from __future__ import annotations

import dataclasses
import sys
import tempfile
import time

import warp as wp

from warp_mpm_bubbles.core.simulation import Simulation

from benchmarks import harness
from benchmarks.validation import convergence  # the cases

VARIANTS = {"cell, velocities": {"volume_correction_moves": "velocities"}, "cell, positions (default)": {},
            "smoothed, positions": {"volume_fill": "smoothed"}}  # the first is the base of the ratios
WARM = 0.02  # s simulated before the clock starts: kernels compiled, the first solves done


def seconds_per_step(case: str, cells: int, t_end: float, settings: dict, device: str) -> dict:
    with tempfile.TemporaryDirectory() as tmp:
        scene = convergence.scene(convergence.CASES[case], cells, tmp)
        scene = dataclasses.replace(scene, solver=dataclasses.replace(scene.solver, **settings))
        sim = Simulation(scene, device)
        sim.advance_to(WARM)
        start, steps = time.perf_counter(), sim.stats.steps
        sim.advance_to(t_end)
        wp.synchronize_device(device)
        return {"s_per_step": (time.perf_counter() - start) / (sim.stats.steps - steps),
                "steps": sim.stats.steps - steps}


def main(argv=None) -> int:
    ap = harness.parser(__doc__, quick="hysing_2d at 20 cells and adelsberger_3d at 12, to 0.1 s, one round")
    ap.add_argument("--rounds", type=int, default=3, help="alternating rounds of the variants (default 3)")
    args = ap.parse_args(argv)
    if args.rounds < 1:
        print(f"--rounds: expected a whole number of at least 1; got {args.rounds}", file=sys.stderr)
        return 2
    wp.config.log_level = getattr(wp, "LOG_WARNING", 30)
    runs = [("hysing_2d", 20, 0.1), ("adelsberger_3d", 12, 0.1)] if args.quick else \
        [("hysing_2d", 80, 0.3), ("adelsberger_3d", 27, 0.3)]
    rounds = 1 if args.quick else args.rounds
    rows = []
    for case, cells, t_end in runs:
        rounds_out = []
        for r in range(rounds):
            times = {name: seconds_per_step(case, cells, t_end, settings, args.device)
                     for name, settings in VARIANTS.items()}
            base = times[next(iter(VARIANTS))]["s_per_step"]
            rounds_out.append({"times": times, "ratios": {name: t["s_per_step"] / base for name, t in times.items()}})
            print(f"{case} {cells} round {r + 1}: " + ", ".join(
                f"{name} {t['s_per_step']:.4f} s/step ({t['s_per_step'] / base:.3f})" for name, t in times.items()),
                flush=True)
        rows.append({"case": case, "cells": cells, "t_end": t_end, "rounds": rounds_out})
    names = list(VARIANTS)
    lines = ["| case | cells | round | " + " | ".join(f"{n} (s/step)" for n in names) + " | "
             + " | ".join(f"{n} / {names[0]}" for n in names[1:]) + " |",
             "|---|---:|---:|" + "---:|" * (2 * len(names) - 1)]
    for row in rows:
        for r, out in enumerate(row["rounds"], 1):
            lines.append(f"| {row['case']} | {row['cells']} | {r} | "
                         + " | ".join(f"{out['times'][n]['s_per_step']:.4f}" for n in names) + " | "
                         + " | ".join(f"{out['ratios'][n]:.3f}" for n in names[1:]) + " |")
    harness.write_result("volume_fill_cost", args, {"rows": rows}, "\n".join(lines),
                         title="The volume correction's variants: cost per step against the default (alternating rounds)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
