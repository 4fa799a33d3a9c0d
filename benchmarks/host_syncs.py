"""Host reads per step and step time, on small CPU scenes (issue #13, item 4; docs/host_syncs.md).

    python benchmarks/host_syncs.py [--steps 60] [--rounds 3] [--before DIR]

Scenes (2D, 32^2 cells): "liquid" (a tank at rest), "splash" (tests/test_subgrid.splash_scene: a
block thrown into a pool, sub-grid bubbles and entrainment at rate 1000 per cell per second,
conversions every 10 steps). Each scene runs `steps` steps (advance_to one stable step at a
time), counting the host reads of every step (core/host_reads.HostReads), then the same steps
again, timed, without counting. --before DIR: a checkout of an earlier commit (its
warp_mpm_bubbles and tests), run in alternating rounds with this one, each round in its own
process; medians of the rounds are printed side by side.
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
from pathlib import Path

HERE = Path(__file__).resolve().parents[1]


def worker(scene_name: str, steps: int) -> dict:
    import numpy as np
    import warp as wp

    wp.config.quiet = True
    sys.path.insert(0, str(Path.cwd() / "tests"))
    from test_subgrid import splash_scene, tank  # noqa: PLC0415

    from warp_mpm_bubbles.core.simulation import Simulation

    sys.path.insert(0, str(HERE / "warp_mpm_bubbles" / "core"))  # this checkout's counter, any code
    from host_reads import HostReads  # noqa: PLC0415

    tmp = Path(tempfile.mkdtemp())
    make = {"liquid": lambda: tank(tmp, depth=0.05), "splash": lambda: splash_scene(tmp)}[scene_name]
    sim = Simulation(make(), "cpu")
    reads, modules = [], {}
    for _ in range(steps):
        with HostReads() as r:
            sim.advance_to(sim.time + sim.stable_dt() * 0.9999)
        reads.append(r.total)
        for m, n in r.by_module.items():
            modules[m] = modules.get(m, 0) + n
    sim = Simulation(make(), "cpu")
    sim.advance_to(sim.time + sim.stable_dt() * 0.9999)  # compile outside the timing
    start, cpu = time.perf_counter(), time.process_time()
    for _ in range(steps - 1):
        sim.advance_to(sim.time + sim.stable_dt() * 0.9999)
    ms = 1e3 * (time.perf_counter() - start) / (steps - 1)
    cpu_ms = 1e3 * (time.process_time() - cpu) / (steps - 1)  # less sensitive to a shared machine's load
    return {"reads_per_step": float(np.mean(reads)), "max_reads": max(reads), "ms_per_step": ms, "cpu_ms": cpu_ms,
            "by_module_per_step": {m: n / steps for m, n in sorted(modules.items())}}


def run(root: Path, scene: str, steps: int) -> dict:
    env = dict(os.environ, PYTHONPATH=str(root))
    out = subprocess.run([sys.executable, __file__, "--worker", scene, "--steps", str(steps)], cwd=root, env=env,
                         capture_output=True, text=True, check=True).stdout
    return json.loads(out.strip().splitlines()[-1])


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--steps", type=int, default=60)
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--before", type=Path, help="checkout of the earlier commit to compare with")
    ap.add_argument("--worker", help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.worker:
        print(json.dumps(worker(args.worker, args.steps)))
        return
    roots = {"after": HERE} | ({"before": args.before.resolve()} if args.before else {})
    for scene in ("liquid", "splash"):
        results = {name: [] for name in roots}
        for _ in range(args.rounds):  # alternating rounds: load changes hit both alike
            for name, root in roots.items():
                results[name].append(run(root, scene, args.steps))
        for name, rs in results.items():
            ms = statistics.median(r["ms_per_step"] for r in rs)
            cpu = statistics.median(r["cpu_ms"] for r in rs)
            r = rs[0]
            print(f"{scene:7s} {name:6s} host reads/step {r['reads_per_step']:.2f} (max {r['max_reads']}), "
                  f"ms/step median wall {ms:.1f} {[round(x['ms_per_step'], 1) for x in rs]}, "
                  f"CPU {cpu:.1f} {[round(x['cpu_ms'], 1) for x in rs]}; by module per step "
                  + ", ".join(f"{m} {n:.2f}" for m, n in r["by_module_per_step"].items()))
        if "before" in results:
            ratios = [statistics.median(r[key] for r in results["after"])
                      / statistics.median(r[key] for r in results["before"]) for key in ("ms_per_step", "cpu_ms")]
            print(f"{scene:7s} after/before step time: wall {ratios[0]:.3f}, CPU {ratios[1]:.3f}")


if __name__ == "__main__":
    main()
