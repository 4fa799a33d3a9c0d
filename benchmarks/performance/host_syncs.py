"""Host reads per step and step time, on small CPU scenes (docs/host_syncs.md).

    python -m benchmarks.performance.host_syncs [--steps 60] [--rounds 3] [--before DIR]
    python -m benchmarks.performance.host_syncs --quick          # 6 steps, 1 round

Scenes (2D, 32^2 cells): "liquid" (a tank at rest), "splash" (benchmarks/cases.splash_scene: a
block thrown into a pool, sub-grid bubbles and entrainment at rate 1000 per cell per second,
conversions every 10 steps). Each scene runs `steps` steps (advance_to one stable step at a
time), counting the host reads of every step (core/host_reads.HostReads), then the same steps
again, timed, without counting. --before DIR: a checkout of an earlier commit (its
warp_mpm_bubbles), run in alternating rounds with this one, each round in its own process, on
the scenes and host-read counter of this checkout; medians of the rounds are printed side by side.
Writes benchmarks/results/host_syncs/<device>.{json,md}.
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from benchmarks import harness
from benchmarks.cases import splash_scene, subgrid_tank


def host_reads_counter():
    """This checkout's HostReads, loaded from its file: the checkout measured may predate it."""
    spec = importlib.util.spec_from_file_location(
        "host_reads_counter", harness.ROOT / "warp_mpm_bubbles" / "core" / "host_reads.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module.HostReads


def worker(scene_name: str, steps: int, device: str) -> dict:
    import numpy as np
    import warp as wp

    wp.config.quiet = True
    from warp_mpm_bubbles.core.simulation import Simulation

    HostReads = host_reads_counter()
    tmp = Path(tempfile.mkdtemp())
    make = {"liquid": lambda: subgrid_tank(tmp, depth=0.05), "splash": lambda: splash_scene(tmp)}[scene_name]
    sim = Simulation(make(), device)
    reads, modules = [], {}
    for _ in range(steps):
        with HostReads() as r:
            sim.advance_to(sim.time + sim.stable_dt() * 0.9999)
        reads.append(r.total)
        for m, n in r.by_module.items():
            modules[m] = modules.get(m, 0) + n
    sim = Simulation(make(), device)
    sim.advance_to(sim.time + sim.stable_dt() * 0.9999)  # compile outside the timing
    start, cpu = time.perf_counter(), time.process_time()
    for _ in range(steps - 1):
        sim.advance_to(sim.time + sim.stable_dt() * 0.9999)
    ms = 1e3 * (time.perf_counter() - start) / (steps - 1)
    cpu_ms = 1e3 * (time.process_time() - cpu) / (steps - 1)  # less sensitive to a shared machine's load
    return {"reads_per_step": float(np.mean(reads)), "max_reads": max(reads), "ms_per_step": ms, "cpu_ms": cpu_ms,
            "by_module_per_step": {m: n / steps for m, n in sorted(modules.items())}}


def run(root: Path, scene: str, steps: int, device: str) -> dict:
    """One worker process on `root`'s package. It starts in `root`, so that package comes first; this
    checkout follows on PYTHONPATH for the benchmarks package (an older checkout's benchmarks/ folder
    is no package and does not shadow it)."""
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(dict.fromkeys([str(root), str(harness.ROOT)])))
    out = subprocess.run(harness.module_command(__spec__.name, "--worker", scene, "--steps", steps,
                                                    "--device", device), cwd=root,
                         env=env, capture_output=True, text=True, check=True).stdout
    return json.loads(out.strip().splitlines()[-1])


def main(argv=None):
    ap = harness.parser(__doc__.split("\n")[0], quick="6 steps, 1 round")
    ap.add_argument("--steps", type=int, default=60)
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--before", type=Path, help="checkout of the earlier commit to compare with")
    ap.add_argument("--worker", help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.worker:
        print(json.dumps(worker(args.worker, args.steps, args.device)))
        return 0
    if args.quick:
        args.steps, args.rounds = 6, 1
    roots = {"after": harness.ROOT} | ({"before": args.before.resolve()} if args.before else {})
    summary, lines = {}, []
    for scene in ("liquid", "splash"):
        results = {name: [] for name in roots}
        for _ in range(args.rounds):  # alternating rounds: load changes hit both alike
            for name, root in roots.items():
                results[name].append(run(root, scene, args.steps, args.device))
        for name, rs in results.items():
            ms = statistics.median(r["ms_per_step"] for r in rs)
            cpu = statistics.median(r["cpu_ms"] for r in rs)
            r = rs[0]
            summary.setdefault(scene, {})[name] = {"rounds": rs, "ms_per_step_median": ms, "cpu_ms_median": cpu}
            lines.append([scene, name, f"{r['reads_per_step']:.2f} ({r['max_reads']})", f"{ms:.1f}", f"{cpu:.1f}"])
            print(f"{scene:7s} {name:6s} host reads/step {r['reads_per_step']:.2f} (max {r['max_reads']}), "
                  f"ms/step median wall {ms:.1f} {[round(x['ms_per_step'], 1) for x in rs]}, "
                  f"CPU {cpu:.1f} {[round(x['cpu_ms'], 1) for x in rs]}; by module per step "
                  + ", ".join(f"{m} {n:.2f}" for m, n in r["by_module_per_step"].items()))
        if "before" in results:
            ratios = [statistics.median(r[key] for r in results["after"])
                      / statistics.median(r[key] for r in results["before"]) for key in ("ms_per_step", "cpu_ms")]
            summary[scene]["after_over_before"] = {"wall": ratios[0], "cpu": ratios[1]}
            print(f"{scene:7s} after/before step time: wall {ratios[0]:.3f}, CPU {ratios[1]:.3f}")
    table = harness.markdown_table(["scene", "code", "host reads / step (max)", "ms / step (wall)",
                                    "ms / step (CPU)"], lines, "llrrr")
    harness.write_result("host_syncs", args, {"steps": args.steps, "scenes": summary}, table,
                         title="Host reads per step")
    return 0


if __name__ == "__main__":
    sys.exit(main())
