"""What the effects model costs a liquid-only scene: this checkout against a commit from before
effects existed, on the same machine in one run.

    python -m benchmarks.performance.effects_overhead                  # against 2561ff2, N = 32, CPU
    python -m benchmarks.performance.effects_overhead --ref 9b9712e --size 48 --rounds 5 --device cuda:0
    python -m benchmarks.performance.effects_overhead --ref 53a888c --label stages   # the stage protocol's cost
    python -m benchmarks.performance.effects_overhead --quick          # N = 12, 2 steps, 1 round

Each round times the same liquid-only 3D dam break (benchmarks/performance/throughput.py's scene, 8 particles
per cell) once with each version, in fresh processes and alternating order, so drifts in machine
load hit both alike. The reference is checked out with `git worktree` into a temporary folder.
Prints the per-round ms/step and the ratio of medians, and writes
benchmarks/results/effects_overhead/<device>[_<label>].{md,json}.
"""

from __future__ import annotations

import os
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

from benchmarks import harness

ROOT = harness.ROOT

# Runs inside each version's checkout: the scene is built with the API both versions share.
TIMER = r"""
import pathlib, sys, time, warp as wp
wp.config.quiet = True
import warp_mpm_bubbles
from warp_mpm_bubbles import Box, Domain, Material, Scene, SolverSettings
# Asked of the checkout's files, not of the import system: an editable install of another checkout
# answers for a subpackage this one lacks (a version from before the core/ layout has no core/).
if (pathlib.Path(warp_mpm_bubbles.__file__).parent / "core").is_dir():
    from warp_mpm_bubbles.core.simulation import Simulation
else:
    from warp_mpm_bubbles.simulation import Simulation
n, steps, device = int(sys.argv[1]), int(sys.argv[2]), sys.argv[3]
scene = Scene(domain=Domain(size=(1.0, 1.0, 1.0), cell_size=1.0 / n, walls="free_slip"),
              materials={"water": Material("water")}, shapes=[Box("water", (0.0, 0.0, 0.0), (0.4, 0.625, 1.0))],
              solver=SolverSettings(particles_per_cell=8))
sim = Simulation(scene, device)
for _ in range(3):
    sim.step(sim.stable_dt())
wp.synchronize_device(device)
t0 = time.perf_counter()
for _ in range(steps):
    sim.step(sim.stable_dt())
wp.synchronize_device(device)
print((time.perf_counter() - t0) / steps)
"""


def time_version(checkout: Path, args) -> float:
    env = dict(os.environ, PYTHONPATH=str(checkout))
    out = subprocess.run([sys.executable, "-c", TIMER, str(args.size), str(args.steps), args.device],
                         cwd=checkout, env=env, capture_output=True, text=True, check=True)
    return float(out.stdout.strip().splitlines()[-1])


def main(argv=None) -> int:
    ap = harness.parser(__doc__.split("\n")[0], quick="N = 12, 2 timed steps, 1 round")
    ap.add_argument("--ref", default="2561ff2", help="git commit from before effects existed (default 2561ff2)")
    ap.add_argument("--size", type=int, default=32, help="N for N^3 cells (default 32)")
    ap.add_argument("--steps", type=int, default=10, help="timed steps per run (default 10)")
    ap.add_argument("--rounds", type=int, default=3, help="alternating rounds (default 3)")
    args = ap.parse_args(argv)
    if args.quick:
        args.size, args.steps, args.rounds = 12, 2, 1

    with tempfile.TemporaryDirectory(prefix="effects_ref_") as tmp:
        ref_dir = Path(tmp) / "ref"
        subprocess.run(["git", "worktree", "add", "--detach", str(ref_dir), args.ref], cwd=ROOT, check=True,
                       capture_output=True)
        try:
            rows = []
            for r in range(args.rounds):
                order = [("now", ROOT), ("ref", ref_dir)][:: 1 if r % 2 == 0 else -1]
                times = {name: time_version(path, args) for name, path in order}
                rows.append(times)
                print(f"round {r + 1}: now {times['now'] * 1e3:.1f} ms/step, {args.ref} {times['ref'] * 1e3:.1f}",
                      file=sys.stderr, flush=True)
        finally:
            subprocess.run(["git", "worktree", "remove", "--force", str(ref_dir)], cwd=ROOT, capture_output=True)

    now = statistics.median(r["now"] for r in rows)
    ref = statistics.median(r["ref"] for r in rows)
    meta = {"ref": args.ref, "size": args.size, "steps": args.steps, "rounds": rows,
            "median_ms_now": now * 1e3, "median_ms_ref": ref * 1e3, "ratio": now / ref}
    text = "\n".join([
        f"- 3D dam break, {args.size}^3 cells, 8 particles per cell, {args.steps} timed steps after 3 warm-up, "
        f"{args.rounds} alternating rounds in fresh processes", "",
        "| round | this checkout (ms/step) | " + args.ref + " (ms/step) |", "|---|---:|---:|",
        *[f"| {i + 1} | {r['now'] * 1e3:.1f} | {r['ref'] * 1e3:.1f} |" for i, r in enumerate(rows)],
        f"| **median** | **{now * 1e3:.1f}** | **{ref * 1e3:.1f}** |", "",
        f"Ratio of medians (this checkout / {args.ref}): **{now / ref:.3f}**", ""])
    print(text)
    harness.write_result("effects_overhead", args, meta, text,
                         title=f"Effects model overhead on a liquid-only scene ({harness.describe_device(args.device)})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
