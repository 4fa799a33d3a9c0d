"""Start-up cost: Warp's cold compile of our kernels and the warm start from its kernel cache, for a
liquid-only scene and for a scene with every effect.

    python -m benchmarks.performance.compile_time                 # both scenes, 1 round, CPU
    python -m benchmarks.performance.compile_time --rounds 3 --steps 12 --device cuda:0
    python -m benchmarks.performance.compile_time --quick         # the liquid scene only, 2 steps

Scenes (2D, small: the step itself costs little next to the compile):
  liquid   a dam break, 40 x 32 cells, water only (the core: p2g, grid, pressure, multigrid, g2p).
  full     gas + surface tension + viscosity + foam + sub-grid bubbles + entrainment + both emitters
           (a pouring stream and a gas injector) + a moving collider, 40 x 40 cells.

Each round runs, per scene, a process with WARP_CACHE_PATH set to a fresh empty folder (cold: every
Warp module the run touches is compiled), then a second process on that now-filled folder (warm: the
modules load from the cache). Each process times its imports, Simulation() (seeding, arrays), the
first step (Warp compiles or loads a module on its first launch) and the next --steps - 1 steps (stages
that launch later: sub-grid conversions every 10 steps, emitters, foam), and the whole process
including Python's start. Warp's own per-module lines ("Module X load ... took N ms (compiled)") are
collected too. Prints a Markdown table and writes benchmarks/results/compile_time/<device>.{json,md}.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from benchmarks import harness

MODULE_LINE = re.compile(r"Module (\S+) \w+ load on device '([^']+)' took ([\d.]+) ms\s+\((compiled|cached)\)")
SCENES = ("liquid", "full")


def liquid_scene(out_dir: str):
    from warp_mpm_bubbles import Box, Domain, Material, Output, Scene, SolverSettings

    return Scene(name="liquid_2d", domain=Domain(size=(0.25, 0.2), cell_size=0.00625),
                 materials={"water": Material("water")}, shapes=[Box("water", (0.0, 0.0), (0.1, 0.15))],
                 solver=SolverSettings(particles_per_cell=4), output=Output(path=str(Path(out_dir) / "l.usdc")))


def full_scene(out_dir: str):
    """Every optional stage: effect_names lists all eight (checked in the worker)."""
    from warp_mpm_bubbles import Box, Domain, Material, Output, Scene, SolverSettings, Sphere
    from warp_mpm_bubbles.scene.effects import (Collider, Entrainment, Foam, GasInjector, LiquidInflow,
                                                SubgridBubbles)

    return Scene(
        name="all_effects_2d", domain=Domain(size=(0.2, 0.2), cell_size=0.005),
        materials={"water": Material("water", surface_tension=0.072, viscosity=1.0e-3),
                   "air": Material("air", kind="gas", viscosity=1.8e-5)},
        shapes=[Box("water", (0.0, 0.0), (0.2, 0.1)), Sphere("air", center=(0.06, 0.04), radius=0.015)],
        effects={"foam": Foam(), "subgrid_bubbles": SubgridBubbles(), "entrainment": Entrainment()},
        emitters=[LiquidInflow("water", center=(0.16, 0.18), direction=(0.0, -1.0), radius=0.01, speed=1.0),
                  GasInjector("air", center=(0.15, 0.02), rate=200.0, radius=0.003, spread=0.01)],
        colliders=[Collider("sphere", center=(0.06, 0.16), radius=0.015, velocity=(0.0, -1.5), stop=0.05)],
        solver=SolverSettings(particles_per_cell=4),
        output=Output(path=str(Path(out_dir) / "f.usdc"), frames=10),  # the pour fills the box in 30 frames
    )


def worker(scene_name: str, steps: int, device: str) -> int:
    t0 = time.perf_counter()
    import warp as wp

    from warp_mpm_bubbles.core.simulation import Simulation

    t_import = time.perf_counter() - t0
    t0 = time.perf_counter()
    wp.init()
    t_init = time.perf_counter() - t0
    with tempfile.TemporaryDirectory(prefix="compile_time_") as out_dir:
        scene = (liquid_scene if scene_name == "liquid" else full_scene)(out_dir)
        t0 = time.perf_counter()
        sim = Simulation(scene, device=device)
        wp.synchronize_device(device)
        t_build = time.perf_counter() - t0
        t0 = time.perf_counter()
        sim.advance_to(sim.time + sim.stable_dt())  # one step, time kept so emitters and colliders run
        wp.synchronize_device(device)
        t_first = time.perf_counter() - t0
        t0 = time.perf_counter()
        for _ in range(steps - 1):
            sim.advance_to(sim.time + sim.stable_dt())
        wp.synchronize_device(device)
        t_rest = time.perf_counter() - t0
    result = {"effects": sim.effects, "particles": sim.num_particles, "import_seconds": t_import,
              "init_seconds": t_init, "build_seconds": t_build, "first_step_seconds": t_first,
              "next_steps_seconds": t_rest, "steps": steps, "kernels_launched": len(sim.launches)}
    print("RESULT " + json.dumps(result), flush=True)
    return 0


def call_worker(scene: str, cache: Path, args) -> dict:
    env = dict(os.environ, WARP_CACHE_PATH=str(cache))
    cmd = harness.module_command(__spec__.name, "--worker", scene, "--steps", args.steps, "--device", args.device)
    t0 = time.perf_counter()
    proc = subprocess.run(cmd, cwd=harness.ROOT, env=env, capture_output=True, text=True)
    wall = time.perf_counter() - t0
    lines = [ln for ln in proc.stdout.splitlines() if ln.startswith("RESULT ")]
    if proc.returncode or not lines:
        raise SystemExit(f"{scene} failed (exit {proc.returncode}):\n{proc.stdout[-3000:]}\n{proc.stderr[-3000:]}")
    out = json.loads(lines[-1][len("RESULT "):])
    modules = [{"module": m[1], "device": m[2], "ms": float(m[3]), "how": m[4]}
               for m in MODULE_LINE.finditer(proc.stdout + proc.stderr)]
    return {**out, "process_seconds": wall, "modules": modules,
            "compiled": sum(m["how"] == "compiled" for m in modules),
            "module_seconds": sum(m["ms"] for m in modules) / 1e3}


FIELDS = [("process_seconds", "whole process (s)"), ("import_seconds", "import warp + package (s)"),
          ("init_seconds", "wp.init() (s)"), ("build_seconds", "Simulation(scene) (s)"),
          ("first_step_seconds", "first step (s)"), ("next_steps_seconds", "next steps (s)"),
          ("module_seconds", "Warp module loads, sum (s)"), ("compiled", "modules compiled")]


def median_of(runs: list[dict], key: str) -> float:
    return statistics.median(r[key] for r in runs)


def module_medians(runs: list[dict]) -> dict[str, float]:
    """Median load time of each Warp module over the runs that loaded it (a module's first load)."""
    times: dict[str, list[float]] = {}
    for r in runs:
        for name in dict.fromkeys(m["module"] for m in r["modules"]):
            times.setdefault(name, []).append(next(m["ms"] for m in r["modules"] if m["module"] == name))
    return {name: statistics.median(t) for name, t in times.items()}


def markdown(meta: dict, runs: dict) -> str:
    scenes = [s for s in SCENES if runs[s]["cold"]]
    out = ["- load average at the end (1, 5, 15 min): " + ", ".join(f"{x:.1f}" for x in meta["load_average"]),
           f"- {meta['rounds']} round(s); per scene a cold process (WARP_CACHE_PATH: a new empty folder) then a "
           f"warm one (the same folder, now filled); {meta['steps']} steps each (the first timed apart); "
           "medians over rounds", ""]
    cols = [(s, kind) for s in scenes for kind in ("cold", "warm")]
    for s in scenes:
        first = runs[s]["cold"][0]
        out.append(f"- {s}: {', '.join(first['effects']) or 'water only'}; {first['particles']:,} particles at the end, "
                   f"{first['kernels_launched']} distinct kernels launched")
    out += ["", "| | " + " | ".join(f"{s} {kind}" for s, kind in cols) + " |", "|---|" + "---:|" * len(cols)]
    for key, label in FIELDS:
        cells = [median_of(runs[s][kind], key) for s, kind in cols]
        out.append(f"| {label} | " + " | ".join(f"{c:.0f}" if key == "compiled" else f"{c:.2f}" for c in cells) + " |")
    last = scenes[-1]  # the full scene's modules when it ran
    out += ["", f"Load time per Warp module (ms, median over rounds; the {last} scene's modules):", "",
            "| module | " + " | ".join(f"{s} {kind}" for s, kind in cols) + " |", "|---|" + "---:|" * len(cols)]
    per = {(s, kind): module_medians(runs[s][kind]) for s, kind in cols}
    for mod in sorted(per[(last, "cold")], key=lambda m: -per[(last, "cold")][m]):
        cell = lambda s, k: f"{per[(s, k)][mod]:.0f}" if mod in per[(s, k)] else "-"  # noqa: E731
        out.append(f"| {mod} | " + " | ".join(cell(s, k) for s, k in cols) + " |")
    return "\n".join(out) + "\n"


def main(argv=None) -> int:
    ap = harness.parser(__doc__.split("\n")[0], quick="the liquid scene only, 2 steps (the cold compile is still timed)")
    ap.add_argument("--rounds", type=int, default=1, help="cold + warm pairs per scene (default 1)")
    ap.add_argument("--steps", type=int, default=12, help="steps per process, the first timed apart (default 12)")
    ap.add_argument("--worker", choices=SCENES, help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.rounds < 1 or args.steps < 1:
        ap.error("need --rounds >= 1 and --steps >= 1")
    if args.worker:
        return worker(args.worker, args.steps, args.device)
    scenes = SCENES[:1] if args.quick else SCENES
    if args.quick:
        args.steps = 2

    runs = {s: {"cold": [], "warm": []} for s in SCENES}
    for r in range(args.rounds):
        for s in scenes if r % 2 == 0 else scenes[::-1]:
            cache = Path(tempfile.mkdtemp(prefix="warp_cold_cache_"))
            try:
                for kind in ("cold", "warm"):
                    runs[s][kind].append(call_worker(s, cache, args))
                    x = runs[s][kind][-1]
                    print(f"round {r + 1} {s} {kind}: process {x['process_seconds']:.1f} s, first step "
                          f"{x['first_step_seconds']:.1f} s, {x['compiled']} modules compiled", file=sys.stderr, flush=True)
            finally:
                shutil.rmtree(cache, ignore_errors=True)

    meta = {"load_average": list(os.getloadavg()), "rounds": args.rounds, "steps": args.steps}
    text = markdown(meta, runs)
    print(text)
    harness.write_result("compile_time", args, {"meta": meta, "runs": runs}, text,
                         title=f"Compile and start-up time on {harness.describe_device(args.device)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
