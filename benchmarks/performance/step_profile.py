"""The step broken into launches, and each stage against this CPU's limits (docs/performance.md,
"How close to the CPU's limit").

    python -m benchmarks.performance.step_profile                # Hysing case 1 at 40 cells, the peer block (64^3)
    python -m benchmarks.performance.step_profile --quick        # Hysing at 10 cells, a 16^3 peer block

Four measurements, in one process:
- launch costs: the host's CPU seconds (every thread's) per launch of a kernel that does nothing (a `Lines` box and two
  arrays, as the cell kernels take): `wp.launch`, a recorded launch (`record_cmd=True`), its replay,
  a replay after `set_param_by_name`, and two replays handed to the CPU's threads at once
  (core/threads.Parallel) against one after the other;
- the Hysing tank (benchmarks/validation/convergence.py's hysing_2d): after --warmup steps, per step:
  launches by kind (direct `wp.launch`, recordings, replays of recorded ones) and by kernel, kernel
  invocations and the CPU seconds of the thread inside Warp's native call (summed over threads: the
  "kernel bodies"; the rest of a step's CPU seconds is the host's), the calling thread's CPU seconds
  outside kernels (the host's serial part: the other threads wait for it) and the calls it handed to
  the other threads, the same for the pressure solve alone with its CG iterations (invocations per
  iteration);
- the stream bandwidth: numpy copies of 256 MB, on one thread and on two at once (read + write bytes,
  over each copying thread's CPU seconds);
- the peer block (benchmarks/performance/peer_comparison.py's scene): the CPU seconds of p2g's and
  g2p's kernels (summed over their parts) against the CPU seconds one thread needs to move the bytes
  each must move at least (each particle field it reads or writes once, PARTICLE_BYTES, plus the
  grid's face arrays once) at one thread's stream bandwidth; the same for the CG's kernels per
  iteration (the bytes of its passes over the solve's box, CG_BYTES_PER_CELL, an estimate: see
  below), and their CPU seconds per iteration per fluid cell.

CPU seconds rather than wall seconds throughout where it can: on a machine shared with other jobs
the wall clock mostly measures them.

The kernel bodies are timed by wrapping Warp's `invoke` (warp._src.context, a private name of Warp
1.19: a Warp that moved it fails here with an AttributeError). Timing every invocation costs about a microsecond each.
Writes benchmarks/results/step_profile/<device>[_quick].{json,md}.
"""

from __future__ import annotations

import collections
import math
import sys
import tempfile
import threading
import time

import numpy as np
import warp as wp

from benchmarks import harness
from warp_mpm_bubbles.core.lines import Lines, make_lines
from warp_mpm_bubbles.core.threads import Parallel

# Bytes per particle that p2g and g2p must read or write at least once (core/transfer_kernels.py):
# p2g reads x, v, C (3x3), mass, vol0, phase, active (76 B), and each further part of the split
# scans x and active again (16 B); g2p reads x, active, phase, J (24 B) and writes x, v, C, J and
# active (68 B).
PARTICLE_BYTES = {"p2g": 76, "p2g_scan_per_extra_part": 16, "g2p": 24 + 68}
# The CG's passes over the solve's box per iteration, bytes per cell of float32/int32 arrays read or
# written (core/pressure.py, core/multigrid.py): apply_operator 28 (d, types, diag, 3 face weights,
# Ad), step_solution 32, fluid_dot 12, update_direction 12, the V-cycle's finest level 8 half-sweeps
# x 28, restriction 28, prolongation 12; the coarser levels add about 1/7 in 3D.
CG_BYTES_PER_CELL = (28 + 32 + 12 + 12 + 8 * 28 + 28 + 12) * 8 / 7


@wp.kernel
def nothing(walk: Lines, a: wp.array3d(dtype=float), b: wp.array3d(dtype=float), c: float, row: int):
    pass


def launch_costs(n: int) -> dict:
    """Microseconds per launch of a kernel that does nothing (`nothing`), by kind."""
    a = wp.zeros((42, 82, 1), dtype=float)
    walk, dims = make_lines((0, 0, 0), a.shape, 2, "cpu")
    args = [walk, a, a, 1.0, 0]
    wp.launch(nothing, dims, inputs=args)  # loads the module
    recorded = wp.launch(nothing, dims, inputs=args, record_cmd=True)
    parallel = Parallel(2)

    def per_call(fn, reps=n):  # CPU seconds of the process (every thread): the host's cost, less the load's
        start = time.process_time()
        for _ in range(reps):
            fn()
        return 1e6 * (time.process_time() - start) / reps

    def set_and_replay():
        recorded.set_param_by_name("row", 1)
        recorded.launch()

    return {"wp.launch": per_call(lambda: wp.launch(nothing, dims, inputs=args)),
            "record (record_cmd=True)": per_call(lambda: wp.launch(nothing, dims, inputs=args, record_cmd=True)),
            "replay": per_call(recorded.launch), "set_param + replay": per_call(set_and_replay),
            "two replays, one after the other": per_call(lambda: (recorded.launch(), recorded.launch()), n // 4),
            "two replays at once on two threads (Parallel.run)":
                per_call(lambda: parallel.run([recorded.launch, recorded.launch]), n // 4)}


class LaunchCounter:
    """Counts launches by kind and kernel and times Warp's native calls, while entered."""

    def __init__(self):
        import warp._src.context as context

        self.context, self.lock = context, threading.Lock()
        self.kinds, self.kernels = collections.Counter(), collections.Counter()
        self.body_s, self.invokes = collections.Counter(), collections.Counter()
        self.caller, self.caller_body_s = threading.get_ident(), 0.0  # the thread that entered: the step's
        self.handoffs = 0  # calls handed to another thread (core/threads.Parallel.run)

    def __enter__(self):
        ctx, self.saved = self.context, (wp.launch, self.context.invoke, self.context.Launch.launch, Parallel.run)
        launch, invoke, replay, run = self.saved

        def counted_launch(kernel, *a, **kw):
            self.kinds["record" if kw.get("record_cmd") else "wp.launch"] += 1
            return launch(kernel, *a, **kw)

        def counted_replay(cmd, *a, **kw):
            self.kinds["replay"] += 1
            return replay(cmd, *a, **kw)

        def timed_invoke(kernel, *a):  # the calling thread's CPU seconds: robust to other jobs' load
            start = time.thread_time()
            try:
                return invoke(kernel, *a)
            finally:
                spent = time.thread_time() - start
                with self.lock:
                    self.body_s[kernel.key] += spent
                    self.invokes[kernel.key] += 1
                    if threading.get_ident() == self.caller:
                        self.caller_body_s += spent

        def counted_run(parallel, calls):
            if parallel.threads > 1:
                self.handoffs += min(len(calls), parallel.threads) - 1
            return run(parallel, calls)

        wp.launch, ctx.invoke, ctx.Launch.launch, Parallel.run = counted_launch, timed_invoke, counted_replay, counted_run
        return self

    def __exit__(self, *exc):
        wp.launch, self.context.invoke, self.context.Launch.launch, Parallel.run = self.saved


def profile_steps(sim, steps: int) -> dict:
    """Per step: wall and CPU ms, launches by kind, kernel invocations and kernel-body ms; the solve's
    share; the slowest kernels."""
    solve = sim.solver.solve
    info = {"s": 0.0, "cpu": 0.0, "body": 0.0, "invokes": 0, "iterations": 0, "host": 0.0}

    def timed_solve(*a, **kw):
        before, count = sum(counter.body_s.values()), sum(counter.invokes.values())
        start, cpu = time.perf_counter(), time.process_time()
        caller, caller_body = time.thread_time(), counter.caller_body_s
        result = solve(*a, **kw)
        info["s"] += time.perf_counter() - start
        info["cpu"] += time.process_time() - cpu
        info["host"] += time.thread_time() - caller - (counter.caller_body_s - caller_body)
        info["body"] += sum(counter.body_s.values()) - before
        info["invokes"] += sum(counter.invokes.values()) - count
        info["iterations"] += result.iterations
        return result

    sim.solver.solve = timed_solve
    sim.timer.seconds.clear()
    try:
        with LaunchCounter() as counter:
            s0, wall, cpu = sim.stats.steps, time.perf_counter(), time.process_time()
            caller = time.thread_time()
            for _ in range(steps):
                sim.step(sim.stable_dt())
            caller = time.thread_time() - caller
            wall, cpu, n = time.perf_counter() - wall, time.process_time() - cpu, sim.stats.steps - s0
    finally:
        sim.solver.solve = solve
    ms = lambda s: round(1e3 * s / n, 3)  # noqa: E731
    return {"steps": n, "wall_ms": ms(wall), "cpu_ms": ms(cpu), "stages_ms": {k: ms(v) for k, v in sim.timer.seconds.items()},
            # The calling thread's CPU outside kernels: the host's serial part (the other threads wait).
            "calling_thread": {"cpu_ms": ms(caller), "kernel_body_ms": ms(counter.caller_body_s),
                               "host_ms": ms(caller - counter.caller_body_s)},
            "handoffs_per_step": counter.handoffs / n,
            "launches_per_step": {k: v / n for k, v in counter.kinds.items()},
            "invokes_per_step": sum(counter.invokes.values()) / n, "kernel_body_ms": ms(sum(counter.body_s.values())),
            "solve": {"ms": ms(info["s"]), "cpu_ms": ms(info["cpu"]), "kernel_body_ms": ms(info["body"]),
                      "calling_thread_host_ms": ms(info["host"]), "invokes_per_step": info["invokes"] / n,
                      "cg_iterations_per_step": info["iterations"] / n,
                      "invokes_per_iteration": info["invokes"] / max(info["iterations"], 1)},
            "kernels": {k: {"ms": ms(v), "per_step": counter.invokes[k] / n, "us_each": 1e6 * v / counter.invokes[k]}
                        for k, v in counter.body_s.most_common()}}


def stream_bandwidth() -> dict:
    """GB/s of numpy copies of 256 MB (read + write bytes), best of 5, on one thread and on two at once,
    each copy timed by its thread's CPU seconds (a copy stalled on memory counts; one descheduled by
    other jobs does not)."""
    a = np.ones(64 * 2**20, np.float32)
    b = np.empty_like(a)
    out = {}
    for threads in (1, 2):
        cuts = [q * a.size // threads for q in range(threads + 1)]
        best = math.inf
        for _ in range(5):
            spent = []

            def copy(lo, hi):
                start = time.thread_time()
                np.copyto(b[lo:hi], a[lo:hi])
                spent.append(time.thread_time() - start)

            parts = [threading.Thread(target=copy, args=(lo, hi)) for lo, hi in zip(cuts, cuts[1:])]
            for t in parts:
                t.start()
            for t in parts:
                t.join()
            best = min(best, max(spent))
        out[f"{threads} thread(s)"] = 2 * a.nbytes / best / 1e9
    return out


def peer_bounds(profile: dict, sim, bandwidth: float) -> dict:
    """p2g, g2p and the CG iteration: their kernels' CPU ms (summed over threads) against the CPU ms of
    their least traffic at `bandwidth` (one thread's)."""
    from warp_mpm_bubbles.core.grid import FLUID

    n, threads = sim.num_particles, sim.parallel.threads
    box = sim.solver.box
    box_cells = math.prod(h - l for l, h in zip(*box))  # noqa: E741
    faces = sum(math.prod(s) for s in (sim.grid.face_shape(a) for a in range(3)))
    fluid = int((sim.fields.types.numpy() == FLUID).sum())
    moved = {"p2g": n * (PARTICLE_BYTES["p2g"] + (threads - 1) * PARTICLE_BYTES["p2g_scan_per_extra_part"]) + faces * 8,
             "g2p": n * PARTICLE_BYTES["g2p"] + faces * 4}
    kernels = {"p2g": f"p2g_{sim.grid.dim}d", "g2p": f"g2p_advect_{sim.grid.dim}d"}
    out = {name: {"measured_ms": profile["kernels"][kernels[name]]["ms"], "bytes": b, "bound_ms": 1e3 * b / (bandwidth * 1e9)}
           for name, b in moved.items()}
    solve = profile["solve"]
    per_iteration = solve["kernel_body_ms"] / max(solve["cg_iterations_per_step"], 1e-9)
    cg_bytes = box_cells * CG_BYTES_PER_CELL
    out["CG iteration"] = {"measured_ms": per_iteration, "bytes": cg_bytes, "bound_ms": 1e3 * cg_bytes / (bandwidth * 1e9),
                           "ns_per_fluid_cell": 1e6 * per_iteration / fluid, "fluid_cells": fluid, "box_cells": box_cells}
    for v in out.values():
        v["measured_over_bound"] = v["measured_ms"] / v["bound_ms"]
    return out


def main(argv=None):
    ap = harness.parser(__doc__.split("\n")[0], quick="Hysing at 10 cells, a 16^3 peer block, fewer steps")
    ap.add_argument("--hysing", type=int, default=40, help="Hysing tank: cells across (40; 0: skip)")
    ap.add_argument("--peer-grid", type=int, default=64, help="the peer block's grid (64; 0: skip)")
    ap.add_argument("--warmup", type=int, default=20, help="untimed steps first (20)")
    ap.add_argument("--steps", type=int, default=40, help="profiled steps of the Hysing tank (40; the peer block: a fifth)")
    args = ap.parse_args(argv)
    if args.quick:
        args.hysing, args.peer_grid, args.warmup, args.steps = 10, 16, 3, 10
    wp.config.quiet = True
    wp.init()
    from benchmarks.performance.peer_comparison import block_scene
    from benchmarks.validation.convergence import CASES, scene
    from warp_mpm_bubbles.core.simulation import Simulation

    data = {"launch_costs_us": launch_costs(2000 if args.quick else 20000)}
    if args.hysing:
        with tempfile.TemporaryDirectory() as tmp:
            sim = Simulation(scene(CASES["hysing_2d"], args.hysing, tmp), args.device)
            for _ in range(args.warmup):
                sim.step(sim.stable_dt())
            data["hysing"] = {"cells": args.hysing, "particles": sim.num_particles, **profile_steps(sim, args.steps)}
    data["stream_GBps"] = stream_bandwidth()
    if args.peer_grid:
        with tempfile.TemporaryDirectory() as tmp:
            sim = Simulation(block_scene(args.peer_grid, 1.0, tmp), args.device)
            for _ in range(3):
                sim.step(sim.stable_dt())
            peer = profile_steps(sim, max(args.steps // 5, 2))
            data["peer"] = {"grid": args.peer_grid, "particles": sim.num_particles, **peer,
                            "bounds": peer_bounds(peer, sim, data["stream_GBps"]["1 thread(s)"])}
    harness.write_result("step_profile", args, data, markdown(data), title="The step broken into launches")
    return 0


def markdown(d: dict) -> str:
    costs = harness.markdown_table(["launch", "host CPU us"], [[k, f"{v:.1f}"] for k, v in d["launch_costs_us"].items()])
    rows = []
    for name in ("hysing", "peer"):
        if name in d:
            p, s = d[name], d[name]["solve"]
            kinds = ", ".join(f"{k} {v:.1f}" for k, v in p["launches_per_step"].items())
            kinds += f", hand-offs {p['handoffs_per_step']:.1f}"
            rows.append([name, f"{p['particles']:,}", f"{p['wall_ms']:.1f} / {p['cpu_ms']:.1f}",
                         f"{p['calling_thread']['host_ms']:.1f}", kinds,
                         f"{p['invokes_per_step']:.0f}", f"{p['kernel_body_ms']:.1f}", f"{s['ms']:.1f} / {s['cpu_ms']:.1f}",
                         f"{s['kernel_body_ms']:.1f}", f"{s['calling_thread_host_ms']:.1f}", f"{s['cg_iterations_per_step']:.2f}",
                         f"{s['invokes_per_iteration']:.1f}"])
    steps = harness.markdown_table(["scene", "particles", "step ms: wall / CPU", "calling thread outside kernels, CPU ms",
                                    "launches per step", "invocations",
                                    "kernel bodies, CPU ms", "solve ms: wall / CPU", "solve's kernel bodies, CPU ms",
                                    "solve: calling thread outside kernels, CPU ms", "CG iterations",
                                    "invocations per iteration"], rows)
    out = "## Host cost per launch\n\n" + costs + "\n## Per step\n\n" + steps
    out += "\nStream bandwidth (numpy copy, read + write): " + ", ".join(
        f"{k} {v:.1f} GB/s" for k, v in d["stream_GBps"].items()) + "\n"
    if "peer" in d:
        out += "\n## The peer block's kernels against one thread's stream bandwidth (CPU ms a step)\n\n" + harness.markdown_table(
            ["stage", "kernels' CPU ms", "least bytes (MB)", "CPU ms at stream bandwidth", "measured / bound"],
            [[k, f"{v['measured_ms']:.2f}", f"{v['bytes'] / 1e6:.1f}", f"{v['bound_ms']:.2f}", f"{v['measured_over_bound']:.1f}"]
             for k, v in d["peer"]["bounds"].items()])
        cg = d["peer"]["bounds"]["CG iteration"]
        out += (f"\nCG: {cg['ns_per_fluid_cell']:.0f} CPU ns per fluid cell per iteration ({cg['fluid_cells']:,} fluid "
                f"cells, a box of {cg['box_cells']:,})\n")
    for name in ("hysing", "peer"):
        if name in d:
            out += f"\n## Slowest kernels, {name} (CPU ms per step, summed over threads)\n\n" + harness.markdown_table(
                ["kernel", "ms", "per step", "us each"],
                [[k, f"{v['ms']:.2f}", f"{v['per_step']:.1f}", f"{v['us_each']:.1f}"]
                 for k, v in list(d[name]["kernels"].items())[:20]])
    return out


if __name__ == "__main__":
    sys.exit(main())
