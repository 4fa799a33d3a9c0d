"""Cost in proportion to the liquid: the same water block in its tight box and in
a domain 8x larger (2x per axis), per step and per stage; and the pressure stage before and after.

    python -m benchmarks.performance.domain_scaling                      # 16^3-cell block: 24^3 and 48^3 domains
    python -m benchmarks.performance.domain_scaling --block 32 --steps 3 # the peer's 32^3 block: 40^3 and 80^3
    python -m benchmarks.performance.domain_scaling --peer-grid 64 --label peer64  # before/after on the full peer grid
    python -m benchmarks.performance.domain_scaling --quick              # 8^3 block, peer grid 16, 1 round

Part 1, scaling. A W^3-cell water block (--block W) at 8 particles per cell falls freely in a closed
free-slip box; "tight": the domain is the block plus --margin cells on every side; "8x": the domain
doubled per axis, the block in its middle. Both are stepped with the same fixed dt (the tight case's
stable_dt at the start), so both see the same physics (the block never reaches a wall; the CG
iteration counts are printed). Configurations: tight and 8x as the step runs now (grid stages on the
particles' box, core/active_box.py; the solve on the fluid's box), and 8x with whole-grid launches
for both (ActiveRegion(enabled=False), PressureSolver(active_box=False)): the cost before the active box.

Part 2, pressure before/after on the peer configuration (benchmarks/performance/peer_comparison.py: an N^3 unit
box, a block of (N/2)^3 cells centred, free-slip walls; --peer-grid N, default 32, the reduced one;
64 is the peer's own): the same scene stepped with "base" (core/pressure.py and core/multigrid.py of
commit --base, loaded from git, with whole-grid grid stages: the code before), "whole_grid" (this
solver and the grid stages over the whole grid), "box" (as the step runs now) and, with
--check-every, the box solver with other check intervals. All step bit-identically (printed).

Each round steps every configuration --steps times, in an order that alternates between rounds, after
--warmup untimed steps (kernel compile or cache load); figures are medians over --rounds rounds of the
per-step milliseconds (PhaseTimer). Writes benchmarks/results/domain_scaling/<device>[_<label>].{json,md}.
"""

from __future__ import annotations

import importlib.util
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

import warp as wp

from warp_mpm_bubbles import Box, Domain, Material, Output, Scene, SolverSettings
from warp_mpm_bubbles.core.active_box import ActiveRegion
from warp_mpm_bubbles.core.pressure import PressureSolver
from warp_mpm_bubbles.core.simulation import Simulation

from benchmarks import harness

ROOT = harness.ROOT
STAGES = ("p2g", "grid", "pressure", "extend", "g2p")
PPC = 8


def block_scene(domain_cells: int, block: int, lo_cell: int, dx: float, out_dir: str) -> Scene:
    lo = lo_cell * dx
    return Scene(
        name=f"block_{block}_in_{domain_cells}",
        domain=Domain(size=(domain_cells * dx,) * 3, cell_size=dx, gravity=(0.0, -9.81, 0.0), walls="free_slip"),
        materials={"water": Material("water")},
        shapes=[Box("water", min=(lo,) * 3, max=(lo + block * dx,) * 3)],
        solver=SolverSettings(particles_per_cell=PPC),
        output=Output(path=str(Path(out_dir) / "unused.usdc")),
    )


def base_solver_class(commit: str):
    """PressureSolver of `commit` (its pressure.py and multigrid.py from git, relative imports made
    absolute), or None if git cannot show them."""
    tmp = Path(tempfile.mkdtemp(prefix="base_solver_"))
    try:
        for name in ("multigrid", "pressure"):
            src = subprocess.run(["git", "show", f"{commit}:warp_mpm_bubbles/core/{name}.py"], cwd=ROOT,
                                 capture_output=True, text=True, check=True).stdout
            src = src.replace("from .multigrid import", "from base_multigrid import")
            src = src.replace("from .", "from warp_mpm_bubbles.core.")
            (tmp / f"base_{name}.py").write_text(src)
    except (subprocess.CalledProcessError, FileNotFoundError):
        return None
    for name in ("base_multigrid", "base_pressure"):  # registered first: base_pressure imports base_multigrid
        spec = importlib.util.spec_from_file_location(name, tmp / f"{name}.py")
        module = importlib.util.module_from_spec(spec)
        sys.modules[name] = module
        spec.loader.exec_module(module)

    class BaseSolver(module.PressureSolver):
        def solve(self, *args, region=None, **kwargs):  # whole grid: it masks x everywhere itself
            return super().solve(*args, **kwargs)

    return BaseSolver


class Runner:
    """One simulation, stepped with a fixed dt; per-step stage milliseconds and CG iterations.
    solver: a function of the simulation giving its pressure solver; whole_grid: grid stages launched
    over the whole grid (ActiveRegion disabled)."""

    def __init__(self, name, scene, device, solver=None, whole_grid=False):
        self.name, self.sim = name, Simulation(scene, device=device)
        if solver is not None:
            self.sim.solver = solver(self.sim)
        if whole_grid:
            self.sim.region = ActiveRegion(self.sim.grid, self.sim.device, enabled=False)
        self.samples = {s: [] for s in (*STAGES, "step")}
        self.iterations = []

    def run(self, steps: int, dt: float, record: bool):
        sim = self.sim
        before, it0 = dict(sim.timer.seconds), sim.stats.cg_iterations
        for _ in range(steps):
            sim.step(dt)
        wp.synchronize_device(sim.device)
        if record:
            spent = {s: (sim.timer.seconds.get(s, 0.0) - before.get(s, 0.0)) * 1e3 / steps for s in STAGES}
            for s, ms in spent.items():
                self.samples[s].append(ms)
            self.samples["step"].append(sum(spent.values()))
            self.iterations.append((sim.stats.cg_iterations - it0) / steps)

    def summary(self) -> dict:
        return {"cells": list(self.sim.grid.interior), "particles": self.sim.num_particles,
                "cg_iterations_per_step": statistics.median(self.iterations),
                **{f"{s}_ms": statistics.median(v) for s, v in self.samples.items()}}


def measure(runners, dt, args):
    for r in runners:
        r.run(args.warmup, dt, record=False)
    for k in range(args.rounds):
        for r in runners if k % 2 == 0 else runners[::-1]:
            r.run(args.steps, dt, record=True)
    out = {r.name: r.summary() for r in runners}
    first = runners[0].sim.particles_numpy()["positions"]
    for r in runners[1:]:  # same scene, same steps: are the particles bit-identical to the first's?
        x = r.sim.particles_numpy()["positions"]
        out[r.name]["positions_identical_to_" + runners[0].name] = bool(x.shape == first.shape and
                                                                        (x == first).all())
    return out


def scaling(args, device, tmp) -> dict:
    w, m = args.block, args.margin
    dx = 1.0 / (2 * (w + 2 * m))  # the 8x domain is 1 m wide
    tight_n, big_n = w + 2 * m, 2 * (w + 2 * m)
    tight, big = block_scene(tight_n, w, m, dx, tmp), block_scene(big_n, w, (big_n - w) // 2, dx, tmp)
    runners = [Runner("tight", tight, device), Runner("8x", big, device),
               Runner("8x_whole_grid", big, device, whole_solver, whole_grid=True)]
    dt = runners[0].sim.stable_dt()
    return {"block": w, "margin": m, "dx": dx, "dt": dt, "domains": [tight_n, big_n],
            "results": measure(runners, dt, args)}


def whole_solver(sim, **kw):
    return PressureSolver(sim.grid.cells, sim.grid.dim, sim.grid.dx, sim.device, active_box=False, **kw)


def peer_pressure(args, device, tmp) -> dict:
    n = args.peer_grid
    w = n // 2
    scene = block_scene(n, w, (n - w) // 2, 1.0 / n, tmp)
    runners = []
    base = base_solver_class(args.base)
    if base is not None:
        runners.append(Runner(f"base_{args.base}", scene, device,
                              lambda sim: base(sim.grid.cells, sim.grid.dim, sim.grid.dx, sim.device),
                              whole_grid=True))
    runners.append(Runner("whole_grid", scene, device, whole_solver, whole_grid=True))
    runners.append(Runner("box", scene, device))
    for k in args.check_every:  # iterations between the host's convergence checks
        runners.append(Runner(f"box_check_every_{k}", scene, device, lambda sim, k=k: PressureSolver(
            sim.grid.cells, sim.grid.dim, sim.grid.dx, sim.device, check_every=k)))
    dt = runners[0].sim.stable_dt()
    results = measure(runners, dt, args)
    return {"grid": n, "block": w, "dt": dt, "results": results,
            "solve_only": solve_only(runners[-1].sim, base, args.rounds * args.steps)}


def solve_only(sim, base, repeats: int) -> dict:
    """The last step's pressure system solved from x = 0 by each solver in turn, `repeats` times:
    milliseconds per solve (median) without the rest of the step, and the iterations."""
    import time

    from warp_mpm_bubbles.core.pressure import PressureSystem
    from warp_mpm_bubbles.core.threads import CACHE_LINE_FLOATS

    f, g, settings = sim.fields, sim.grid, sim.scene.solver
    system = PressureSystem(f.types, tuple(f.inv_rho), f.diag, f.extra_diag)
    counts = f.counters.numpy().reshape(-1, CACHE_LINE_FLOATS)  # one group per part of the assembly
    n_fluid, n_pinned = int(counts[:, 0].sum()), int(counts[:, 1].sum())
    make = {"whole_grid": lambda: PressureSolver(g.cells, g.dim, g.dx, sim.device, active_box=False),
            "box": lambda: PressureSolver(g.cells, g.dim, g.dx, sim.device)}
    if base is not None:
        make = {"base": lambda: base(g.cells, g.dim, g.dx, sim.device), **make}
    solvers = {name: m() for name, m in make.items()}
    times, info = {name: [] for name in solvers}, {}
    for k in range(repeats + 1):  # the first round warms up
        for name, solver in solvers.items() if k % 2 else reversed(solvers.items()):
            b, x = wp.clone(f.rhs), wp.zeros_like(f.pressure)
            wp.synchronize_device(sim.device)
            t0 = time.perf_counter()
            info[name] = solver.solve(system, b, x, tol=settings.cg_tolerance, max_iter=settings.cg_max_iterations,
                                      singular=n_pinned == 0, n_fluid=n_fluid, preconditioner=settings.preconditioner)
            wp.synchronize_device(sim.device)
            if k:
                times[name].append((time.perf_counter() - t0) * 1e3)
    return {name: {"ms": statistics.median(t), "iterations": info[name].iterations} for name, t in times.items()}


def table(results: dict, columns=("step", *STAGES)) -> list[str]:
    lines = ["| configuration | cells | particles | CG it/step | " + " | ".join(f"{c} ms" for c in columns) + " |",
             "|---|---|---:|---:|" + "---:|" * len(columns)]
    for name, r in results.items():
        cells = "x".join(map(str, r["cells"]))
        lines.append(f"| {name} | {cells} | {r['particles']:,} | {r['cg_iterations_per_step']:.1f} | "
                     + " | ".join(f"{r[c + '_ms']:.1f}" for c in columns) + " |")
    return lines


def markdown(meta, scale, peer) -> str:
    out = [f"Medians over {meta['rounds']} rounds of {meta['steps']} steps.", ""]
    if scale:
        r = scale["results"]
        out += [f"## The same {scale['block']}^3-cell block in a {scale['domains'][0]}^3 and a "
                f"{scale['domains'][1]}^3 domain (dt = {scale['dt']:.3g} s)", "", *table(r), "",
                f"8x / tight per step: **{r['8x']['step_ms'] / r['tight']['step_ms']:.2f}** (pressure "
                f"{r['8x']['pressure_ms'] / r['tight']['pressure_ms']:.2f}); with whole-grid launches (grid stages "
                f"and solve, as before the active box) {r['8x_whole_grid']['step_ms'] / r['tight']['step_ms']:.2f} "
                f"(pressure {r['8x_whole_grid']['pressure_ms'] / r['tight']['pressure_ms']:.2f}).", ""]
    if peer:
        r = peer["results"]
        out += [f"## Pressure stage before/after: peer configuration at {peer['grid']}^3, "
                f"{peer['block']}^3-cell block", "", *table(r), ""]
        first = next(iter(r))
        so = peer["solve_only"]
        out += [f"Solve only (the last system, from x = 0, {meta['rounds'] * meta['steps']} alternating repeats): "
                + ", ".join(f"{k} {v['ms']:.1f} ms ({v['iterations']} it)" for k, v in so.items()), ""]
        out += [f"pressure ms, {name} / {first}: {v['pressure_ms'] / r[first]['pressure_ms']:.2f}; step "
                f"{v['step_ms'] / r[first]['step_ms']:.2f}; particles bit-identical to {first}'s after all steps: "
                f"{v.get('positions_identical_to_' + first, True)}" + "  " for name, v in r.items()]
    return "\n".join(out) + "\n"


def main(argv=None) -> int:
    ap = harness.parser(__doc__, quick="an 8^3 block, peer grid 16, 1 step, 1 round")
    ap.add_argument("--block", type=int, default=16, help="water block side in cells")
    ap.add_argument("--margin", type=int, default=4, help="cells between the block and the tight box's walls")
    ap.add_argument("--peer-grid", type=int, default=32, help="peer configuration grid for part 2 (0: skip)")
    ap.add_argument("--skip-scaling", action="store_true")
    ap.add_argument("--check-every", type=int, nargs="*", default=[],
                    help="part 2 also runs the box solver with these check intervals (e.g. 1 2 8; the default is "
                         "core.pressure.CHECK_EVERY)")
    ap.add_argument("--base", default="b8f0711", help="commit whose solver is 'base' in part 2")
    ap.add_argument("--steps", type=int, default=4)
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--warmup", type=int, default=2)
    args = ap.parse_args(argv)
    if args.quick:
        args.block, args.margin, args.peer_grid, args.steps, args.rounds, args.warmup = 8, 2, 16, 1, 1, 1
    wp.config.quiet = True
    wp.init()
    device = wp.get_device(args.device)
    with tempfile.TemporaryDirectory() as tmp:
        scale = None if args.skip_scaling else scaling(args, device, tmp)
        peer = peer_pressure(args, device, tmp) if args.peer_grid else None
    meta = {"rounds": args.rounds, "steps": args.steps}
    text = markdown(meta, scale, peer)
    print(text)
    harness.write_result("domain_scaling", args, {"meta": meta, "scaling": scale, "peer": peer}, text,
                         title=f"Domain scaling ({harness.describe_device(args.device)})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
