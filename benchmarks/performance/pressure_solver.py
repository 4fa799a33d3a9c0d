"""Pressure solver: CG iterations and solve time of each preconditioner against resolution.

    python -m benchmarks.performance.pressure_solver             # 2D 64..256, 3D 32 and 64, on the CPU
    python -m benchmarks.performance.pressure_solver --sizes-2d 64 --sizes-3d 32 --device cuda:0
    python -m benchmarks.performance.pressure_solver --quick     # 2D 32, 3D 16: a smoke run

Problems (built directly as PressureSystem arrays, no particles), domain [1]^dim m in N^dim cells,
dx = 1/N, solid walls all round (ghost layer), y up:
- tank: water (rho 1000) up to y = 0.6 + 0.3 dx, empty (p = 0) above; the surface faces carry the
  ghost-fluid 1/theta of the surface's position.
- bubbles: the same with 5 gas bubbles (rho 1.2, radius 0.06 .. 0.12 m) inside the water: gas cells
  have extra_diag = kappa/dt^2 with kappa = 1/101325 Pa^-1, dt = 0.5 dx / sqrt(9.81 dx); a face
  between a liquid and a gas cell takes 1/rho with rho = theta rho_l + (1 - theta) rho_g, theta the
  liquid share of the segment between the centres (ghost fluid; from the bubbles' distance field).
Right-hand side: b = -div(u*)/dt with u* = dt g plus a smooth random velocity of amplitude
0.05 m/s and a cell-scale random velocity of 0.01 m/s (particle noise), normal velocity zero on
solid faces; x starts at 0; tolerance 1e-5 on ||r|| / ||b|| (the scenes' cg_tolerance).
All kernels are compiled or loaded first, by solves on an 8^dim grid. Each case is then solved
--repeat times with jacobi and multigrid (the best time is reported; the first multigrid solve on
a grid includes allocating its levels) and once with none. Writes
benchmarks/results/pressure_solver/<device>.{json,md}.
"""

from __future__ import annotations

import sys
import time

import numpy as np
import warp as wp

from warp_mpm_bubbles.core.grid import EMPTY, FLUID, SOLID_FREE_SLIP
from warp_mpm_bubbles.core.pressure import PRECONDITIONERS, PressureSolver, PressureSystem

from benchmarks import harness

RHO_LIQUID, RHO_GAS, P_ATM, G = 1000.0, 1.2, 101325.0, 9.81
SURFACE = 0.6
BUBBLES = [((0.3, 0.25, 0.5), 0.1), ((0.7, 0.3, 0.4), 0.12), ((0.5, 0.45, 0.6), 0.08),
           ((0.2, 0.47, 0.3), 0.06), ((0.8, 0.12, 0.7), 0.07)]
TOL = 1e-5


def problem(n: int, dim: int, bubbles: bool, seed: int = 0):
    """(types, inv_rho faces, extra_diag, b, dx) for the tank (with or without bubbles) at N = n."""
    dx = 1.0 / n
    dt = 0.5 * dx / np.sqrt(G * dx)
    shape = (n + 2, n + 2, n + 2 if dim == 3 else 1)
    centre = (np.indices(shape).transpose(1, 2, 3, 0) - [1, 1, 1 if dim == 3 else 0] + 0.5) * dx
    if dim == 2:
        centre[..., 2] = 0.5
    surface = SURFACE + 0.3 * dx
    phi_surface = surface - centre[..., 1]  # > 0 in the water
    phi_gas = np.full(shape, np.inf)  # < 0 inside a bubble
    if bubbles:
        for c, r in BUBBLES:
            d = centre[..., :dim] - np.asarray(c[:dim])
            phi_gas = np.minimum(phi_gas, np.sqrt((d * d).sum(-1)) - r)
    types = np.where(phi_surface > 0, FLUID, EMPTY).astype(np.int32)
    walls = np.zeros(shape, bool)
    for a in range(dim):
        walls |= (np.arange(shape[a]) == 0).reshape([-1 if b == a else 1 for b in range(3)])
        walls |= (np.arange(shape[a]) == shape[a] - 1).reshape([-1 if b == a else 1 for b in range(3)])
    types[walls] = SOLID_FREE_SLIP
    gas = (types == FLUID) & (phi_gas < 0)
    inv_rho_cell = np.where(gas, 1.0 / RHO_GAS, 1.0 / RHO_LIQUID)
    extra = np.where(gas, 1.0 / (P_ATM * dt * dt), 0.0)

    rng = np.random.default_rng(seed)
    faces, vel = [], []
    for a in range(3):
        fshape = list(shape)
        fshape[a] += 1
        w = np.zeros(fshape)
        u = np.zeros(fshape)
        if a < dim:
            lo = [slice(None)] * 3
            hi = [slice(None)] * 3
            lo[a], hi[a] = slice(0, -1), slice(1, None)
            inner = tuple(slice(1, -1) if b == a else slice(None) for b in range(3))
            t_lo, t_hi = types[tuple(lo)], types[tuple(hi)]
            fluid_lo, fluid_hi = t_lo == FLUID, t_hi == FLUID
            open_face = (t_lo <= FLUID) & (t_hi <= FLUID) & (fluid_lo | fluid_hi)
            w_in = np.zeros(open_face.shape)
            # fluid-fluid: liquid, gas, or a liquid-gas face by the ghost-fluid density
            g_lo, g_hi = gas[tuple(lo)], gas[tuple(hi)]
            pg_lo, pg_hi = phi_gas[tuple(lo)], phi_gas[tuple(hi)]
            both = fluid_lo & fluid_hi
            w_in[both] = 1.0 / RHO_LIQUID
            w_in[both & g_lo & g_hi] = 1.0 / RHO_GAS
            mixed = both & (g_lo != g_hi)
            with np.errstate(divide="ignore", invalid="ignore"):
                theta = np.clip(np.maximum(pg_lo, pg_hi) / np.abs(pg_hi - pg_lo), 0.0, 1.0)  # liquid share
            w_in[mixed] = 1.0 / (theta[mixed] * RHO_LIQUID + (1 - theta[mixed]) * RHO_GAS)
            # fluid-empty: p = 0 at the surface, theta of the way from the fluid centre
            ps_lo, ps_hi = phi_surface[tuple(lo)], phi_surface[tuple(hi)]
            with np.errstate(divide="ignore", invalid="ignore"):
                th_s = np.clip(np.maximum(ps_lo, ps_hi) / np.abs(ps_lo - ps_hi), 0.1, 1.0)
            inv_cell = np.where(fluid_lo, inv_rho_cell[tuple(lo)], inv_rho_cell[tuple(hi)])
            surf = open_face & ~both
            w_in[surf] = inv_cell[surf] / th_s[surf]
            w[inner] = np.where(open_face, w_in, 0.0)
            # velocity: gravity, a smooth random field, cell-scale noise; zero on solid faces
            x = (np.indices(fshape).transpose(1, 2, 3, 0) + 0.5 - 0.5 * np.eye(3)[a]) * dx
            smooth = sum(rng.normal() * np.sin(np.pi * (m + 1) * x[..., (a + 1) % dim] + rng.uniform(0, 6))
                         * np.cos(np.pi * (m + 1) * x[..., a]) for m in range(3))
            u = 0.05 * smooth / 3 + 0.01 * rng.normal(size=fshape) - (dt * G if a == 1 else 0.0)
            solid = np.zeros(fshape, bool)
            solid[inner] = (t_lo > FLUID) | (t_hi > FLUID)
            solid[tuple(slice(0, 1) if b == a else slice(None) for b in range(3))] = True
            solid[tuple(slice(-1, None) if b == a else slice(None) for b in range(3))] = True
            u[solid] = 0.0
        faces.append(w)
        vel.append(u)
    div = sum(np.diff(vel[a], axis=a) for a in range(dim)) / dx
    b = np.where(types == FLUID, -div / dt, 0.0)
    return types, faces, extra, b, dx


def warm_up(dev):
    """Compile (or load) every kernel once, on a small problem, so no timed solve includes it."""
    for dim in (2, 3):
        types, faces, extra, b_np, dx = problem(8, dim, True)
        system, n_fluid, singular = PressureSystem.from_numpy(types, faces, extra, dx, dim, dev)
        solver = PressureSolver(types.shape, dim, dx, dev)
        for pc in PRECONDITIONERS:
            b = wp.array(b_np.astype(np.float32), dtype=float, device=dev)
            x = wp.zeros(types.shape, dtype=float, device=dev)
            solver.solve(system, b, x, tol=TOL, max_iter=1000, singular=singular, n_fluid=n_fluid, preconditioner=pc)
    wp.synchronize_device(dev)


def run(n, dim, bubbles, dev, repeat):
    types, faces, extra, b_np, dx = problem(n, dim, bubbles)
    system, n_fluid, singular = PressureSystem.from_numpy(types, faces, extra, dx, dim, dev)
    solver = PressureSolver(types.shape, dim, dx, dev)
    b = wp.array(b_np.astype(np.float32), dtype=float, device=dev)
    x = wp.zeros(types.shape, dtype=float, device=dev)
    out = {"n": n, "dim": dim, "bubbles": bubbles, "cells": int(np.prod(types.shape)), "fluid_cells": n_fluid,
           "gas_cells": int(((types == FLUID) & (extra > 0)).sum()), "multigrid_levels": None}
    solutions = {}
    for pc in PRECONDITIONERS:
        times = []
        for _ in range(1 if pc == "none" else repeat):  # "none" is slow and has nothing to warm up
            x.zero_()
            wp.synchronize_device(dev)
            t0 = time.perf_counter()
            info = solver.solve(system, b, x, tol=TOL, max_iter=100000, singular=singular, n_fluid=n_fluid,
                                preconditioner=pc)
            wp.synchronize_device(dev)
            times.append(time.perf_counter() - t0)
        solutions[pc] = x.numpy().astype(np.float64).copy()
        out[pc] = {"iterations": info.iterations, "seconds": min(times), "seconds_all": times,
                   "residual": info.residual, "converged": info.converged}
        print(f"  {dim}D N={n} {'bubbles' if bubbles else 'tank'} {pc}: {info.iterations} iterations, "
              f"{min(times):.3f} s, residual {info.residual:.2e}", file=sys.stderr, flush=True)
    out["multigrid_levels"] = [list(s) for s in solver.multigrid.shapes]
    ref = solutions["jacobi"]
    out["max_rel_difference_to_jacobi"] = {
        pc: float(np.abs(s - ref).max() / max(np.abs(ref).max(), 1e-30)) for pc, s in solutions.items()}
    return out


def markdown(meta, rows) -> str:
    out = [f"- problems: {meta['problems']}",
           f"- tolerance {TOL:g} on ||r||/||b||, x0 = 0; seconds: best of {meta['repeat']} solves (none: 1), "
           "kernels compiled beforehand; the build of the multigrid levels is inside each solve", "",
           "| problem | grid | fluid cells (gas) | " + " | ".join(f"{p}: iterations, s" for p in PRECONDITIONERS)
           + " | speed-up multigrid vs jacobi |",
           "|---|---|---:|" + "---:|" * len(PRECONDITIONERS) + "---:|"]
    for r in rows:
        grid = f"{r['n']}^{r['dim']}"
        cells = f"{r['fluid_cells']:,}" + (f" ({r['gas_cells']:,})" if r["bubbles"] else "")
        cols = [f"{r[p]['iterations']}{'' if r[p]['converged'] else ' (not converged)'}, {r[p]['seconds']:.3f}"
                for p in PRECONDITIONERS]
        speed = r["jacobi"]["seconds"] / r["multigrid"]["seconds"]
        out.append(f"| {'bubbles 1000:1' if r['bubbles'] else 'tank'} ({r['dim']}D) | {grid} | {cells} | "
                   + " | ".join(cols) + f" | {speed:.1f}x |")
    return "\n".join(out) + "\n"


def main(argv=None) -> int:
    ap = harness.parser(__doc__.split("\n")[0], quick="2D N = 32 and 3D N = 16, one timed solve each")
    ap.add_argument("--sizes-2d", default="64,128,256", help="comma-separated N for N^2 grids")
    ap.add_argument("--sizes-3d", default="32,64", help="comma-separated N for N^3 grids")
    ap.add_argument("--repeat", type=int, default=2, help="timed solves per case (default 2; the best counts)")
    args = ap.parse_args(argv)
    if args.quick:
        args.sizes_2d, args.sizes_3d, args.repeat = "32", "16", 1
    wp.config.quiet = True
    wp.init()
    dev = wp.get_device(args.device)
    meta = {
        "problems": "tank: water to y = 0.6 m with a free surface; bubbles: the same with 5 gas bubbles at "
                    "rho 1000:1.2 and extra_diag = kappa/dt^2 (see the script's docstring)",
        "repeat": args.repeat,
    }
    cases = [(int(s), 2) for s in args.sizes_2d.split(",") if s.strip()]
    cases += [(int(s), 3) for s in args.sizes_3d.split(",") if s.strip()]
    warm_up(dev)
    rows = [run(n, dim, bubbles, dev, args.repeat) for n, dim in cases for bubbles in (False, True)]
    text = markdown(meta, rows)
    print(text)
    harness.write_result("pressure_solver", args, {"meta": meta, "results": rows}, text,
                         title=f"Pressure solver: PCG iterations and solve time on {harness.describe_device(args.device)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
