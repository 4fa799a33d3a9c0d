"""The particle <-> grid transfers, per stage: p2g, g2p and the sort by cell.

    python -m benchmarks.performance.transfers --grid 32 --rounds 3
    python -m benchmarks.performance.transfers --grid 32 --compare /tmp/base   # this tree against another copy
    python -m benchmarks.performance.transfers --quick     # 16^3, seeded order, 1 round

Scene: the configuration of benchmarks/performance/peer_comparison.py (a unit box, free-slip walls, an N^3 grid,
a centred water block of (N/2)^3 cells at 8 particles per cell). Each variant runs in its own
subprocess, the variants alternating between rounds (so drifts in machine load hit all alike):

  tree        the source tree whose package runs: this one, and --compare DIR (e.g. an unchanged copy)
  order       "seeded" (the seeder's cell-major order) or "shuffled" (a random permutation of the
              particles, as after a long splash has mixed them)
  sort        Simulation.sort_every: a number of steps (default 10), or "off" (0); a tree
              without the sort runs its own step once per order

Per variant: --warmup full steps, then --steps full steps timed by the stage timer (ms per step of
p2g, grid, pressure, extend, g2p; the sort is charged to p2g), and --reps repetitions of each
transfer alone (p2g: Simulation.particles_to_grid(); g2p: the g2p launch with dt = 0, which leaves
the particles where they are) and of Simulation.sort_particles() where the tree has it.
Medians over rounds. Times are the process's CPU time (time.process_time; Warp runs CPU kernels on
the calling thread), not wall time: on a shared machine wall time mostly measures the other jobs.
--clock wall switches to wall time (a GPU needs it). Writes
benchmarks/results/transfers/<device>_g<N>[_<label>].{json,md}.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from contextlib import contextmanager
from pathlib import Path

from benchmarks import harness

ROOT = harness.ROOT
STAGES = ("p2g", "grid", "pressure", "extend", "g2p")


def block_scene(grid: int, out_dir: str):
    from warp_mpm_bubbles import Box, Domain, Material, Output, Scene, SolverSettings

    n = grid // 2
    lo = (grid - n) // 2 / grid
    hi = lo + n / grid
    return Scene(
        name="transfer_block",
        domain=Domain(size=(1.0, 1.0, 1.0), cell_size=1.0 / grid, gravity=(0.0, -9.81, 0.0), walls="free_slip"),
        materials={"water": Material("water")},
        shapes=[Box("water", min=(lo, lo, lo), max=(hi, hi, hi))],
        solver=SolverSettings(particles_per_cell=8),
        output=Output(path=str(Path(out_dir) / "unused.usdc")),
    )


def shuffle(sim, seed: int = 0):
    """Permute every particle field by one random permutation (host side, before timing)."""
    import numpy as np
    import warp as wp

    p = sim.particles
    perm = np.random.default_rng(seed).permutation(p.count)
    for name, dtype in p.fields.items():
        data = p.numpy(name)[perm].copy()
        getattr(p, name)[: p.count].assign(wp.array(data, dtype=dtype, device=sim.device))


CLOCK = time.process_time  # the worker's clock (--clock)


def timed(fn, reps: int) -> float:
    """Median seconds of `reps` calls."""
    import warp as wp

    out = []
    for _ in range(reps):
        t0 = CLOCK()
        fn()
        wp.synchronize()
        out.append(CLOCK() - t0)
    return statistics.median(out)


def stage_timer(device):
    """The simulation's PhaseTimer on CLOCK."""
    import warp as wp
    from warp_mpm_bubbles.core.timing import PhaseTimer

    class Timer(PhaseTimer):
        @contextmanager
        def __call__(self, stage: str):
            start = CLOCK()
            try:
                yield
            finally:
                if self.device.is_cuda:
                    wp.synchronize_device(self.device)
                self.seconds[stage] = self.seconds.get(stage, 0.0) + CLOCK() - start

    return Timer(device)


def worker(args) -> int:
    import warp as wp

    wp.config.quiet = True
    from warp_mpm_bubbles.core.simulation import Simulation, SolverStats

    global CLOCK
    CLOCK = time.perf_counter if args.clock == "wall" else time.process_time

    with tempfile.TemporaryDirectory() as out_dir:
        sim = Simulation(block_scene(args.grid, out_dir), device=args.device)
    if hasattr(sim, "sort_every"):
        sim.sort_every = 0 if args.sort == "off" else int(args.sort)
    if args.order == "shuffled":
        shuffle(sim)
    for _ in range(args.warmup):
        sim.step(sim.stable_dt())
    sim.timer, sim.stats = stage_timer(sim.device), SolverStats()
    t0 = CLOCK()
    for _ in range(args.steps):
        sim.step(sim.stable_dt())
    wp.synchronize()
    wall = CLOCK() - t0
    result = {"particles": sim.num_particles, "ms_per_step": 1e3 * wall / args.steps,
              "stages": {k: 1e3 * t / args.steps for k, t in sim.timer.seconds.items()}}
    result["p2g_alone"] = 1e3 * timed(sim.particles_to_grid, args.reps)
    dt = sim.stable_dt()
    sim.step(dt)  # the grid fields of a step, for g2p
    result["g2p_alone"] = 1e3 * timed(lambda: sim._phase_g2p(0.0, False), args.reps)
    if hasattr(sim, "sort_particles"):
        result["sort_alone"] = 1e3 * timed(sim.sort_particles, args.reps)
    print("RESULT " + json.dumps(result), flush=True)
    return 0


def call_worker(tree: str, order: str, sort: str, args) -> dict:
    cmd = harness.module_command(__spec__.name, "--worker", "--grid", args.grid, "--order", order, "--sort", sort,
                                 "--warmup", args.warmup, "--steps", args.steps, "--reps", args.reps,
                                 "--device", args.device, "--clock", args.clock)
    # The worker starts in `tree`, so that tree's package comes first; this checkout follows for the
    # benchmarks package (an older tree's benchmarks/ folder is no package and does not shadow it).
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(dict.fromkeys([tree, str(ROOT)]))}
    proc = subprocess.run(cmd, cwd=tree, env=env, capture_output=True, text=True)
    lines = [line for line in proc.stdout.splitlines() if line.startswith("RESULT ")]
    if proc.returncode or not lines:
        raise SystemExit(f"worker failed ({tree}, {order}, sort {sort}):\n{proc.stdout}\n{proc.stderr}")
    return json.loads(lines[-1][len("RESULT "):])


def variants(args) -> list[tuple[str, str, str, str]]:
    """(name, tree, order, sort) for every variant asked for."""
    trees = [("this", str(ROOT))] + ([("compare", str(Path(args.compare).resolve()))] if args.compare else [])
    out = []
    for tname, tree in trees:
        for order in args.orders.split(","):
            for sort in args.sorts.split(","):
                if tname == "compare" and sort != args.sorts.split(",")[0]:
                    continue  # the other tree may not sort at all
                out.append((f"{tname} {order} sort={sort}", tree, order, sort))
    return out


def markdown(meta: dict, summary: dict) -> str:
    names = list(summary)
    out = [f"- {meta['grid']}^3 grid, {meta['particles']:,} particles",
           f"- {meta['rounds']} alternating rounds, each variant in its own process; medians over rounds; "
           f"{meta['clock']} time; load average at the end {meta['load_average']}",
           f"- trees: this = {meta['this']}" + (f"; compare = {meta['compare']}" if meta["compare"] else ""), "",
           "| ms | " + " | ".join(names) + " |", "|---|" + "---:|" * len(names)]
    rows = [("p2g alone", "p2g_alone"), ("g2p alone", "g2p_alone"), ("sort alone", "sort_alone")]
    rows += [(f"step: {k}", k) for k in STAGES] + [("step: total", "ms_per_step")]
    for label, key in rows:
        out.append(f"| {label} | " + " | ".join(
            f"{summary[n][key]:.1f}" if summary[n].get(key) is not None else "-" for n in names) + " |")
    return "\n".join(out) + "\n"


def main(argv=None) -> int:
    ap = harness.parser(__doc__.split("\n")[0], quick="a 16^3 grid, seeded order, 1 round of 2 steps")
    ap.add_argument("--grid", type=int, default=32)
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--warmup", type=int, default=3)
    ap.add_argument("--steps", type=int, default=10)
    ap.add_argument("--reps", type=int, default=10)
    ap.add_argument("--orders", default="seeded,shuffled", help="comma-separated: seeded, shuffled")
    ap.add_argument("--sorts", default="10,off", help="comma-separated sort intervals (steps) or off (default 10,off)")
    ap.add_argument("--compare", default=None, help="another source tree (a directory holding warp_mpm_bubbles)")
    ap.add_argument("--clock", choices=("cpu", "wall"), default="cpu", help="CPU time (default) or wall time")
    ap.add_argument("--worker", action="store_true", help=argparse.SUPPRESS)
    ap.add_argument("--order", default="seeded", help=argparse.SUPPRESS)
    ap.add_argument("--sort", default="10", help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.worker:
        return worker(args)
    if args.quick:
        args.grid, args.rounds, args.warmup, args.steps, args.reps, args.orders = 16, 1, 1, 2, 2, "seeded"
    args.label = f"g{args.grid}" + (f"_{args.label}" if args.label else "")

    todo = variants(args)
    rounds: dict[str, list[dict]] = {name: [] for name, *_ in todo}
    for r in range(args.rounds):
        order = todo if r % 2 == 0 else todo[::-1]
        for name, tree, o, s in order:
            print(f"round {r + 1}: {name}", file=sys.stderr, flush=True)
            rounds[name].append(call_worker(tree, o, s, args))
    keys = ["p2g_alone", "g2p_alone", "sort_alone", "ms_per_step", *STAGES]
    summary = {}
    for name, results in rounds.items():
        pick = lambda k, rs=results: [r.get(k, r["stages"].get(k)) for r in rs]  # noqa: E731
        summary[name] = {k: statistics.median(pick(k)) if None not in pick(k) else None for k in keys}
    meta = {"grid": args.grid, "particles": rounds[todo[0][0]][0]["particles"], "rounds": args.rounds,
            "this": str(ROOT), "compare": args.compare, "clock": args.clock,
            "load_average": [round(x, 1) for x in os.getloadavg()]}
    text = markdown(meta, summary)
    print(text)
    harness.write_result("transfers", args, {"meta": meta, "summary": summary, "rounds": rounds}, text,
                         title=f"Transfers on {harness.describe_device(args.device)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
