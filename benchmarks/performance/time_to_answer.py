"""Time to an answer: the wall and CPU seconds a user waits for the rising-bubble benchmarks to reach
their end time, the seconds per simulated second, and the accuracy reached there.

    python -m benchmarks.performance.time_to_answer                      # Hysing 40 and 80, Adelsberger 27, to t = 3
    python -m benchmarks.performance.time_to_answer --cases hysing_2d:40 --rounds 3
    python -m benchmarks.performance.time_to_answer --cases hysing_2d:40 --before ../main   # side by side
    python -m benchmarks.performance.time_to_answer --quick              # Hysing 20, Adelsberger 8, to 0.1 t_end

Cases (benchmarks/validation/convergence.py defines them): hysing_2d, Hysing et al.'s test case 1 (a
1 x 2 tank, "cells across" the width), and adelsberger_3d, Adelsberger et al.'s test case 1. Each run
is a fresh process, as a user's is: `start-up` is importing the package and Warp, loading the kernels
and building the scene; `run` is the steps to the end time. The steps advance to the convergence
study's 60 sample times, so a run takes the same steps as that study's run at the same code. CPU
seconds are the process's, every thread's (user + system): on a shared machine they move less with the
load than wall seconds. The gas centroid is read after every step (its cost is taken off both times)
for the accuracy: the centroid at t_end and the peak rise speed (the centroid's rate through the
study's window, `convergence.extremum`), each against the published value, only for runs that reach
the case's end time (--fraction 1).

--before DIR runs every case with DIR's package too (an earlier checkout, which needs the same cases
in its benchmarks/validation/convergence.py), the two alternating round by round, so that ratios
come from one run on one machine. The table also gives the cost per simulated second of the peer
block (benchmarks/performance/peer_comparison.py's stored result), ours and Taichi's.
Writes benchmarks/results/time_to_answer/<device>[_label][_quick].{json,md}.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path

from benchmarks import harness

DEFAULT_CASES = "hysing_2d:40,hysing_2d:80,adelsberger_3d:27"
QUICK_CASES = "hysing_2d:20,adelsberger_3d:8"
QUICK_FRACTION = 0.1


def worker(case_key: str, cells: int, fraction: float, device: str) -> dict:
    """One run in this process, from import to the end time (the caller started the process)."""
    start_wall, start_cpu = time.perf_counter(), time.process_time()
    import tempfile

    import warp as wp

    wp.config.quiet = True
    from benchmarks.validation.convergence import CASES, SAMPLES, extremum, scene, tracker
    from warp_mpm_bubbles.core.simulation import Simulation

    case = CASES[case_key]
    t_end = case.t_end * fraction
    with tempfile.TemporaryDirectory() as tmp:
        sim = Simulation(scene(case, cells, tmp), device)
        gas_index = [m.is_gas for m in sim.scene.materials.values()].index(True)
        track = {"t": [], "centroid_y": [], "particle_speed": [], "cost_s": 0.0}
        on_step = tracker(sim, gas_index, track)
        on_step(0.0, 0.0)
        built_wall, built_cpu = time.perf_counter(), time.process_time()
        for k in range(1, SAMPLES + 1):
            sim.advance_to(t_end * k / SAMPLES, on_step)
        wp.synchronize_device(sim.device)
        end_wall, end_cpu = time.perf_counter(), time.process_time()
    out = {"case": case_key, "cells": cells, "t_end": t_end, "particles": sim.num_particles,
           "steps": sim.stats.steps, "startup_wall_s": built_wall - start_wall, "startup_cpu_s": built_cpu - start_cpu,
           "run_wall_s": end_wall - built_wall - track["cost_s"], "run_cpu_s": end_cpu - built_cpu - track["cost_s"],
           "stages_s": dict(sim.timer.seconds), "centroid_end": track["centroid_y"][-1]}
    if fraction == 1.0:  # the accuracy at the case's own end time, against the published values
        peak = extremum(track["t"], track["centroid_y"], t_end / 20, t_end / SAMPLES, "peak_slope")
        out["rise_speed_max"] = peak["value"]
        for metric, value in (("centroid_end", out["centroid_end"]), ("rise_speed_max", peak["value"])):
            reference = case.reference[metric][0]
            out[f"{metric}_error"] = value / reference - 1.0
    return out


def run(root: Path, case: str, cells: int, fraction: float, device: str) -> dict:
    """One worker process on `root`'s package: this file run as a script, so that the package and the
    cases imported are `root`'s (PYTHONPATH), this folder alone ahead of them."""
    env = dict(os.environ, PYTHONPATH=str(root))
    cmd = [sys.executable, str(Path(__file__).resolve()), "--worker", f"{case}:{cells}", "--fraction", str(fraction),
           "--device", device]
    start = time.perf_counter()
    proc = subprocess.run(cmd, cwd=root, env=env, capture_output=True, text=True)
    if proc.returncode != 0:
        raise RuntimeError(f"the run of {case} at {cells} on {root} failed:\n{proc.stderr[-3000:]}")
    out = json.loads(proc.stdout.strip().splitlines()[-1])
    out["process_wall_s"] = time.perf_counter() - start  # start-up, run and exit, as the user waits
    return out


def peer_rows() -> list[list]:
    """The peer block's cost per simulated second from peer_comparison's stored result (medians of its
    rounds): seconds per step over simulated seconds per step, ours and each peer code's."""
    path = harness.RESULTS / "peer_comparison" / "cpu.json"
    if not path.exists():
        return []
    stored = json.loads(path.read_text())
    # A result written through the harness keeps the run's figures under "meta" and its commit and date
    # under "provenance"; an older one kept them at the top.
    meta, made = stored.get("meta", stored), stored.get("provenance", stored)
    rows = []
    for code in ("ours", "taichi-2t", "warp-mls"):
        rounds = [r[code] for r in stored.get("rounds", []) if code in r]
        if rounds:
            per_sim_s = statistics.median(r["seconds_per_step"] / r["dt_mean"] for r in rounds)
            rows.append([f"peer block ({meta['particles']:,} particles, 64^3), {code}; stored run of "
                         f"{made['date'][:10]} at {made['commit'].split()[0]}", "", "", "", "", "",
                         f"{per_sim_s:.3g} (wall)", "", ""])
    return rows


def pct(x) -> str:
    return "" if x is None else f"{100 * x:+.2f}%"


def main(argv=None):
    ap = harness.parser(__doc__.split("\n")[0], quick=f"{QUICK_CASES} to {QUICK_FRACTION} of the end time")
    ap.add_argument("--cases", default=None, help=f"case:cells, comma-separated (default {DEFAULT_CASES})")
    ap.add_argument("--fraction", type=float, default=None, help="run to this fraction of each case's end time (1)")
    ap.add_argument("--rounds", type=int, default=1, help="runs of each case (medians; alternating with --before)")
    ap.add_argument("--before", type=Path, help="a checkout of an earlier commit to run side by side")
    ap.add_argument("--worker", help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    fraction = args.fraction or (QUICK_FRACTION if args.quick else 1.0)
    if args.worker:
        case, cells = args.worker.split(":")
        print(json.dumps(worker(case, int(cells), fraction, args.device)))
        return 0
    specs = [(c.split(":")[0], int(c.split(":")[1]))
             for c in (args.cases or (QUICK_CASES if args.quick else DEFAULT_CASES)).split(",")]
    roots = {"now": harness.ROOT} | ({"before": args.before.resolve()} if args.before else {})
    results, rows = [], []
    for case, cells in specs:
        runs = {name: [] for name in roots}
        for r in range(args.rounds):  # alternating order: a change of load hits both alike
            for name in (list(roots) if r % 2 == 0 else list(roots)[::-1]):
                runs[name].append(run(roots[name], case, cells, fraction, args.device))
                x = runs[name][-1]
                print(f"{case} {cells} {name}: {x['steps']} steps, run {x['run_wall_s']:.1f} s wall, "
                      f"{x['run_cpu_s']:.1f} s CPU, start-up {x['startup_wall_s']:.1f} s, centroid "
                      f"{x['centroid_end']:.4f} {pct(x.get('centroid_end_error'))}", file=sys.stderr, flush=True)
        entry = {"case": case, "cells": cells, "fraction": fraction, "runs": runs}
        med = {name: {k: statistics.median(x[k] for x in rs) for k in
                      ("run_wall_s", "run_cpu_s", "startup_wall_s", "startup_cpu_s", "process_wall_s")}
               for name, rs in runs.items()}
        entry["medians"] = med
        if "before" in runs:
            entry["now_over_before"] = {k: med["now"][k] / med["before"][k] for k in ("run_wall_s", "run_cpu_s")}
        results.append(entry)
        for name, rs in runs.items():
            x, m = rs[0], med[name]
            rows.append([f"{case} {cells} ({name})" if args.before else f"{case} {cells}", f"{x['particles']:,}",
                         x["steps"], f"{x['t_end']:g}", f"{m['startup_wall_s']:.1f}",
                         f"{m['run_wall_s']:.1f} / {m['run_cpu_s']:.1f}",
                         f"{m['run_wall_s'] / x['t_end']:.3g} / {m['run_cpu_s'] / x['t_end']:.3g}",
                         pct(x.get("centroid_end_error")), pct(x.get("rise_speed_max_error"))])
    table = harness.markdown_table(
        ["run", "particles", "steps", "t_end (s)", "start-up (s, wall)", "run (s): wall / CPU",
         "s per simulated s: wall / CPU", "centroid at t_end vs published", "peak rise speed vs published"],
        rows + peer_rows(), "lrrrrrrrr")
    ratios = [f"- {e['case']} {e['cells']}: now / before, run wall {e['now_over_before']['run_wall_s']:.3f}, "
              f"CPU {e['now_over_before']['run_cpu_s']:.3f}" for e in results if "now_over_before" in e]
    if ratios:
        table += "\n" + "\n".join(ratios) + "\n"
    table += f"\nLoad average at the end (1, 5, 15 min): {', '.join(f'{v:.2f}' for v in os.getloadavg())}\n"
    harness.write_result("time_to_answer", args, {"cases": results, "load_average": os.getloadavg()}, table,
                         title="Time to an answer")
    return 0


if __name__ == "__main__":
    sys.exit(main())
