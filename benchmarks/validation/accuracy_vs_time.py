"""Accuracy against cost: the 2D reference cases of docs/design.md#validation over the settings that trade one for the other.

    python -m benchmarks.validation.accuracy_vs_time           # full study on the CPU (see its .md for the time)
    python -m benchmarks.validation.accuracy_vs_time --quick   # smoke run, into <device>_quick.*
    python -m benchmarks.validation.accuracy_vs_time --cases laplace,minnaert --out /tmp/acc
    python -m benchmarks.validation.accuracy_vs_time --only presets   # rerun the quality and seed rows, keep the rest
    python -m benchmarks.validation.accuracy_vs_time --quick --cases laplace --workers 1,2   # on 1 Dask worker, then 2

Cases (all 2D; the set-ups and error measures of the tests, re-created here so that the tests can
change without moving this study):
- dam_break: Martin & Moyce's column (width a = 0.1 m, height 2a, n^2 = 2) in a 6a x 2.5a tank, to
  T = t sqrt(2g/a) = 3.33 (tests/test_solver.py). Three measures from the one run:
  front_speed   |dZ/dT / (dZ/dT)_exp - 1|, least-squares slopes over T >= 1.4 (Z = front / a)
  front_position RMS of Z_exp(T + s) - Z(T) after the best gate-delay shift s in [-0.5, 1] (in a)
  volume_drift  |V_end / V_start - 1|, V = sum(min(phi, 1)) dx^3 over cells (Simulation.liquid_volume)
- minnaert: a 2D bubble (R0 = 1 cm, seeded at 1.02 p_atm) breathing in a free liquid disc of
  radius 5 R0, no gravity, 3.2 periods sampled 40 times per period (tests/test_gas.py); error
  |f / f0 - 1| with f0 from omega0^2 = 2 p0 / (rho R0^2 ln(Rinf/R0)) = 178.6 Hz.
- laplace: a 2D water drop (R = 1 cm, sigma = 0.072 N/m, no gravity) settling for 0.06 s
  (tests/test_tension.py); error |p_inside / (sigma/R) - 1|, p_inside the mean over r < R - 2 dx.
- rising_bubble: a 2 cm air bubble in water (sigma = 0.072 N/m) in a 0.08 x 0.16 m tank; rise speed
  of the gas centroid between t = 0.05 and 0.15 s. A 2D bubble has no analytic terminal speed: the
  error is against this study's finest-resolution run (production settings), not against physics.
- dam_break_3d: the same column in a 3D slab 0.5 a deep, at one resolution (12 cells per a), swept
  only over the settings whose 3D preset values differ from 2D (particles per cell, cfl) and the
  presets: the check behind the presets' 3D values.

Settings, each varied alone around the production defaults (the default resolution of each case
and quality = "production"): resolution (cells per a or per radius), particles_per_cell, cfl
(only on the cases where the CFL limit sets the step: on the others the sampling interval or the
capillary limit does), cg_tolerance, interface (gas cases), the three quality presets, and the
seed (each preset again with two more seeds: the noise floor of each measure, and whether a
preset lowers it). A preset is applied as `--quality` applies it, with Scene.with_quality, so its
grid refinement ([solver].refine) holds too: the `resolution` and `dx` columns give the grid
simulated (cells per a or radius of the refined grid), `refine` the factor.

Reruns: --only SETTING[,SETTING] (or --only presets, meaning quality,seed; --only all) reruns just
those sweeps of the chosen cases and merges them into the saved JSON: the rows they
replace go, every other row is kept with its measurement. Each row names its `batch`, the run that
measured it (meta.batches in the JSON); compare timings only within one batch.

Timing: every case first runs a few untimed steps at its smallest size, so Warp's kernels are
compiled or loaded before any timed run. wall_s and cpu_s cover only the simulation loop
(Simulation.advance_to), not set-up or the host-side measurements. Warp's CPU kernels run on one
thread; cpu_s (process time) is less disturbed than wall_s when other work shares the cores. Each
run is timed --repeat times and the fastest kept, except runs longer than --repeat-under seconds,
timed once (a long run averages contention bursts over its length).

Workers: --workers N runs the distinct runs as Dask tasks (the wedge engine's LocalCluster, one
single-threaded process per worker; `pip install '.[cluster]'`), each task warming up its case
first; --workers 1,2 runs them on 1 worker, then on 2, prints both wall times and refuses to
write if any measurement differs between them (the CPU runs are deterministic). The rows keep the
first count's per-run timings (on more workers than free cores, runs time each other's load).

Writes benchmarks/results/accuracy_vs_time/<device>.{json,csv,md,png} and <device>_presets.md (with
--quick: <device>_quick.*; --out names another results folder).
"""

from __future__ import annotations

import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import warp as wp

from warp_mpm_bubbles import Scene
from warp_mpm_bubbles.scene.quality import GOVERNED, PRESETS, preset_value
from warp_mpm_bubbles.core.simulation import Simulation

from benchmarks import harness
from benchmarks.validation.accuracy_cases import CASES, Case, Clock
from benchmarks.validation.accuracy_report import render


# ------------------------------------------------------------------------------------ running
def build_scene(case: Case, over: dict, tmp) -> Scene:
    """The case's scene at one point of a sweep: production with the point's overrides, or a preset
    applied as `--quality` applies it (Scene.with_quality: its cfl, tolerance, particles per cell and
    grid refinement replace the scene's)."""
    s = {k: v for k, v in over.items() if k not in ("quality", "resolution")}
    quality = over.get("quality", "production")
    scene = case.scene(s, over["resolution"], tmp)
    if any(k in s for k in GOVERNED):  # a sweep of one governed setting around production
        if quality != "production":
            raise ValueError(f"{case.key}: overrides {s} at quality {quality}; the sweeps vary one setting "
                             "around production")
        return scene
    # validated first: with_quality fails on a scene whose particles_per_cell is still unset
    return scene.validate().with_quality(quality)


SWEEPS_FULL = {"particles_per_cell": (2, 4, 9, 16), "cfl": (0.25, 0.5, 1.0, 1.5),
               "cg_tolerance": (1e-3, 1e-4, 1e-5, 1e-7), "interface": ("sharp", "baseline"),
               "quality": tuple(PRESETS), "seed": (0, 1, 2)}  # seeds: each preset at 3 seeds
SWEEPS_QUICK = {"particles_per_cell": (4, 9), "cfl": (0.5, 1.0), "cg_tolerance": (1e-3, 1e-5),
                "interface": ("sharp", "baseline"), "quality": ("preview", "production"), "seed": (0,)}


def plan(case: Case, quick: bool) -> list[tuple[str, object, dict]]:
    """(setting, value, overrides) for every point of every sweep of one case."""
    levels = case.quick_levels if quick else case.levels
    default = levels[0] if quick else case.default
    sweeps = SWEEPS_QUICK if quick else SWEEPS_FULL
    base = {"quality": "production", "resolution": default}
    points = [("resolution", n, {**base, "resolution": n}) for n in levels]
    for name, values in sweeps.items():
        if (name == "cfl" and not case.cfl_binds) or (name == "interface" and not case.gas):
            continue
        if name in case.sweeps:
            values = case.sweeps[name][:2] if quick else case.sweeps[name]
        if name == "seed":  # each preset (quick: production only) at every seed: the noise floor
            for q in (PRESETS if not quick else ("production",)):
                points += [("seed", v, {**base, "quality": q, "seed": v}) for v in values]
            continue
        for v in values:
            points.append((name, v, {**base, name: v}))
    return points


def run_key(case: Case, over: dict) -> tuple:
    """Runs with the same resolved settings are one run (e.g. cfl = 0.5 is the production default)."""
    resolved = dict(over)
    for k in ("particles_per_cell", "cfl", "cg_tolerance"):
        if resolved.get("quality") == "production" and resolved.get(k) == preset_value("production", k, case.dim):
            resolved.pop(k)
    if resolved.get("interface") == "sharp":
        resolved.pop("interface")
    if resolved.get("seed") == 0:
        resolved.pop("seed")
    return case.key, tuple(sorted((k, str(v)) for k, v in resolved.items()))


def warm_up(case: Case, tmp, device="cpu"):
    """Compile or load every kernel the case launches (untimed): a few steps at its smallest size."""
    sim = Simulation(build_scene(case, {"resolution": min(case.quick_levels)}, tmp), device)
    for _ in range(3):
        sim.step(sim.stable_dt())



# ------------------------------------------------------------------------------------- runs
def record(sim, metrics, clock) -> dict:
    """What the rows keep of one run."""
    sol = sim.scene.solver
    return dict(metrics=metrics, wall=clock.wall, cpu=clock.cpu, particles=sim.num_particles,
                cells=int(np.prod(sim.grid.interior)), steps=sim.stats.steps, dx=sim.grid.dx, refine=sol.refine,
                cg=sim.stats.cg_iterations / max(sim.stats.cg_solves, 1), ppc=sol.particles_per_cell, cfl=sol.cfl,
                tol=sol.cg_tolerance, interface=sol.interface, seed=sol.seed, quality=sol.quality, timed=1)


def report(i, n, case, over, r, timing=False):
    first = next(iter(r["metrics"].values()))
    shown = first["error_signed"] if np.isfinite(first["error_signed"]) else first["measured"]
    what = "error" if np.isfinite(first["error_signed"]) else "value"
    desc = " ".join(f"{k}={v}" for k, v in over.items() if not (k == "quality" and v == "production"))
    print(f"[{'time' if timing else 'run'} {i:3d}/{n}] {case.key:13s} {desc:45s} "
          f"{r['wall']:7.2f} s {r['steps']:5d} steps  {what} {shown:+.4g}", file=sys.stderr, flush=True)


def run_serial(keys, unique, args, tmp) -> dict:
    """Every distinct run in this process; repeats re-time every run in a later pass (contention
    bursts differ)."""
    for k in keys:
        warm_up(CASES[k], tmp, args.device)
    results = {}
    for rep in range(args.repeat):
        for i, (key, (case, over)) in enumerate(unique.items(), 1):
            if rep and results[key]["wall"] >= args.repeat_under:
                continue
            clock = Clock()
            sim = Simulation(build_scene(case, over, tmp), args.device)
            run = record(sim, case.measure(sim, clock), clock)
            if rep:  # the CPU run is deterministic: a repeat only re-measures the time
                r = results[key]
                r["wall"], r["cpu"] = min(r["wall"], clock.wall), min(r["cpu"], clock.cpu)
                r["timed"] += 1
            else:
                results[key] = run
            report(i, len(unique), case, over, run, timing=bool(rep))
            del sim
    return results


def measure_task(case_key: str, over: dict, tmp: str, repeat: int, repeat_under: float, device="cpu") -> dict:
    """One distinct run as a Dask task (in a worker process): warm up, run, re-time."""
    wp.config.log_level = getattr(wp, "LOG_WARNING", 30)
    case = CASES[case_key]
    warm_up(case, tmp, device)  # each worker loads the case's kernels untimed
    best = None
    for _ in range(repeat):
        clock = Clock()
        sim = Simulation(build_scene(case, over, tmp), device)
        run = record(sim, case.measure(sim, clock), clock)
        if best is None:
            best = run
        else:
            best["wall"], best["cpu"] = min(best["wall"], run["wall"]), min(best["cpu"], run["cpu"])
            best["timed"] += 1
        if run["wall"] >= repeat_under:
            break
    return best


def run_on_workers(unique, args, tmp) -> tuple[dict, dict]:
    """The distinct runs as Dask tasks on a LocalCluster of N single-threaded worker processes
    (the wedge engine's, warp_mpm_bubbles.io.wedge.dask_client), once per count in --workers. The
    rows keep the first count's timings; every later count must measure the same values."""
    from warp_mpm_bubbles.io.wedge import dask_client

    # The task by reference from the study imported as a module (the workers inherit this process's
    # path, which holds the repository root), not pickled by value out of __main__ with everything it touches.
    from benchmarks.validation import accuracy_vs_time as study

    counts = [int(w) for w in args.workers.split(",")]
    by_count, walls = {}, {}
    for n in counts:
        start = time.perf_counter()
        with dask_client(workers=n) as client:
            futures = client.map(study.measure_task, [case.key for case, _ in unique.values()],
                                 [over for _, over in unique.values()], tmp=tmp, repeat=args.repeat,
                                 repeat_under=args.repeat_under, device=args.device, pure=False, retries=1)
            runs = client.gather(futures)
        walls[n] = time.perf_counter() - start
        by_count[n] = dict(zip(unique, runs))
        for i, (key, (case, over)) in enumerate(unique.items(), 1):
            report(i, len(unique), case, over, by_count[n][key])
        print(f"{n} worker(s): {walls[n]:.1f} s for {len(unique)} runs (cluster start and warm-ups included)",
              file=sys.stderr, flush=True)
    first = by_count[counts[0]]
    for n in counts[1:]:
        for key, r in by_count[n].items():
            for metric, d in r["metrics"].items():
                a, b = d["measured"], first[key]["metrics"][metric]["measured"]
                if not (a == b or (np.isnan(a) and np.isnan(b))):
                    raise SystemExit(f"{key} {metric}: {a!r} with {n} workers, {b!r} with {counts[0]}")
        print(f"{n} worker(s): {walls[n]:.1f} s, speed-up {walls[counts[0]] / walls[n]:.2f}x over {counts[0]}; "
              f"every measurement identical", file=sys.stderr, flush=True)
    return first, {str(n): round(w, 2) for n, w in walls.items()}

# ------------------------------------------------------------------------------------- main
SETTINGS = ("resolution", *SWEEPS_FULL)  # the sweeps, in the order the tables list them
ALIASES = {"presets": ("quality", "seed"), "all": SETTINGS}


def load_saved(stem: Path) -> tuple[dict, list[dict]]:
    """The saved measurements; a file from before batches (one run) becomes batch 0 at refine 1."""
    saved = json.loads(stem.with_suffix(".json").read_text())
    meta, rows = saved["meta"], saved["rows"]
    if "batches" not in meta:
        meta = {"mode": meta.pop("mode"), "production": meta.pop("production"), "batches": [meta]}
        for r in rows:
            r.setdefault("batch", 0)
            r.setdefault("refine", 1)
    return meta, rows


def fine_reference(case: Case, levels, results: dict, saved_rows: list[dict]) -> dict:
    """{metric: measured} of the self-referenced case's finest production run: this run's, or the saved one."""
    key = run_key(case, {"quality": "production", "resolution": max(levels)})
    if key in results:
        return {m: d["measured"] for m, d in results[key]["metrics"].items()}
    fine = [r for r in saved_rows if r["case"] == case.key and r["setting"] == "resolution"
            and r["value"] == max(levels)]
    if not fine:
        raise SystemExit(f"{case.key}: its reference, the {max(levels)}-{case.unit} production run, is neither in "
                         "this run nor in the saved JSON; rerun with --only resolution,... as well")
    return {r["metric"]: r["measured"] for r in fine}


def main(argv=None) -> int:
    ap = harness.parser(__doc__.split("\n")[0], quick="smoke run: two coarse levels, two values per setting")
    ap.add_argument("--cases", default=",".join(CASES), help=f"comma-separated subset of {', '.join(CASES)}")
    ap.add_argument("--only", default=None,
                    help=f"rerun only these sweeps ({', '.join(SETTINGS)}; 'presets' = quality,seed; 'all') of "
                         "the --cases and merge them into the saved JSON, keeping every other "
                         "saved row")
    ap.add_argument("--repeat", type=int, default=None,
                    help="time each run this many times and keep the fastest (default 2, or 1 with --quick)")
    ap.add_argument("--repeat-under", type=float, default=60.0,
                    help="time only runs whose first pass took less than this many wall seconds again (default 60)")
    ap.add_argument("--workers", default=None,
                    help="run the distinct runs as Dask tasks on N single-threaded worker processes (the wedge "
                         "engine's LocalCluster; the [cluster] extra); a list such as 1,2 runs them once per count "
                         "and reports the wall time of each (the rows keep the first count's timings)")
    ap.add_argument("--no-plot", action="store_true", help="skip the PNG (no matplotlib needed)")
    ap.add_argument("--render-only", action="store_true",
                    help="rewrite the CSV, Markdown and plot from the saved JSON without running")
    args = ap.parse_args(argv)
    args.repeat = args.repeat or (1 if args.quick else 2)
    keys = [k.strip() for k in args.cases.split(",") if k.strip()]
    unknown = [k for k in keys if k not in CASES]
    if unknown or not keys:
        ap.error(f"unknown case(s) {unknown}; choose from {', '.join(CASES)}")
    only = None
    if args.only is not None:
        only = [s for w in args.only.split(",") if w.strip() for s in ALIASES.get(w.strip(), (w.strip(),))]
        if not only or any(s not in SETTINGS for s in only):
            ap.error(f"--only {args.only}: choose from {', '.join(SETTINGS)} or {', '.join(ALIASES)}")
    stem = harness.result_stem("accuracy_vs_time", args)
    stem.parent.mkdir(parents=True, exist_ok=True)
    if args.render_only:
        if not stem.with_suffix(".json").exists():
            ap.error(f"--render-only: no saved run at {stem.with_suffix('.json')}: run the study first")
        meta, rows = load_saved(stem)
        render(stem, meta, rows, args)
        return 0
    mode = "quick" if args.quick else "full"
    saved_meta, saved_rows = ({"batches": [], "mode": mode}, [])
    if only and stem.with_suffix(".json").exists():  # merged into the saved run; else a new file of these sweeps
        saved_meta, saved_rows = load_saved(stem)
    if only and saved_meta.get("mode") != mode:
        ap.error(f"--only merges into the saved {saved_meta.get('mode')} run: run it in that mode")

    start = time.perf_counter()
    wp.config.quiet = True
    wp.init()
    production = {k: PRESETS["production"][k] for k in ("particles_per_cell", "cfl", "cg_tolerance")}
    meta = {"mode": mode, "production": ", ".join(f"{k} = {v}" for k, v in production.items()) + ", interface = sharp",
            "batches": saved_meta["batches"]}
    prov = harness.provenance(args.device)  # per batch: the rows of one file may come from several runs
    changed = ", ".join(prov["changed_files"])
    batch = {"date": prov["date"], "warp": prov["versions"]["warp"], "python": prov["python"], "device": prov["device"],
             "code": prov["commit"] + (f" with uncommitted changes to {changed}" if changed else ""),
             "command": prov["command"], "repeat": args.repeat, "repeat_under_s": args.repeat_under,
             "only": f"the {', '.join(only)} sweeps of {', '.join(keys)}" if only else "everything"}

    todo = []  # (case, setting, value, overrides)
    for k in keys:
        todo += [(CASES[k], *p) for p in plan(CASES[k], args.quick) if only is None or p[0] in only]
    unique = {}
    for case, _, _, over in todo:
        unique.setdefault(run_key(case, over), (case, over))
    print(f"{len(todo)} points, {len(unique)} distinct runs over {len(keys)} case(s) ({mode} mode"
          f"{', only ' + ', '.join(only) if only else ''})", file=sys.stderr, flush=True)

    with tempfile.TemporaryDirectory() as tmp:
        if args.workers:
            results, batch["workers_wall_s"] = run_on_workers(unique, args, tmp)
        else:
            results = run_serial(keys, unique, args, tmp)

    # rising bubble: the reference is the finest production run of the study
    for case in (CASES[k] for k in keys if CASES[k].self_referenced):
        fine = fine_reference(case, case.quick_levels if args.quick else case.levels, results, saved_rows)
        for key, r in results.items():
            if key[0] == case.key:
                for m, d in r["metrics"].items():
                    d["reference"] = fine[m]
                    d["error_signed"] = d["measured"] / d["reference"] - 1.0

    default_key = {k: run_key(CASES[k], {"quality": "production", "resolution": CASES[k].quick_levels[0]
                                         if args.quick else CASES[k].default}) for k in keys}
    b = len(meta["batches"])
    first_id = 1 + max((r["run_id"] for r in saved_rows), default=-1)
    rows = []
    for case, setting, value, over in todo:
        key = run_key(case, over)
        r = results[key]
        for metric, d in r["metrics"].items():
            rows.append({"case": case.key, "metric": metric, "setting": setting, "value": value,
                         "is_default": int(key == default_key[case.key]),
                         "run_id": first_id + list(results).index(key), "batch": b, "quality": r["quality"],
                         "resolution": over["resolution"] * r["refine"], "resolution_unit": case.unit,
                         "dx": r["dx"], "refine": r["refine"], "particles_per_cell": r["ppc"], "cfl": r["cfl"],
                         "cg_tolerance": r["tol"], "interface": r["interface"], "seed": r["seed"],
                         "particles": r["particles"], "cells": r["cells"], "steps": r["steps"],
                         "cg_iterations_mean": r["cg"], "wall_s": r["wall"], "cpu_s": r["cpu"],
                         "measured": float(d["measured"]), "reference": float(d["reference"]),
                         "error": abs(float(d["error_signed"])), "error_signed": float(d["error_signed"]),
                         "error_kind": d["error_kind"], "note": d["note"]})

    if only:  # the replaced rows go; where a replaced run had the same settings, did its error move?
        replaced = [r for r in saved_rows if r["case"] in keys and r["setting"] in only]
        same = [(o, n) for o in replaced for n in rows
                if all(o[k] == n[k] for k in ("case", "metric", "setting", "value", "quality", "seed", "dx",
                                              "particles_per_cell", "cfl", "cg_tolerance", "interface"))]
        change = max((abs(n["error_signed"] - o["error_signed"]) for o, n in same), default=None)
        batch["rerun_same_settings"] = {"rows": len(same), "max_abs_error_change": change}
        kept = [r for r in saved_rows if not (r["case"] in keys and r["setting"] in only)]
        order = {(c, s): i for i, (c, s) in enumerate((c, s) for c in CASES for s in SETTINGS)}
        rows = sorted(kept + rows, key=lambda r: order[(r["case"], r["setting"])])  # stable: sweep order kept
    batch["runs"] = len(unique)
    batch["timed_runs"] = sum(r["timed"] for r in results.values())
    batch["contention"] = sum(r["wall"] for r in results.values()) / max(sum(r["cpu"] for r in results.values()), 1e-9)
    batch["total_minutes"] = (time.perf_counter() - start) / 60
    meta["batches"].append(batch)
    harness.write_result("accuracy_vs_time", args, {"meta": meta, "rows": rows})
    print("(the JSON holds the measurements; --render-only rewrites the rest from it)", file=sys.stderr)
    render(stem, meta, rows, args)
    return 0


if __name__ == "__main__":
    sys.exit(main())
