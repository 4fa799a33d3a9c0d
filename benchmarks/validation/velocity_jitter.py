"""Where a rising bubble's step-to-step speed jitter comes from: hysing_2d (benchmarks/validation/convergence.py)
at one grid to t = 1.5 s, one setting changed at a time. The jitter is the RMS, over 0.025 s bins
from t = 0.3 s on, of the bin's mean centroid rate (every step's gas centroid) about a least-squares
quadratic through the step rates within +-0.15 s, read at the bin's centre; also as a share of the
peak rise speed (convergence.windowed's largest slope).
Prints a table and writes benchmarks/results/velocity_jitter/<device>[_<cells>].{json,md}.

The reference is a fit to the rates, not the slope of a quadratic through the centroid
(convergence.windowed; kept as "jitter_position_window" for comparison with older tables): that
slope misses the rise speed's curvature over the window by about 0.1 v'' h^2, which on a noise-free
Hysing-like rise (v = 0.24 tanh(t / 0.2)) reads 0.0011 m/s, 0.5% of the peak, and was the "floor"
below. A quadratic through the rates is exact at the centre for any cubic speed: the same noise-free
rise reads 6e-5 m/s (tests/test_velocity_jitter.py), so a jitter of 0.1% of the peak can be read.

    python -m benchmarks.validation.velocity_jitter              # 40 cells across, every variant: 2 min on 2 CPU cores
    python -m benchmarks.validation.velocity_jitter --cells 80   # about 25 min (2-4 min a variant)
    python -m benchmarks.validation.velocity_jitter --cells 80 --variants "default,volume correction off"
    python -m benchmarks.validation.velocity_jitter --quick      # 10 cells, two variants

Measured 2026-12-07 (this reading), 40 cells: default 0.0043 m/s, 1.8% of the peak rise speed;
volume_relaxation_time 1 ms 0.0049, 1 s 0.00029 (0.12%); 9 / 16 particles per cell 0.0023 / 0.0013;
cg_tolerance 1e-8, max_dt 2 ms, liquid_velocity = shared, gas_films = passive within 10% of the
default; the volume correction off (volume_relaxation_time = 0) 0.00026 (0.11%). At 80 cells
(--cells 80 --variants "default,volume correction off,volume_relaxation_time 1 s,particles_per_cell 16"
--label 80): default 0.0026 (1.1%); the volume correction off 0.00008 (0.03%), 1 s 0.00011 (0.05%),
16 particles per cell 0.00014 (0.06%, twice the wall time); the position window read 0.0011 for all
three, its own bias. The volume correction, answering the particles' sampling noise in each
cell's fill, is nearly all of it (docs/design.md#limitations). Measured before that reading
(2026-12-05, c0f4e15, the position window): 40 cells 0.0046, 80 cells 0.0029.
"""

from __future__ import annotations

import dataclasses
import sys
import tempfile
import time

import numpy as np
import warp as wp

from warp_mpm_bubbles.core.simulation import Simulation

from benchmarks import harness
from benchmarks.validation import convergence  # the study's case, tracker and window

VARIANTS = {  # label -> SolverSettings fields changed from the production defaults
    "default": {}, "volume_relaxation_time 1 ms": {"volume_relaxation_time": 1e-3},
    "volume_relaxation_time 1 s": {"volume_relaxation_time": 1.0}, "particles_per_cell 9": {"particles_per_cell": 9},
    "particles_per_cell 16": {"particles_per_cell": 16}, "cg_tolerance 1e-8": {"cg_tolerance": 1e-8},
    "max_dt 2 ms": {"max_dt": 2e-3}, "liquid_velocity shared": {"liquid_velocity": "shared"},
    "gas_films passive": {"gas_films": "passive"}, "volume correction off": {"volume_relaxation_time": 0.0},
    "volume_fill smoothed": {"volume_fill": "smoothed"},
    "volume_correction_moves velocities": {"volume_correction_moves": "velocities"},  # the default before
    "smoothed and positions": {"volume_fill": "smoothed", "volume_correction_moves": "positions"},
}
T_END, BIN, WINDOW, FROM = 1.5, 0.025, 0.15, 0.3  # s


def jitter(t: np.ndarray, y: np.ndarray) -> float:
    """RMS of the bins' mean centroid rate about a quadratic through the rates within +-WINDOW of
    each bin's centre, read there (exact for a speed that is any cubic in time near the bin)."""
    rate, mid = np.diff(y) / np.diff(t), 0.5 * (t[1:] + t[:-1])
    deviations = []
    for start in np.arange(FROM, T_END - WINDOW - BIN, BIN):
        centre = start + BIN / 2
        inside = (mid >= start) & (mid < start + BIN)
        if not inside.any():  # a step longer than a bin (coarse grids): no rate of its own
            continue
        near = np.abs(mid - centre) <= WINDOW
        smooth = np.polyval(np.polyfit(mid[near] - centre, rate[near], 2), 0.0)
        deviations.append(rate[inside].mean() - smooth)
    return float(np.sqrt(np.mean(np.square(deviations))))


def jitter_position_window(t: np.ndarray, y: np.ndarray) -> float:
    """The older reading: the bins' mean rate about the slope of convergence.windowed (a quadratic
    through the centroid) at the bins' centres. Biased by the speed's curvature (module docstring)."""
    rate, mid = np.diff(y) / np.diff(t), 0.5 * (t[1:] + t[:-1])
    centres, _, speed = convergence.windowed(t, y, WINDOW, FROM - WINDOW)
    deviations = []
    for start in np.arange(FROM, T_END - WINDOW - BIN, BIN):
        inside = (mid >= start) & (mid < start + BIN)
        if not inside.any():
            continue
        deviations.append(rate[inside].mean() - np.interp(start + BIN / 2, centres, speed))
    return float(np.sqrt(np.mean(np.square(deviations))))


def peak_speed(t: np.ndarray, y: np.ndarray) -> float:
    """The rise speed's peak: the largest slope of the windowed centroid (convergence.windowed)."""
    return float(convergence.windowed(t, y, WINDOW, FROM - WINDOW)[2].max())


def run(cells: int, fields: dict, device="cpu") -> dict:
    case = convergence.CASES["hysing_2d"]
    with tempfile.TemporaryDirectory() as tmp:
        scene = convergence.scene(case, cells, tmp)
        scene = dataclasses.replace(scene, solver=dataclasses.replace(scene.solver, **fields))
        sim = Simulation(scene, device)
        gas_index = [m.is_gas for m in sim.scene.materials.values()].index(True)
        track = {"t": [], "centroid_y": [], "particle_speed": [], "cost_s": 0.0}
        start = time.perf_counter()
        sim.advance_to(T_END, convergence.tracker(sim, gas_index, track))
        t, y = np.array(track["t"]), np.array(track["centroid_y"])
        peak = peak_speed(t, y)
        return {"jitter": jitter(t, y), "jitter_share_of_peak": jitter(t, y) / peak, "peak_speed": peak,
                "jitter_position_window": jitter_position_window(t, y), "steps": sim.stats.steps,
                "wall_s": time.perf_counter() - start}


def main(argv=None) -> int:
    ap = harness.parser(__doc__, quick="10 cells across, the default and one other variant")
    ap.add_argument("--cells", type=int, default=40, help="cells across the tank (at least 10)")
    ap.add_argument("--variants", default=None,
                    help="comma-separated labels of the variants to run (default all); the file is then "
                         "<device>_<cells>_<labels>")
    args = ap.parse_args(argv)
    variants = VARIANTS
    if args.quick:
        args.cells = 10
        variants = {k: VARIANTS[k] for k in ("default", "volume_relaxation_time 1 s")}
    if args.variants is not None:
        chosen = [v.strip() for v in args.variants.split(",")]
        unknown = [v for v in chosen if v not in VARIANTS]
        if unknown or not chosen:
            print(f"--variants: unknown label(s) {unknown}; expected comma-separated labels among: "
                  + ", ".join(VARIANTS), file=sys.stderr)
            return 2
        variants = {k: VARIANTS[k] for k in chosen}
        if args.label is None:
            args.label = f"{args.cells}_" + "_".join("-".join(k.split()) for k in chosen)
    if args.cells != 40 and args.label is None:  # 40: the default's file
        args.label = str(args.cells)
    wp.config.quiet = True  # older Warp; 1.19 reads log_level
    wp.config.log_level = getattr(wp, "LOG_WARNING", 30)
    if args.cells < 10:
        print(f"--cells: expected a whole number of at least 10 (cells across the tank); got {args.cells}",
              file=sys.stderr)
        return 2
    rows = {}
    for label, fields in variants.items():
        rows[label] = run(args.cells, fields, args.device)
        r = rows[label]
        print(f"{label:30s} jitter {r['jitter']:.5f} m/s ({100 * r['jitter_share_of_peak']:.2f}% of the peak "
              f"{r['peak_speed']:.4f}; position window {r['jitter_position_window']:.5f})  ({r['steps']} steps, "
              f"{r['wall_s']:.0f} s)", flush=True)
    out = {"code": convergence.git_describe(), "cells": args.cells, "t_end": T_END, "rows": rows}
    lines = [f"Solver at {out['code']}.", "",
             "| variant | jitter (m/s) | % of peak speed | x default | position window (m/s) | steps |",
             "|---|---:|---:|---:|---:|---:|"]
    base = rows["default"]["jitter"] if "default" in rows else float("nan")  # --variants may leave it out
    lines += [f"| {k} | {r['jitter']:.5f} | {100 * r['jitter_share_of_peak']:.2f} | {r['jitter'] / base:.2f} | "
              f"{r['jitter_position_window']:.5f} | {r['steps']} |" for k, r in rows.items()]
    harness.write_result("velocity_jitter", args, out, "\n".join(lines),
                         title=f"Velocity jitter, hysing_2d at {args.cells} cells to t = {T_END} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
