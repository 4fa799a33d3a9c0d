"""Explicit vs implicit viscosity side by side, in one process (docs/viscosity.md, "Measured").

    python -m benchmarks.performance.viscous_solver --cells 20   # tank to t = 0.29 s and Taylor-Green: ~4 min on the CPU
    python -m benchmarks.performance.viscous_solver --cells 40 --t-end 0.05 --no-taylor-green --label 40  # ~2 min
    python -m benchmarks.performance.viscous_solver --cells 20 --t-end 0.1 --max-dt 8e-5 --no-taylor-green --label 20_same_steps  # ~5 min
    python -m benchmarks.performance.viscous_solver --quick      # 10 cells, a few ms of simulated time
    python -m benchmarks.performance.viscous_solver --hysing 40 --label hysing40   # Hysing case 1 to t = 3 only
    python -m benchmarks.performance.viscous_solver --hysing 80 --hysing-t-end 0.3 --density-ratio 1000 --label ratio1000_80
    python -m benchmarks.performance.viscous_solver --hysing 80 --hysing-t-end 1.0 --label hysing80   # t = 1 of 3

tank: the case the implicit solve was built for. A closed 2D tank W x 2W filled with liquid (no-slip top and bottom,
    free-slip sides), an incompressible-gas bubble of radius W/4 at (W/2, W/2): Hysing et al.
    (2009) test case 1 (density ratio 10, Eo 10, Re 35; W = 4.5 cm so that sigma = 0.5 N/m) but
    with the gas's kinematic viscosity 10x the liquid's (mu 0.86 Pa s in both), which makes the
    explicit limit bind. 0.29 s is Hysing's t = 3.
hysing: benchmarks/validation/convergence.py's Hysing case 1 tank (--hysing CELLS; implicit, auto), the
    low-Reynolds run where the viscous solve once cost as much as the pressure solve; with
    --density-ratio 1000 its gas is 1000x lighter than the liquid and 100x less viscous (Hysing's
    case 2 fluids at case 1's Eo).
taylor_green: the low-viscosity case. The Taylor-Green cell of tests/test_viscosity.py (nu 1e-3,
    32 cells) at the stress form's explicit limit, where explicit needs no extra steps.

For each: steps, wall time, the viscosity stage's seconds and share of the step (the run's stage
timer) and its CPU seconds (the process's, all threads, while the stage ran: on a shared machine wall
time waits for a core), the implicit solve's PCG iterations, and the state at the end (bubble
centroid height and rise speed; Taylor-Green amplitude) to show the solvers agree. The implicit solve
runs with each preconditioner ("sgs", the default; "jacobi", the diagonal it replaced; "multigrid",
a V-cycle per component), side by side; the Hysing runs also with the warm start off ("cold").
Writes benchmarks/results/viscous_solver/<device>[_<label>].{json,md}. A measurement, not a test.
"""

from __future__ import annotations

from dataclasses import replace

import time

import numpy as np
import warp as wp

from warp_mpm_bubbles import Box, Domain, Material, Output, Scene, SolverSettings, Sphere
from warp_mpm_bubbles.core.grid import PHASE_GAS
from warp_mpm_bubbles.core.simulation import Simulation
from warp_mpm_bubbles.scene.effects import Viscosity

from benchmarks import harness


W = 0.045  # m: Hysing's 1 x 2 tank scaled so that sigma fits the bounds (0.5 N/m), Eo 10, Re 35
MU = 1000.0 * (9.81 * W / 2) ** 0.5 * (W / 2) / 35.0  # 0.86 Pa s in both phases: the gas's nu is 10x


def tank(cells: int, solver: str, max_dt: float | None = None) -> Scene:
    walls = {"x_min": "free_slip", "x_max": "free_slip", "y_min": "no_slip", "y_max": "no_slip"}
    return Scene(domain=Domain(size=(W, 2 * W), cell_size=W / cells, walls=walls),
                 materials={"liquid": Material("liquid", density=1000.0, viscosity=MU, surface_tension=0.5),
                            "gas": Material("gas", kind="gas", density=100.0, viscosity=MU, eos="incompressible")},
                 shapes=[Box("liquid", (0.0, 0.0), (W, 2 * W)), Sphere("gas", (W / 2, W / 2), W / 4)],
                 solver=SolverSettings(max_dt=max_dt),
                 effects={"viscosity": Viscosity(solver=solver)},
                 output=Output(path="/tmp/viscous_solver.usdc", fps=10))


def taylor_green(cells: int, solver: str) -> Scene:
    L, nu = 0.1, 1e-3
    return Scene(domain=Domain(size=(L, L), cell_size=L / cells, gravity=(0.0, 0.0)),
                 materials={"water": Material("water", viscosity=nu * 1000.0)},
                 shapes=[Box("water", (0.0, 0.0), (L, L))],
                 solver=SolverSettings(max_dt=(L / cells) ** 2 / (8 * nu)),
                 effects={"viscosity": Viscosity(solver=solver)},
                 output=Output(path="/tmp/viscous_solver.usdc", fps=10))


def start_taylor_green(sim):
    L = sim.scene.domain.size[0]
    x = sim.particles.x.numpy()
    kx, ky = np.pi * x[:, 0] / L, np.pi * x[:, 1] / L
    v = np.zeros_like(x)
    v[:, 0], v[:, 1] = 0.01 * np.sin(kx) * np.cos(ky), -0.01 * np.cos(kx) * np.sin(ky)
    sim.particles.v = wp.array(v.astype(np.float32), dtype=wp.vec3, device=sim.device)


def hysing(cells: int, density_ratio: int) -> Scene:
    from benchmarks.validation.convergence import CASES, SCALE, scene
    made = scene(CASES["hysing_2d"], cells, "/tmp")
    if density_ratio == 1000:
        materials = dict(made.materials)
        materials["bubble"] = replace(materials["bubble"], density=1 * SCALE, viscosity=0.1 * SCALE)
        made = replace(made, materials=materials)
    return made


def run(case: str, cells: int, solver: str, t_end: float, max_dt: float | None = None, device="cpu",
        preconditioner: str = "sgs", density_ratio: int = 10, warm_start: bool = True) -> dict:
    scene = (tank(cells, solver, max_dt) if case == "tank" else taylor_green(cells, solver) if case == "taylor_green"
             else hysing(cells, density_ratio))
    sim = Simulation(scene, device)
    stage = sim.stage("viscosity")
    stage.solver.preconditioner, stage.solver.warm_start = preconditioner, warm_start
    cpu = [0.0]
    force = stage.force

    def timed_force(ctx, dt):  # the stage's CPU seconds (process time: every thread)
        t = time.process_time()
        force(ctx, dt)
        cpu[0] += time.process_time() - t

    stage.force = timed_force
    if case == "taylor_green":
        start_taylor_green(sim)
    start, start_cpu = time.perf_counter(), time.process_time()
    sim.advance_to(t_end)
    wall, total_cpu = time.perf_counter() - start, time.process_time() - start_cpu
    p = sim.particles_numpy()
    seconds = sim.timer.seconds
    name = preconditioner if warm_start else f"{preconditioner}, cold"
    row = {"case": case, "cells": cells, "solver": solver if solver == "explicit" else f"{solver} ({name})",
           "t_end": t_end, "steps": sim.stats.steps, "wall_s": round(wall, 2),
           "ms_per_step": round(1e3 * wall / sim.stats.steps, 2), "viscosity_s": round(seconds.get("viscosity", 0.0), 2),
           "viscosity_share": seconds.get("viscosity", 0.0) / sum(seconds.values()),
           "viscosity_cpu_s": round(cpu[0], 2), "cpu_s": round(total_cpu, 2), **stage.counts,
           "explicit_limit_s": stage.explicit_limit(sim.ctx)}
    if case != "taylor_green":
        gas = p["phase"] == PHASE_GAS
        w = p["volume"][gas]
        row["centroid_y"] = float((p["positions"][gas, 1] * w).sum() / w.sum())
        row["rise_speed"] = float((p["velocities"][gas, 1] * w).sum() / w.sum())
    return row


RUNS = [("explicit", "sgs"), ("implicit", "sgs"), ("implicit", "jacobi")]  # (solver, implicit preconditioner)
HYSING_RUNS = [("sgs", True), ("sgs", False), ("multigrid", True)]  # (preconditioner, warm start)


def main(argv=None):
    ap = harness.parser(__doc__.split("\n")[0], quick="tank at 10 cells to t = 0.005 s, Taylor-Green to t = 0.02 s")
    ap.add_argument("--cells", default="20", help="tank cells across (comma-separated)")
    ap.add_argument("--t-end", type=float, default=0.29, help="tank: simulated seconds (Hysing's t = 3)")
    ap.add_argument("--max-dt", type=float, default=None, help="tank: the same steps for both solvers")
    ap.add_argument("--no-taylor-green", action="store_true")
    ap.add_argument("--hysing", default="", help="only the Hysing tank at these cells across (comma-separated)")
    ap.add_argument("--hysing-t-end", type=float, default=3.0, help="Hysing tank: simulated seconds")
    ap.add_argument("--density-ratio", type=int, default=10, choices=(10, 1000), help="Hysing tank: liquid/gas")
    args = ap.parse_args(argv)
    tg_end = 0.5
    if args.quick:
        args.cells, args.t_end, tg_end = "10", 0.005, 0.02
    wp.config.quiet = True
    rows = []
    if args.hysing:  # only the Hysing tank, at its default settings, with each preconditioner
        args.cells, args.no_taylor_green = "", True
        for cells in (int(c) for c in args.hysing.split(",")):
            for pre, warm in HYSING_RUNS:
                rows.append(run(f"hysing_{args.density_ratio}", cells, "auto", args.hysing_t_end, device=args.device,
                                preconditioner=pre, density_ratio=args.density_ratio, warm_start=warm))
                print(rows[-1], flush=True)
    for cells in (int(c) for c in args.cells.split(",") if c):
        for solver, pre in RUNS:
            rows.append(run("tank", cells, solver, args.t_end, args.max_dt, args.device, pre))
            print(rows[-1], flush=True)
    for solver, pre in () if args.no_taylor_green else RUNS:
        rows.append(run("taylor_green", 32, solver, tg_end, device=args.device, preconditioner=pre))
        print(rows[-1], flush=True)
    lines = ["| case | cells | solver | steps | wall s | ms/step | viscosity s (share) | viscosity CPU s (share) | "
             "PCG its (max) | its/solve | explicit limit s | centroid y | rise speed |",
             "|---|---:|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|"]
    for r in rows:
        per_solve = r["pcg_iterations"] / max(1, r["implicit_steps"])
        lines.append(f"| {r['case']} | {r['cells']} | {r['solver']} | {r['steps']} | {r['wall_s']} | {r['ms_per_step']} | "
                     f"{r['viscosity_s']} ({100 * r['viscosity_share']:.1f}%) | "
                     f"{r['viscosity_cpu_s']} ({100 * r['viscosity_cpu_s'] / r['cpu_s']:.1f}%) | "
                     f"{r['pcg_iterations']} ({r['pcg_max_iterations']}) | {per_solve:.2f} | {r['explicit_limit_s']:.3g} | "
                     f"{r.get('centroid_y', float('nan')):.4f} | {r.get('rise_speed', float('nan')):.4f} |")
    print("\n".join(lines))
    harness.write_result("viscous_solver", args, {"rows": rows}, "\n".join(lines),
                         title="Explicit vs implicit viscosity")


if __name__ == "__main__":
    main()
