"""Our full step against what a user would pick instead: Taichi's `mpm3d` algorithm, run by Taichi
and by Warp, on the configuration of that example scaled to a block.

    python -m benchmarks.performance.peer_comparison                       # 64^3 grid, 262,144 particles, CPU
    python -m benchmarks.performance.peer_comparison --grid 32 --rounds 3  # 32^3 grid, 16^3-cell block (32,768)
    python -m benchmarks.performance.peer_comparison --device cuda:0 --particles-scale 4 --grid 128
    python -m benchmarks.performance.peer_comparison --quick               # 16^3 grid, 1 round of 2 steps
    python -m benchmarks.performance.peer_comparison --before ../main      # our step before a change, side by side

Configuration: a unit box, free-slip walls, gravity 9.81 m/s^2 down y, an N^3 grid (--grid, default
64) and a water block of (N/2)^3 cells centred in the box (side 0.5 m at N = 64), seeded by our
seeder at 8 particles per cell (jittered, 2x2x2 per cell). --particles-scale S scales the block's
volume, so its particle count, by about S (whole cells). Every code starts from the same particles.

Codes:
  ours       `Simulation.step(sim.stable_dt())` on a Scene built with the Python API: MAC grid APIC,
             the incompressibility solve (multigrid-PCG), extrapolation, walls.
  taichi-1t  Taichi's mpm3d algorithm (MLS-MPM, a weakly compressible fluid: pressure E (1 - J) from
             each particle's volume ratio J, no pressure solve, one collocated grid, quadratic
             B-splines, dt = 4e-4 * 32 / N as in the example), ti.init(arch=ti.cpu,
             cpu_max_num_threads=1); taichi-2t the same with 2 threads (taichi-cuda on a GPU).
             Needs `pip install .[bench]` (taichi); skipped with a note if it is missing.
  warp-mls   the same algorithm written in Warp below (the engine held equal: one CPU thread).
  ours-before  with --before DIR: our step with DIR's package (an earlier checkout), in the same
             rounds, so a change's gain and the ratios to the peers come from one run.

Each round runs every code once in its own subprocess, in an order that alternates between rounds,
so drifts in machine load hit all alike; --warmup steps (compile or cache load included) are untimed;
the figure is the median over rounds of particle-steps per second. A separate untimed physics check
runs each code (taichi once) to the --check-times and compares the block's centroid fall with free
fall (with each code's own steps), each code's volume measure (the peer: mean J; ours:
liquid_volume()) and the particles' J: before impact all fall freely; after it the peer's particles
compress where the block lands (its only resistance is the stiffness E).
Writes benchmarks/results/peer_comparison/<device>[_g<N>][_s<S>][_<label>].{json,md}.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import warp as wp

from benchmarks import harness

ROOT = harness.ROOT
GRAVITY = 9.81  # m/s^2 along -y, ours' default; mpm3d uses 9.8 (set equal so both fall alike)
PPC = 8
# mpm3d's material: only E / rho matters (sound speed sqrt(E / rho) = 20 m/s); bound: wall nodes.
E, RHO, BOUND = 400.0, 1.0, 3


def peer_dt(grid: int) -> float:
    return 4e-4 * 32 / grid  # mpm3d: 4e-4 at 32^3, 2e-4 at 64^3


def block_cells(grid: int, scale: float) -> int:
    return max(2, int(round(grid / 2 * scale ** (1.0 / 3.0))))


def block_scene(grid: int, scale: float, out_dir: str):
    from warp_mpm_bubbles import Box, Domain, Material, Output, Scene, SolverSettings

    n = block_cells(grid, scale)
    lo = (grid - n) // 2 / grid  # on cell faces
    hi = lo + n / grid
    if hi > 1.0 - 4.0 / grid:
        raise SystemExit(f"--particles-scale {scale} makes a {n}-cell block that fills the {grid}^3 box; "
                         f"use a smaller scale (at most ~{((grid - 8) / (grid / 2)) ** 3:.2f})")
    return Scene(
        name="peer_block",
        domain=Domain(size=(1.0, 1.0, 1.0), cell_size=1.0 / grid, gravity=(0.0, -GRAVITY, 0.0), walls="free_slip"),
        materials={"water": Material("water")},
        shapes=[Box("water", min=(lo, lo, lo), max=(hi, hi, hi))],
        solver=SolverSettings(particles_per_cell=PPC),
        output=Output(path=str(Path(out_dir) / "unused.usdc")),
    )


# ----------------------------------------------------------------- mpm3d's algorithm in Warp
@wp.func
def bspline(f: float):
    return wp.vec3(0.5 * (1.5 - f) * (1.5 - f), 0.75 - (f - 1.0) * (f - 1.0), 0.5 * (f - 0.5) * (f - 0.5))


@wp.kernel
def mls_p2g(x: wp.array(dtype=wp.vec3), v: wp.array(dtype=wp.vec3), C: wp.array(dtype=wp.mat33),
            J: wp.array(dtype=float), dx: float, dt: float, p_vol: float, p_mass: float, e_mod: float,
            grid_v: wp.array3d(dtype=wp.vec3), grid_m: wp.array3d(dtype=float)):
    p = wp.tid()
    X = x[p] / dx
    b = wp.vec3i(int(X[0] - 0.5), int(X[1] - 0.5), int(X[2] - 0.5))
    f = X - wp.vec3(float(b[0]), float(b[1]), float(b[2]))
    wx, wy, wz = bspline(f[0]), bspline(f[1]), bspline(f[2])
    stress = -dt * 4.0 * e_mod * p_vol * (J[p] - 1.0) / (dx * dx)  # weakly compressible: no solve
    affine = stress * wp.identity(n=3, dtype=float) + p_mass * C[p]
    mom = p_mass * v[p]
    for i in range(3):
        for j in range(3):
            for k in range(3):
                dpos = (wp.vec3(float(i), float(j), float(k)) - f) * dx
                w = wx[i] * wy[j] * wz[k]
                wp.atomic_add(grid_v, b[0] + i, b[1] + j, b[2] + k, w * (mom + affine @ dpos))
                wp.atomic_add(grid_m, b[0] + i, b[1] + j, b[2] + k, w * p_mass)


@wp.kernel
def mls_grid(grid_v: wp.array3d(dtype=wp.vec3), grid_m: wp.array3d(dtype=float), dt: float, gravity: float,
             n: int, bound: int):
    i, j, k = wp.tid()
    vel = grid_v[i, j, k]
    m = grid_m[i, j, k]
    if m > 0.0:
        vel = vel / m
    vel = vel - wp.vec3(0.0, dt * gravity, 0.0)
    node = wp.vec3i(i, j, k)
    for d in range(3):  # free slip: the normal component stops at the walls, the others slide
        if (node[d] < bound and vel[d] < 0.0) or (node[d] > n - bound and vel[d] > 0.0):
            vel[d] = 0.0
    grid_v[i, j, k] = vel


@wp.kernel
def mls_g2p(x: wp.array(dtype=wp.vec3), v: wp.array(dtype=wp.vec3), C: wp.array(dtype=wp.mat33),
            J: wp.array(dtype=float), dx: float, dt: float, grid_v: wp.array3d(dtype=wp.vec3)):
    p = wp.tid()
    X = x[p] / dx
    b = wp.vec3i(int(X[0] - 0.5), int(X[1] - 0.5), int(X[2] - 0.5))
    f = X - wp.vec3(float(b[0]), float(b[1]), float(b[2]))
    wx, wy, wz = bspline(f[0]), bspline(f[1]), bspline(f[2])
    new_v = wp.vec3()
    new_C = wp.mat33()
    for i in range(3):
        for j in range(3):
            for k in range(3):
                dpos = (wp.vec3(float(i), float(j), float(k)) - f) * dx
                w = wx[i] * wy[j] * wz[k]
                g_v = grid_v[b[0] + i, b[1] + j, b[2] + k]
                new_v += w * g_v
                new_C += (4.0 * w / (dx * dx)) * wp.outer(g_v, dpos)
    v[p] = new_v
    x[p] = x[p] + dt * new_v
    J[p] = J[p] * (1.0 + dt * wp.trace(new_C))
    C[p] = new_C


class WarpPeer:
    def __init__(self, positions: np.ndarray, grid: int, device: str):
        self.device, self.n, self.dx, self.dt = device, grid, 1.0 / grid, peer_dt(grid)
        self.p_vol = self.dx**3 / PPC
        count = len(positions)
        self.x = wp.array(positions, dtype=wp.vec3, device=device)
        self.v = wp.zeros(count, dtype=wp.vec3, device=device)
        self.C = wp.zeros(count, dtype=wp.mat33, device=device)
        self.J = wp.full(count, 1.0, dtype=float, device=device)
        self.grid_v = wp.zeros((grid,) * 3, dtype=wp.vec3, device=device)
        self.grid_m = wp.zeros((grid,) * 3, dtype=float, device=device)

    def step(self):
        p, d = [self.x, self.v, self.C, self.J, self.dx, self.dt], self.device
        self.grid_v.zero_()
        self.grid_m.zero_()
        wp.launch(mls_p2g, len(self.x), [*p, self.p_vol, RHO * self.p_vol, E, self.grid_v, self.grid_m], device=d)
        wp.launch(mls_grid, self.grid_m.shape, [self.grid_v, self.grid_m, self.dt, GRAVITY, self.n, BOUND], device=d)
        wp.launch(mls_g2p, len(self.x), [*p, self.grid_v], device=d)

    def sync(self):
        wp.synchronize_device(self.device)

    def state(self):
        return self.x.numpy().copy(), self.J.numpy().copy()


# --------------------------------------------------------------- mpm3d's algorithm in Taichi
class TaichiPeer:
    def __init__(self, positions: np.ndarray, grid: int, arch: str, threads: int):
        import taichi as ti

        self.ti = ti
        kw = {"cpu_max_num_threads": threads} if arch == "cpu" else {}
        ti.init(arch=getattr(ti, arch), default_fp=ti.f32, log_level=ti.WARN, random_seed=0, **kw)
        count, self.dt = len(positions), peer_dt(grid)
        dt, dx, n = self.dt, 1.0 / grid, grid
        p_vol = dx**3 / PPC
        p_mass = RHO * p_vol
        x = ti.Vector.field(3, float, count)
        v = ti.Vector.field(3, float, count)
        C = ti.Matrix.field(3, 3, float, count)
        J = ti.field(float, count)
        grid_v = ti.Vector.field(3, float, (n,) * 3)
        grid_m = ti.field(float, (n,) * 3)

        @ti.kernel
        def substep():
            for I in ti.grouped(grid_m):
                grid_v[I] = ti.zero(grid_v[I])
                grid_m[I] = 0.0
            for p in x:  # p2g
                X = x[p] / dx
                base = int(X - 0.5)
                f = X - base
                w = [0.5 * (1.5 - f) ** 2, 0.75 - (f - 1.0) ** 2, 0.5 * (f - 0.5) ** 2]
                stress = -dt * 4.0 * E * p_vol * (J[p] - 1.0) / dx**2
                affine = ti.Matrix.identity(float, 3) * stress + p_mass * C[p]
                for o in ti.static(ti.grouped(ti.ndrange(3, 3, 3))):
                    dpos = (o - f) * dx
                    weight = w[o[0]][0] * w[o[1]][1] * w[o[2]][2]
                    grid_v[base + o] += weight * (p_mass * v[p] + affine @ dpos)
                    grid_m[base + o] += weight * p_mass
            for I in ti.grouped(grid_m):  # grid: velocity, gravity, free-slip walls
                if grid_m[I] > 0:
                    grid_v[I] /= grid_m[I]
                grid_v[I][1] -= dt * GRAVITY
                stop = (I < BOUND) & (grid_v[I] < 0) | (I > n - BOUND) & (grid_v[I] > 0)
                grid_v[I] = ti.select(stop, 0, grid_v[I])
            for p in x:  # g2p
                X = x[p] / dx
                base = int(X - 0.5)
                f = X - base
                w = [0.5 * (1.5 - f) ** 2, 0.75 - (f - 1.0) ** 2, 0.5 * (f - 0.5) ** 2]
                new_v = ti.zero(v[p])
                new_C = ti.zero(C[p])
                for o in ti.static(ti.grouped(ti.ndrange(3, 3, 3))):
                    dpos = (o - f) * dx
                    weight = w[o[0]][0] * w[o[1]][1] * w[o[2]][2]
                    g_v = grid_v[base + o]
                    new_v += weight * g_v
                    new_C += 4.0 * weight * g_v.outer_product(dpos) / dx**2
                v[p] = new_v
                x[p] += dt * v[p]
                J[p] *= 1.0 + dt * new_C.trace()
                C[p] = new_C

        x.from_numpy(positions.astype(np.float32))
        J.fill(1.0)
        self.x, self.J, self.step = x, J, substep

    def sync(self):
        self.ti.sync()

    def state(self):
        return self.x.to_numpy(), self.J.to_numpy()


# ------------------------------------------------------------------------------------ ours
class Ours:
    def __init__(self, grid: int, scale: float, device: str, out_dir: str):
        from warp_mpm_bubbles.core.simulation import Simulation

        self.sim = Simulation(block_scene(grid, scale, out_dir), device=device)
        self.device = device

    def step(self):
        self.sim.step(self.sim.stable_dt())

    def sync(self):
        wp.synchronize_device(self.device)

    def state(self):
        p = self.sim.particles_numpy()
        return p["positions"], p["J"]


def make_code(args, positions, out_dir):
    if args.worker == "ours":
        code = Ours(args.grid, args.particles_scale, args.device, out_dir)
        if code.sim.num_particles != len(positions):
            raise SystemExit(f"ours seeded {code.sim.num_particles} particles, the peers {len(positions)}")
        return code
    if args.worker == "warp-mls":
        return WarpPeer(positions, args.grid, args.device)
    arch, threads = {"taichi-1t": ("cpu", 1), "taichi-2t": ("cpu", 2), "taichi-cuda": ("cuda", 0)}[args.worker]
    return TaichiPeer(positions, args.grid, arch, threads)


# ---------------------------------------------------------------------------------- worker
def run_timing(code, args) -> dict:
    sim = getattr(code, "sim", None)
    t0 = time.perf_counter()
    for _ in range(args.warmup):
        code.step()
    code.sync()
    warmup = time.perf_counter() - t0
    if sim is not None:  # count only the timed steps
        from warp_mpm_bubbles.core.simulation import SolverStats
        from warp_mpm_bubbles.core.timing import PhaseTimer

        sim.timer, sim.stats = PhaseTimer(sim.device), SolverStats()
    t0 = time.perf_counter()
    for _ in range(args.steps):
        code.step()
    code.sync()
    wall = time.perf_counter() - t0
    count = len(code.state()[1])
    out = {"particles": count, "warmup_steps": args.warmup, "warmup_seconds": warmup, "steps": args.steps,
           "wall_seconds": wall, "seconds_per_step": wall / args.steps,
           "particle_steps_per_second": count * args.steps / wall}
    if sim is not None:
        st = sim.stats
        out.update(stages_ms={k: 1e3 * t / args.steps for k, t in sim.timer.seconds.items()},
                   cg_iterations_mean=st.cg_iterations / max(st.cg_solves, 1),
                   dt_mean=sum(st.dt_history) / len(st.dt_history))
    else:
        out["dt_mean"] = code.dt
    return out


def run_check(code, times: list[float]) -> list[dict]:
    """Step to each time; the block's centroid fall against free fall and the volume ratios J."""
    x0, _ = code.state()
    y0 = float(x0[:, 1].astype(np.float64).mean())
    sim, steps, rows = getattr(code, "sim", None), 0, []
    volume0 = sim.liquid_volume() if sim is not None else None  # ours' own measure of its water's volume
    for t_end in times:
        if sim is not None:
            sim.advance_to(t_end)
            t, dts = sim.time, sim.stats.dt_history
        else:
            while (steps + 1) * code.dt <= t_end + 1e-9:
                code.step()
                steps += 1
            t, dts = steps * code.dt, [code.dt] * steps
        # Both codes add g dt to the velocity, then move by v dt: free fall with the same steps.
        v = discrete = 0.0
        for dt in dts:
            v += GRAVITY * dt
            discrete += v * dt
        code.sync()
        x, J = code.state()
        J = J.astype(np.float64)
        drop = y0 - float(x[:, 1].astype(np.float64).mean())
        # The volume as each code knows it: ours from the grid (cells filled by the splatted rest
        # volumes), the peer from J, the state its pressure acts on.
        volume = sim.liquid_volume() / volume0 if sim is not None else float(J.mean())
        rows.append({"t": t, "steps": len(dts), "centroid_drop": drop, "free_fall": 0.5 * GRAVITY * t * t,
                     "volume_ratio": volume,
                     "free_fall_same_steps": discrete,
                     "lowest_y": float(x[:, 1].min()), "J_min": float(J.min()), "J_mean": float(J.mean()),
                     "J_max": float(J.max())})
    return rows


def worker(args) -> int:
    wp.config.quiet = True
    positions = np.load(args.seeds)
    with tempfile.TemporaryDirectory(prefix="peer_") as out_dir:
        t0 = time.perf_counter()
        code = make_code(args, positions, out_dir)
        setup = time.perf_counter() - t0
        if args.check:
            result = {"check": run_check(code, [float(t) for t in args.check_times.split(",")])}
        else:
            result = run_timing(code, args)
    result.update(code=args.worker, setup_seconds=setup)
    print("RESULT " + json.dumps(result), flush=True)
    return 0


# ------------------------------------------------------------------------------------ main
def call_worker(code: str, args, seeds: Path, check: bool = False) -> dict:
    flags = ["--seeds", seeds, "--grid", args.grid, "--particles-scale", args.particles_scale, "--steps", args.steps,
             "--warmup", args.warmup, "--device", args.device]
    cwd, env = ROOT, None
    if code == "ours-before":  # this file run as a script on the earlier checkout's package (PYTHONPATH)
        cwd, env = args.before, dict(os.environ, PYTHONPATH=str(args.before))
        cmd = [sys.executable, str(Path(__file__).resolve()), "--worker", "ours", *map(str, flags)]
    else:
        cmd = harness.module_command(__spec__.name, "--worker", code, *flags)
    if check:
        cmd += ["--check", "--check-times", args.check_times]
    proc = subprocess.run(cmd, cwd=cwd, env=env, capture_output=True, text=True)
    lines = [ln for ln in proc.stdout.splitlines() if ln.startswith("RESULT ")]
    if proc.returncode or not lines:
        raise SystemExit(f"{code} failed (exit {proc.returncode}):\n{proc.stdout[-3000:]}\n{proc.stderr[-3000:]}")
    return json.loads(lines[-1][len("RESULT "):])


def peer_codes(device: str) -> tuple[list[str], str | None]:
    """The Taichi variants to run, and the Taichi version (None: not installed)."""
    from importlib import metadata

    try:
        version = metadata.version("taichi")
    except metadata.PackageNotFoundError:
        return [], None
    return (["taichi-cuda"] if device.startswith("cuda") else ["taichi-1t", "taichi-2t"]), version


LABELS = {
    "ours": "ours, full step (liquid only: MAC APIC, multigrid-PCG), `Simulation.step(stable_dt())`",
    "ours-before": "ours before: the same step with the package at `{before}`",
    "taichi-1t": "Taichi {taichi} `mpm3d` algorithm (weakly compressible MLS-MPM, no pressure solve), 1 thread",
    "taichi-2t": "the same, 2 threads",
    "taichi-cuda": "Taichi {taichi} `mpm3d` algorithm (weakly compressible MLS-MPM, no pressure solve), CUDA",
    "warp-mls": "the same algorithm written in Warp {warp} (benchmarks/performance/peer_comparison.py{warp_note})",
}


def summarize(rounds: list[dict], codes: list[str]) -> dict:
    out = {}
    for c in codes:
        pss = [r[c]["particle_steps_per_second"] for r in rounds]
        out[c] = {"median_particle_steps_per_second": statistics.median(pss),
                  "median_ms_per_step": 1e3 * statistics.median(r[c]["seconds_per_step"] for r in rounds),
                  "per_round_particle_steps_per_second": pss, "dt_mean": rounds[0][c]["dt_mean"]}
    ours = out["ours"]["median_particle_steps_per_second"]
    for c in codes:
        out[c]["ours_over_it"] = ours / out[c]["median_particle_steps_per_second"]
        out[c]["ours_over_it_per_round"] = [o / i for o, i in zip(out["ours"]["per_round_particle_steps_per_second"],
                                                                   out[c]["per_round_particle_steps_per_second"])]
    for c in [c for c in codes if c.startswith("ours")]:
        stages = rounds[0][c].get("stages_ms", {})
        out[c]["stages_ms"] = {k: statistics.median(r[c]["stages_ms"][k] for r in rounds) for k in stages}
        out[c]["cg_iterations_mean"] = statistics.mean(r[c]["cg_iterations_mean"] for r in rounds)
    return out


def markdown(meta: dict, summary: dict, checks: dict) -> str:
    fmt = {"taichi": meta["taichi_version"], "warp": meta["warp_version"], "before": meta.get("before"),
           "warp_note": ", one CPU thread" if meta["device_alias"] == "cpu" else ""}
    out = [f"- taichi {meta['taichi_version'] or 'not installed (skipped)'}; load average at the end (1, 5, 15 min): "
           + ", ".join(f"{x:.1f}" for x in meta["load_average_1_5_15min_at_end"]),
           f"- configuration: {meta['configuration']}",
           f"- {meta['rounds']} alternating rounds, each code in its own process; {meta['warmup']} warm-up steps "
           f"(compile or cache load) excluded, then {meta['steps']} timed steps; medians over rounds"]
    if meta.get("before"):
        out.append(f"- ours before: the package at `{meta['before']}` ({meta['before_commit']})")
    out += ["", "| code | particle-steps per second | ms / step | ours / it | ours / it, per round | dt (ms) "
                "| per round (M/s) |",
            "|---|---:|---:|---:|---|---:|---|"]
    for c, s in summary.items():
        out.append(f"| {LABELS[c].format(**fmt)} | {s['median_particle_steps_per_second'] / 1e6:.2f} M | "
                   f"{s['median_ms_per_step']:.1f} | {s['ours_over_it']:.2f} | "
                   + ", ".join(f"{x:.2f}" for x in s["ours_over_it_per_round"]) + f" | {s['dt_mean'] * 1e3:.3g} | "
                   + ", ".join(f"{p / 1e6:.2f}" for p in s["per_round_particle_steps_per_second"]) + " |")
    for c in [c for c in summary if c.startswith("ours")]:
        ours = summary[c]
        total = sum(ours["stages_ms"].values())
        out += ["", f"{'Our' if c == 'ours' else 'Before: our'} stages, ms per step (median over rounds; "
                    f"{ours['cg_iterations_mean']:.1f} CG iterations per solve): "
                    + ", ".join(f"{k} {v:.1f} ({100 * v / total:.0f}%)" for k, v in ours["stages_ms"].items())]
    if checks:
        out += ["", "## Physics: do the codes agree?", "",
                f"Untimed runs from the same particles to t = {meta['check_times']} s (the block's bottom meets "
                f"the floor after about {meta['impact_time']:.2f} s). Free fall: 0.5 g t^2, and with the code's "
                "own steps (both add g dt to the velocity, then move by v dt: the fall overshoots 0.5 g t^2 by "
                "about 1/steps; after impact the falls differ also because mpm3d's walls stand 3 cells inside "
                "the box, ours at its faces). Volume / start: the peer's mean J (its pressure is E (1 - J)); "
                "ours' `Simulation.liquid_volume()` (the cells its particles fill). J: each particle's volume "
                "ratio; ours' is a diagnostic integrated from the interpolated divergence, not what its "
                "pressure acts on (splashing surface particles drift).", "",
                "| code | t (s) | steps | centroid fall (m) | free fall: 0.5 g t^2 / same steps (m) "
                "| fall / free fall, same steps | volume / start | J min / mean / max |",
                "|---|---:|---:|---:|---:|---:|---:|---|"]
        for c, rows in checks.items():
            for r in rows:
                out.append(f"| {c} | {r['t']:.3f} | {r['steps']} | {r['centroid_drop']:.5f} | {r['free_fall']:.5f} / "
                           f"{r['free_fall_same_steps']:.5f} | {r['centroid_drop'] / r['free_fall_same_steps']:.4f} | "
                           f"{r['volume_ratio']:.4f} | "
                           f"{r['J_min']:.4f} / {r['J_mean']:.5f} / {r['J_max']:.4f} |")
    out += ["", "What differs: the peer (Taichi's `mpm3d`) is a weakly compressible fluid, pressure "
            f"E (1 - J) with E / rho = {E / RHO:g} m^2/s^2 (sound speed {math.sqrt(E / RHO):.0f} m/s), "
            "on one collocated grid with a fixed dt = 4e-4 * 32 / N and no pressure solve: nothing holds its "
            "volume but the stiffness, so it compresses where the block lands. Ours projects a MAC velocity "
            "field onto divergence-free (multigrid-PCG) every step, extrapolates it, and takes the CFL step "
            "(larger: the figures are per step, not per simulated second)."]
    return "\n".join(out) + "\n"


def parse(argv):
    ap = harness.parser(__doc__.split("\n")[0], quick="a 16^3 grid, 1 round of 2 steps after 1 warm-up, "
                                                       "the physics check to t = 0.05 s")
    ap.add_argument("--grid", type=int, default=64, help="N for the N^3 grid; the block is N/2 cells a side (64)")
    ap.add_argument("--particles-scale", type=float, default=1.0,
                    help="scale the block's volume (so its particles) by about this factor (default 1)")
    ap.add_argument("--rounds", type=int, default=3, help="alternating rounds (default 3)")
    ap.add_argument("--steps", type=int, default=20, help="timed steps per code and round (default 20)")
    ap.add_argument("--warmup", type=int, default=3, help="untimed steps first, compile included (default 3)")
    ap.add_argument("--check-times", default="0.1,0.3",
                    help="simulated times (s) of the physics check, comma-separated (default 0.1,0.3)")
    ap.add_argument("--no-check", action="store_true", help="skip the physics check")
    ap.add_argument("--before", type=Path, help="an earlier checkout whose step runs side by side (ours-before)")
    ap.add_argument("--worker", choices=sorted(LABELS), help=argparse.SUPPRESS)
    ap.add_argument("--seeds", help=argparse.SUPPRESS)
    ap.add_argument("--check", action="store_true", help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.quick and not args.worker:
        args.grid, args.rounds, args.steps, args.warmup, args.check_times = 16, 1, 2, 1, "0.05"
    if args.grid < 16 or args.grid % 2:
        ap.error(f"--grid {args.grid}: expected an even number >= 16")
    if not args.particles_scale > 0 or args.rounds < 1 or args.steps < 1 or args.warmup < 0:
        ap.error("need --particles-scale > 0, --rounds >= 1, --steps >= 1 and --warmup >= 0")
    try:
        times = [float(t) for t in args.check_times.split(",")]
    except ValueError:
        ap.error(f"--check-times {args.check_times!r}: expected comma-separated seconds, e.g. 0.1,0.3")
    if times != sorted(times) or times[0] <= 0:
        ap.error(f"--check-times {args.check_times!r}: expected increasing times > 0")
    return args


def main(argv=None) -> int:
    args = parse(argv)
    if args.worker:
        return worker(args)
    from warp_mpm_bubbles.core.seeding import seed_particles

    taichi_codes, taichi_version = peer_codes(args.device)
    if taichi_version is None:
        print("taichi is not installed (pip install .[bench]): the Taichi peer is skipped", file=sys.stderr)
    if args.before:
        args.before = args.before.resolve()
    codes = ["ours", *(["ours-before"] if args.before else []), *taichi_codes, "warp-mls"]
    wp.config.quiet = True
    dev = wp.get_device(args.device)
    n = block_cells(args.grid, args.particles_scale)
    with tempfile.TemporaryDirectory(prefix="peer_seeds_") as tmp:
        scene = block_scene(args.grid, args.particles_scale, tmp)
        seeds = Path(tmp) / "positions.npy"
        np.save(seeds, seed_particles(scene)["positions"])
        lo = scene.shapes[0].min[1]
        rounds = []
        for r in range(args.rounds):
            order = codes if r % 2 == 0 else codes[::-1]
            rounds.append({c: call_worker(c, args, seeds) for c in order})
            print(f"round {r + 1}: " + ", ".join(
                f"{c} {rounds[-1][c]['particle_steps_per_second'] / 1e6:.2f} M/s" for c in codes), file=sys.stderr, flush=True)
        checks = {}
        if not args.no_check:
            for c in ["ours", *taichi_codes[-1:], "warp-mls"]:
                checks[c] = call_worker(c, args, seeds, check=True)["check"]
                print(f"check {c}: " + ", ".join(f"t {x['t']:.3f} fall/free {x['centroid_drop'] / x['free_fall_same_steps']:.4f} "
                                                 f"J {x['J_min']:.3f}..{x['J_max']:.3f}" for x in checks[c]), file=sys.stderr)
    particles = rounds[0]["ours"]["particles"]
    meta = {
        "device_alias": dev.alias, "warp_version": wp.config.version, "taichi_version": taichi_version,
        "load_average_1_5_15min_at_end": list(os.getloadavg()),
        "grid": args.grid, "block_cells": n, "particles": particles,
        "configuration": f"unit box, free-slip walls, {args.grid}^3 grid, a {n}^3-cell water block "
                         f"[{lo:g}, {lo + n / args.grid:g}]^3 at {PPC} particles per cell ({particles:,} particles) "
                         f"falling under g = {GRAVITY} m/s^2",
        "rounds": args.rounds, "steps": args.steps, "warmup": args.warmup, "check_times": args.check_times,
        "before": str(args.before) if args.before else None,
        "before_commit": harness.checkout_commit(args.before) if args.before else None,
        "impact_time": math.sqrt(2 * (lo - BOUND / args.grid) / GRAVITY),
    }
    summary = summarize(rounds, codes)
    text = markdown(meta, summary, checks)
    print(text)
    config = ([f"g{args.grid}"] if args.grid != 64 else []) + ([f"s{args.particles_scale:g}"] if args.particles_scale != 1
                                                                 else [])
    args.label = "_".join(config + ([args.label] if args.label else [])) or None
    harness.write_result("peer_comparison", args, {"meta": meta, "summary": summary, "rounds": rounds,
                                                   "physics_check": checks}, text,
                         title=f"Peer comparison on {harness.describe_device(args.device)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
