"""Throughput of one simulation step: a 3D dam break at several grid sizes, per pipeline stage.

    python -m benchmarks.performance.throughput                  # N = 32 and 64 on the CPU
    python -m benchmarks.performance.throughput --sizes 32 --steps 5 --device cuda:0
    python -m benchmarks.performance.throughput --quick          # N = 16, 2 steps: a smoke run

Scene per size N: domain [1, 1, 1] m in N^3 cells (cell_size 1/N), free-slip walls, a water box
x in [0, 0.4], y in [0, 0.625], full z (1/4 of the domain) against the x_min wall.

The first --warmup steps are untimed and reported apart: the first of them loads Warp's kernels
from the kernel cache or compiles them (--cold-cache forces a compile into an empty cache). Then
the stage timer and solver statistics are reset and --steps steps of dt = sim.stable_dt() are
timed. Prints a Markdown table and writes benchmarks/results/throughput/<device>.{json,md}.
"""

from __future__ import annotations

import shutil
import sys
import tempfile
import time

import warp as wp

from warp_mpm_bubbles import Box, Domain, Material, Scene, SolverSettings
from warp_mpm_bubbles.core.simulation import Simulation, SolverStats
from warp_mpm_bubbles.core.timing import PhaseTimer

from benchmarks import harness

WATER_MAX = (0.4, 0.625, 1.0)  # water box corner; the other corner is the origin


def dam_break(n: int, ppc: int) -> Scene:
    return Scene(
        name=f"dam_break_{n}",
        domain=Domain(size=(1.0, 1.0, 1.0), cell_size=1.0 / n, walls="free_slip"),
        materials={"water": Material(name="water")},
        shapes=[Box(material="water", min=(0.0, 0.0, 0.0), max=WATER_MAX)],
        solver=SolverSettings(particles_per_cell=ppc),
    )


def run_size(n: int, args, dev) -> dict:
    t0 = time.perf_counter()
    sim = Simulation(dam_break(n, args.ppc), device=dev)
    setup = time.perf_counter() - t0

    t0, first = time.perf_counter(), 0.0
    for _ in range(args.warmup):
        sim.step(sim.stable_dt())
        wp.synchronize_device(dev)
        first = first or time.perf_counter() - t0  # the first step compiles or loads the kernels
    warmup = time.perf_counter() - t0

    sim.timer, sim.stats = PhaseTimer(sim.device), SolverStats()
    t0 = time.perf_counter()
    for _ in range(args.steps):
        sim.step(sim.stable_dt())
    wp.synchronize_device(dev)
    wall = time.perf_counter() - t0

    p, s, st = sim.num_particles, args.steps, sim.stats
    return {
        "n": n,
        "cells": list(sim.grid.interior),
        "num_cells": sim.grid.interior[0] * sim.grid.interior[1] * sim.grid.interior[2],
        "particles": p,
        "steps": s,
        "setup_seconds": setup,
        "warmup_steps": args.warmup,
        "first_step_seconds": first,
        "warmup_seconds": warmup,
        "wall_seconds": wall,
        "seconds_per_step": wall / s,
        "particle_steps_per_second": p * s / wall,
        "stages": {k: {"seconds_per_step": t / s, "particle_steps_per_second": p * s / t}
                   for k, t in sim.timer.seconds.items()},
        "cg_solves": st.cg_solves,
        "cg_iterations_mean": st.cg_iterations / max(st.cg_solves, 1),
        "cg_iterations_max": st.cg_max_iterations,
        "cg_unconverged": st.cg_unconverged,
        "dt_mean": sum(st.dt_history) / max(len(st.dt_history), 1),
    }


def markdown(meta: dict, rows: list[dict]) -> str:
    stages = list(dict.fromkeys(k for r in rows for k in r["stages"]))
    out = [f"- scene: {meta['scene']}", f"- {meta['ppc']} particles per cell, {meta['warmup']} warm-up steps "
           f"(kernel cache: {meta['kernel_cache']}) then {meta['steps']} timed steps of dt = stable_dt()", ""]
    table = [["grid"] + [f"{r['n']}^3 ({r['num_cells']:,} cells)" for r in rows],
             ["particles"] + [f"{r['particles']:,}" for r in rows],
             ["setup / first step / all warm-up (s)"] + [" / ".join(
                 f"{r[k]:.2f}" for k in ("setup_seconds", "first_step_seconds", "warmup_seconds")) for r in rows],
             ["timed steps"] + [str(r["steps"]) for r in rows],
             ["**wall s / step**"] + [f"**{r['seconds_per_step'] * 1e3:.1f} ms**" for r in rows],
             ["**particle-steps / s**"] + [f"**{r['particle_steps_per_second']:.3g}**" for r in rows]]
    for k in stages:
        table.append([f"{k}: ms / step (particle-steps/s)"] + [
            f"{r['stages'][k]['seconds_per_step'] * 1e3:.1f} ({r['stages'][k]['particle_steps_per_second']:.3g})"
            if k in r["stages"] else "-" for r in rows])
    table.append(["CG iterations / solve: mean, max"] + [
        f"{r['cg_iterations_mean']:.1f}, {r['cg_iterations_max']}"
        + (f" ({r['cg_unconverged']} unconverged)" if r["cg_unconverged"] else "") for r in rows])
    table.append(["mean dt (ms)"] + [f"{r['dt_mean'] * 1e3:.3f}" for r in rows])
    out.append("| " + " | ".join(table[0]) + " |")
    out.append("|" + "---|" + "---:|" * len(rows))
    out += ["| " + " | ".join(line) + " |" for line in table[1:]]
    return "\n".join(out) + "\n"


def main(argv=None) -> int:
    ap = harness.parser(__doc__.split("\n")[0], quick="N = 16 only, 1 warm-up and 2 timed steps")
    ap.add_argument("--sizes", default="32,64", help="comma-separated N for N^3 cells (default 32,64)")
    ap.add_argument("--ppc", type=int, default=8, help="particles per cell (default 8)")
    ap.add_argument("--steps", type=int, default=20, help="timed steps per size (default 20)")
    ap.add_argument("--warmup", type=int, default=3, help="untimed steps first, compile included (default 3)")
    ap.add_argument("--cold-cache", action="store_true",
                    help="use an empty temporary kernel cache, so the warm-up includes the full compile")
    args = ap.parse_args(argv)
    if args.quick:
        args.sizes, args.steps, args.warmup = "16", 2, 1
    sizes = [int(s) for s in args.sizes.split(",") if s.strip()]
    if args.steps < 1 or args.warmup < 0 or not sizes:
        ap.error("need --steps >= 1, --warmup >= 0 and at least one size")

    cold_dir = tempfile.mkdtemp(prefix="warp_cache_") if args.cold_cache else None
    if cold_dir:
        wp.config.kernel_cache_dir = cold_dir
    wp.init()
    dev = wp.get_device(args.device)
    meta = {
        "kernel_cache": ("cold: compiled into " if args.cold_cache else "as found: ") + wp.config.kernel_cache_dir,
        "scene": f"domain [1, 1, 1] m, free-slip walls, water box [0, 0, 0] .. {list(WATER_MAX)}",
        "ppc": args.ppc, "warmup": args.warmup, "steps": args.steps,
    }
    rows = []
    for n in sizes:
        print(f"N = {n}: {args.warmup} warm-up + {args.steps} timed steps ...", file=sys.stderr, flush=True)
        rows.append(run_size(n, args, dev))
    text = markdown(meta, rows)
    print(text)

    harness.write_result("throughput", args, {"meta": meta, "results": rows}, text,
                         title=f"Throughput: 3D dam break on {harness.describe_device(args.device)}")
    if cold_dir:
        shutil.rmtree(cold_dir, ignore_errors=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
