"""Accuracy against cost: the 2D reference cases of docs/design.md#validation over the settings that trade one for the other.

    python benchmarks/accuracy_vs_time.py            # full study on the CPU, writes docs/ (see its .md for the time)
    python benchmarks/accuracy_vs_time.py --quick    # smoke run, into benchmarks/results/accuracy_quick/
    python benchmarks/accuracy_vs_time.py --cases laplace,minnaert --out-dir /tmp/acc
    python benchmarks/accuracy_vs_time.py --only presets   # rerun the quality and seed rows, keep the rest
    python benchmarks/accuracy_vs_time.py --quick --cases laplace --workers 1,2   # on 1 Dask worker, then 2

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
those sweeps of the chosen cases and merges them into <out-dir>/accuracy_vs_time.json: the rows they
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

Writes <out-dir>/accuracy_vs_time.{csv,md,png} and <out-dir>/presets.md (default out-dir: docs/,
or benchmarks/results/accuracy_quick/ with --quick).
"""

from __future__ import annotations

import argparse
import csv
import datetime
import json
import math
import platform
import shlex
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from itertools import pairwise
from pathlib import Path

import numpy as np
import warp as wp

from warp_mpm_bubbles import Box, Cylinder, Domain, Material, Output, Scene, SolverSettings, Sphere
from warp_mpm_bubbles.diagnostics import gas_centroid_and_diameter
from warp_mpm_bubbles.scene.quality import GOVERNED, PRESETS, preset_value
from warp_mpm_bubbles.core.simulation import Simulation
from warp_mpm_bubbles.core.timing import describe_device

ROOT = Path(__file__).resolve().parent.parent
MARTIN_MOYCE = ROOT / "tests" / "data" / "martin_moyce_1952_n2_2_a2.25in.csv"
G, P_ATM, RHO_W, SIGMA = 9.81, 101325.0, 1000.0, 0.072

COLUMNS = ["case", "metric", "setting", "value", "is_default", "run_id", "batch", "quality", "resolution",
           "resolution_unit", "dx", "refine", "particles_per_cell", "cfl", "cg_tolerance", "interface", "seed",
           "particles", "cells", "steps", "cg_iterations_mean", "wall_s", "cpu_s", "measured", "reference", "error",
           "error_signed", "error_kind", "note"]


# ------------------------------------------------------------------------------------ running
class Clock:
    """Wall and process seconds spent inside Simulation.advance_to, nothing else."""

    def __init__(self):
        self.wall = self.cpu = 0.0

    def advance(self, sim, t):
        w, c = time.perf_counter(), time.process_time()
        sim.advance_to(t)
        self.wall += time.perf_counter() - w
        self.cpu += time.process_time() - c


def solver_settings(s: dict, **extra) -> SolverSettings:
    """s: the overrides of the production settings (None or absent: the preset's value)."""
    return SolverSettings(particles_per_cell=s.get("particles_per_cell"), cfl=s.get("cfl"),
                          cg_tolerance=s.get("cg_tolerance"), interface=s.get("interface", "sharp"),
                          seed=s.get("seed", 0), **extra)


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


def _output(tmp):
    return Output(path=str(Path(tmp) / "unused.usdc"))  # validated for writability, never written here


# -------------------------------------------------------------------------------------- cases
A = 0.1  # dam-break column width


def dam_break_scene(s: dict, res: int, tmp) -> Scene:
    a = A
    return Scene(domain=Domain(size=(6 * a, 2.5 * a), cell_size=a / res),
                 materials={"water": Material("water", density=RHO_W)},
                 shapes=[Box("water", min=(0.0, 0.0), max=(a, 2 * a))],
                 solver=solver_settings(s), output=_output(tmp), name="dam_break_2d")


def dam_break_3d_scene(s: dict, res: int, tmp) -> Scene:
    """The same column in a 3D slab 0.5 a deep (free-slip walls): checks the presets' 3D values."""
    a = A
    return Scene(domain=Domain(size=(6 * a, 2.5 * a, 0.5 * a), cell_size=a / res),
                 materials={"water": Material("water", density=RHO_W)},
                 shapes=[Box("water", min=(0.0, 0.0, 0.0), max=(a, 2 * a, 0.5 * a))],
                 solver=solver_settings(s), output=_output(tmp), name="dam_break_3d")


def dam_break(sim: Simulation, clock: Clock) -> dict:
    a = A
    ref = np.loadtxt(MARTIN_MOYCE, delimiter=",", comments="#", skiprows=4)[1:]  # T = 0 skipped, as the test
    volume0 = sim.liquid_volume()
    unit = math.sqrt(a / (2 * G))
    front = []
    for T, _ in ref:
        clock.advance(sim, T * unit)
        front.append(sim.particles_numpy()["positions"][:, 0].max() / a)
    front = np.array(front)
    drift = sim.liquid_volume() / volume0 - 1.0
    late = ref[:, 0] >= 1.4
    slope = np.polyfit(ref[late, 0], front[late], 1)[0]
    slope_ref = np.polyfit(ref[late, 0], ref[late, 1], 1)[0]
    shifts = np.linspace(-0.5, 1.0, 151)
    rms = np.array([_shifted_rms(ref, front, sh) for sh in shifts])
    best = int(np.nanargmin(rms))
    return {
        "front_speed": dict(measured=slope, reference=slope_ref, error_signed=slope / slope_ref - 1.0,
                            error_kind="relative", note=""),
        "front_position": dict(measured=rms[best], reference=0.0, error_signed=rms[best], error_kind="a (RMS)",
                               note=f"gate shift dT = {shifts[best]:+.2f}"),
        "volume_drift": dict(measured=1.0 + drift, reference=1.0, error_signed=drift, error_kind="relative",
                             note=""),
    }


def _shifted_rms(ref, front, shift):
    """RMS of Z_ref(T + shift) - Z_sim(T) where the shifted reference exists (tests/test_solver.py)."""
    T = ref[:, 0] + shift
    ok = (T >= ref[0, 0]) & (T <= ref[-1, 0])
    if ok.sum() < 8:
        return np.nan
    return float(np.sqrt(np.mean((np.interp(T[ok], ref[:, 0], ref[:, 1]) - front[ok]) ** 2)))


R0, R_INF = 0.01, 0.05
OMEGA_2D = math.sqrt(2 * P_ATM / (RHO_W * R0**2 * math.log(R_INF / R0)))
PERIOD = 2 * math.pi / OMEGA_2D
SAMPLES_PER_PERIOD = 40


def minnaert_scene(s: dict, res: int, tmp) -> Scene:
    L, period = 12 * R0, PERIOD
    return Scene(domain=Domain(size=(L, L), cell_size=R0 / res, gravity=(0.0, 0.0), walls="open"),
                 materials={"water": Material("water"), "air": Material("air", kind="gas")},
                 shapes=[Cylinder("water", center=(L / 2, L / 2), radius=R_INF),
                         Cylinder("air", center=(L / 2, L / 2), radius=R0, pressure=0.02 * P_ATM)],
                 solver=solver_settings(s, max_dt=period / SAMPLES_PER_PERIOD), output=_output(tmp))


def minnaert(sim: Simulation, clock: Clock) -> dict:
    period = PERIOD
    v0 = sim.gas_budget()["volume"]
    t, V = [], []
    while sim.time < 3.2 * period:
        clock.advance(sim, sim.time + period / SAMPLES_PER_PERIOD)
        t.append(sim.time)
        V.append(sim.gas_budget()["volume"])
    t, V = np.array(t), np.array(V)
    x = V - V.mean()
    up = [t[i] - x[i] * (t[i + 1] - t[i]) / (x[i + 1] - x[i]) for i in range(len(x) - 1) if x[i] < 0 <= x[i + 1]]
    f_ref = OMEGA_2D / (2 * math.pi)
    f = 1.0 / np.diff(up).mean() if len(up) >= 3 else np.nan
    return {"frequency": dict(
        measured=f, reference=f_ref, error_signed=f / f_ref - 1.0, error_kind="relative",
        note=f"mean V / V_seed = {V.mean() / v0:.4f} (pV: 1.02)" + ("" if len(up) >= 3 else "; < 3 up-crossings"))}


L_DROP = 0.04


def laplace_scene(s: dict, res: int, tmp) -> Scene:
    L = L_DROP
    return Scene(domain=Domain(size=(L, L), cell_size=R0 / res, gravity=(0.0, 0.0)),
                 materials={"water": Material("water", surface_tension=SIGMA)},
                 shapes=[Cylinder("water", center=(L / 2, L / 2), radius=R0)],
                 solver=solver_settings(s), output=_output(tmp))


def laplace(sim: Simulation, clock: Clock) -> dict:
    L = L_DROP
    speeds = []
    while sim.time < 0.06 - 1e-12:
        clock.advance(sim, sim.time + 0.005)
        speeds.append(np.linalg.norm(sim.particles_numpy()["velocities"], axis=1).max())
    centres = sim.grid.cell_centres()[sim.grid.interior_slice()][:, :, 0, :2]
    r = np.linalg.norm(centres - L / 2, axis=-1)
    inside = float(sim.pressure_numpy()[:, :, 0][r < R0 - 2 * sim.grid.dx].mean())
    ref = SIGMA / R0
    capillary = math.sqrt(SIGMA / (RHO_W * R0))
    return {"pressure_jump": dict(
        measured=inside, reference=ref, error_signed=inside / ref - 1.0, error_kind="relative",
        note=f"spurious currents max {max(speeds) / capillary:.0%} of sqrt(sigma/(rho R))")}


RISE_WINDOW = (0.05, 0.15)


def rising_bubble_scene(s: dict, res: int, tmp) -> Scene:
    return Scene(domain=Domain(size=(0.08, 0.16), cell_size=R0 / res),
                 materials={"water": Material("water", surface_tension=SIGMA), "air": Material("air", kind="gas")},
                 shapes=[Box("water", min=(0.0, 0.0), max=(0.08, 0.14)),
                         Sphere("air", center=(0.04, 0.03), radius=R0)],
                 solver=solver_settings(s), output=_output(tmp))


def rising_bubble(sim: Simulation, clock: Clock) -> dict:
    y = []
    for t in RISE_WINDOW:
        clock.advance(sim, t)
        p = sim.particles_numpy()
        gas = p["material"] == 1
        y.append(gas_centroid_and_diameter(p["positions"], gas, p["volume"], 2)[0][1])
    speed = (y[1] - y[0]) / (RISE_WINDOW[1] - RISE_WINDOW[0])
    vented = sim.gas_budget()["vented"] / sim.gas_budget()["total"]
    # reference filled in later: the finest-resolution production run of this study
    return {"rise_speed": dict(
        measured=speed, reference=np.nan, error_signed=np.nan, error_kind="relative to finest run",
        note=f"gas vented {vented:.1%}" if vented else "")}


@dataclass
class Case:
    key: str
    scene: Callable  # (overrides, resolution, tmp dir) -> Scene
    measure: Callable  # (Simulation, Clock) -> {metric: dict(measured, reference, error_signed, error_kind, note)}
    metrics: dict[str, str]  # metric -> panel title
    unit: str  # what the resolution counts
    levels: tuple[int, ...]
    default: int
    quick_levels: tuple[int, ...]
    gas: bool = False
    cfl_binds: bool = False
    self_referenced: bool = False  # error against the finest run of the study
    sweeps: dict = field(default_factory=dict)  # per-case values of a sweep (quick: the first two)
    dim: int = 2


CASES = {c.key: c for c in [
    Case("laplace", laplace_scene, laplace, {"pressure_jump": "Laplace jump, 2D drop: |p / (sigma/R) - 1|"},
         "cells per radius", (4, 6, 8, 12, 16), 8, (4, 6)),
    Case("dam_break", dam_break_scene, dam_break,
         {"front_speed": "dam break front speed vs Martin & Moyce: |dZ/dT rel. error|",
          "front_position": "dam break front position: RMS after gate shift (a)",
          "volume_drift": "dam break liquid volume drift: |V/V0 - 1|"},
         "cells per a", (8, 12, 16, 24, 32), 16, (8, 12), cfl_binds=True),
    Case("minnaert", minnaert_scene, minnaert, {"frequency": "Minnaert 2D breathing: |f / f0 - 1|"},
         "cells per radius", (4, 6, 8, 12, 16), 8, (4, 6), gas=True),
    Case("rising_bubble", rising_bubble_scene, rising_bubble,
         {"rise_speed": "rising bubble 2D: rise speed vs finest run"},
         "cells per radius", (3, 4, 6, 8, 12), 4, (3, 4), gas=True, cfl_binds=True, self_referenced=True),
    # 3D: one resolution; only the settings whose 3D values the presets set differently from 2D
    Case("dam_break_3d", dam_break_3d_scene, dam_break,
         {"front_speed": "3D dam break (slab 0.5a) front speed vs Martin & Moyce",
          "front_position": "3D dam break front position: RMS after gate shift (a)",
          "volume_drift": "3D dam break liquid volume drift: |V/V0 - 1|"},
         "cells per a", (12,), 12, (8,), cfl_binds=True,
         sweeps={"particles_per_cell": (8, 27), "cfl": (0.5, 0.25, 1.0), "cg_tolerance": ()}, dim=3),
    # (the default first, so that --quick runs the default and one alternative)
]}

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


def warm_up(case: Case, tmp):
    """Compile or load every kernel the case launches (untimed): a few steps at its smallest size."""
    sim = Simulation(build_scene(case, {"resolution": min(case.quick_levels)}, tmp), "cpu")
    for _ in range(3):
        sim.step(sim.stable_dt())


# ------------------------------------------------------------------------------ convergence
NOISE_FACTOR = 2.0  # a level counts in a fit when its error exceeds this many times the seed range


def fit_order(points, noise):
    """points: [(dx, error)], coarse to fine. Returns (p, used, verdict, local orders)."""
    pts = [(dx, e) for dx, e in points if np.isfinite(e) and e > 0]
    local = [math.log(e1 / e2) / math.log(d1 / d2) for (d1, e1), (d2, e2) in pairwise(pts)]
    above = [(dx, e) for dx, e in pts if e > noise]
    if len(pts) >= 2:
        p_all = float(np.polyfit(np.log([d for d, _ in pts]), np.log([e for _, e in pts]), 1)[0])
    else:
        p_all = np.nan
    if len(above) < 3:
        return p_all, len(above), f"no clean order: {len(above)} level(s) above the seed noise", local
    errs = [e for _, e in above]
    if any(e2 >= e1 for e1, e2 in pairwise(errs)):
        return p_all, len(above), "no clean order: error not monotone in dx", local
    p = float(np.polyfit(np.log([d for d, _ in above]), np.log(errs), 1)[0])
    return p, len(above), f"p = {p:.2f} over {len(above)} levels", local


# ---------------------------------------------------------------------------------- writing
def fmt(x, digits=3):
    if isinstance(x, str):
        return x
    if x is None or (isinstance(x, float) and not math.isfinite(x)):
        return "-"
    if isinstance(x, (int, np.integer)):
        return f"{x:,}"
    return f"{x:.{digits}g}"


def write_csv(path, rows):
    with open(path, "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=COLUMNS)
        w.writeheader()
        for r in rows:
            w.writerow({k: (f"{r[k]:.6g}" if isinstance(r[k], float) else r[k]) for k in COLUMNS})


def value_label(setting, value):
    if setting == "cg_tolerance":
        return f"{value:.0e}"
    return str(value)


def batch_lines(meta) -> list[str]:
    """Markdown items naming each run (batch) whose rows are in the tables."""
    out = []
    for i, b in enumerate(meta["batches"]):
        timed = (f"each timed {b['repeat']}×, the fastest kept" if "repeat_under_s" not in b else
                 f"each timed {b['repeat']}× (once if over {b['repeat_under_s']:g} s), the fastest kept")
        out.append(f"- batch {i}: {b['date']} on {b['device']}; warp {b['warp']}, python {b['python']}; code "
                   f"{b['code']}; `{b['command']}` ({meta['mode']} mode; measured {b.get('only', 'everything')}; "
                   f"{b['runs']} runs, {timed}; {b['total_minutes']:.1f} min in all, warm-up and set-up "
                   f"included; summed wall / CPU time {b['contention']:.2f})")
        if b.get("workers_wall_s"):
            out[-1] += "; as Dask tasks, " + ", ".join(f"{n} worker(s) {w:.1f} s" for n, w in b["workers_wall_s"].items())
        same = b.get("rerun_same_settings")
        if same and same["rows"]:
            change = same["max_abs_error_change"]
            out.append(f"  - the {same['rows']} rows it re-measured at unchanged settings " + (
                "reproduced the errors they replaced exactly" if change == 0 else
                f"moved their errors by up to {change:.2g} from those they replaced (the code changed between)"))
    return out


def markdown(meta, rows, orders, noise) -> str:
    devices = ", ".join(dict.fromkeys(b["device"] for b in meta["batches"]))
    out = [f"# Accuracy against time: reference cases (2D, and one 3D check) on {devices}", "",
           *batch_lines(meta),
           f"- production defaults: {meta['production']}; every setting varied alone around them at each "
           "case's default resolution (marked **bold**)",
           "- cost: `wall_s`, seconds of the simulation loop only (kernels compiled beforehand; set-up and "
           "measurements excluded). The 2 CPU cores are shared with other work, so single timings carry "
           "tens of % of noise; compare ratios within one batch. `cpu_s` is the process time of the same "
           "loop (Warp's CPU kernels use one thread), less disturbed by other work (the batches above give "
           "the summed wall time over the summed CPU time). Each run was timed as often as its batch says, "
           "the fastest kept. Batches ran at different times and loads, so the `× default` column divides by "
           "the default run of the row's own batch.",
           "- errors: see the script's docstring for each measure. `seed` rows rerun the default with other "
           "seeds: their spread is the noise floor of a measure. The rising-bubble error is against the "
           "finest run of this study (no 2D analytic terminal speed), so it measures convergence, not truth.",
           "- grid: the `grid` column counts cells per a or per radius of the grid simulated, refined where "
           "a preset refines it ([solver].refine; `refine` in the CSV, `dx` the spacing).",
           "- data: `accuracy_vs_time.csv` (one row per point and measure; the default run is repeated in "
           "every sweep with the same `run_id`; `batch` names the run that measured it); plot: "
           "`accuracy_vs_time.png`.", ""]
    for case in CASES.values():
        crow = [r for r in rows if r["case"] == case.key]
        if not crow:
            continue
        metrics = list(case.metrics)
        out += [f"## {case.key}", "",
                f"Grid: {case.unit}.", "",
                "| setting | value | grid | batch | wall s | cpu s | × default (wall, cpu) | steps | particles | "
                "CG it. | " + " | ".join(metrics) + " |",
                "|---|---|---:|---:|---:|---:|---:|---:|---:|---:|" + "---:|" * len(metrics)]
        d0 = {}  # the default run of each batch
        for r in crow:
            if r["is_default"]:
                d0.setdefault(r["batch"], r)
        seen = []
        for r in crow:
            key = (r["setting"], r["value"], r["quality"])
            if r["metric"] != metrics[0] or key in seen:
                continue
            seen.append(key)
            errs = []
            for m in metrics:
                rr = next(x for x in crow if x["metric"] == m and (x["setting"], x["value"], x["quality"]) == key)
                errs.append(fmt(rr["error_signed"]) + (f" ({rr['note']})" if rr["note"] and m != "volume_drift"
                                                        else ""))
            label = value_label(r["setting"], r["value"])
            if r["setting"] == "seed":
                label = f"{label} ({r['quality']})"
            if r["is_default"]:
                label = f"**{label}**"
            d = d0.get(r["batch"])
            ratio = f"{r['wall_s'] / d['wall_s']:.2f}, {r['cpu_s'] / d['cpu_s']:.2f}" if d else "-"
            out.append(f"| {r['setting']} | {label} | {r['resolution']} | {r['batch']} | {r['wall_s']:.2f} | "
                       f"{r['cpu_s']:.2f} | {ratio} | "
                       f"{r['steps']} | {r['particles']:,} | {r['cg_iterations_mean']:.1f} | " + " | ".join(errs)
                       + " |")
        out.append("")
        out.append("Errors are signed (`error_signed`: simulated minus reference, relative unless the measure "
                   "is in `a`); the plot shows their magnitude.")
        out.append("")
    out += ["## Convergence with resolution (error ∝ dx^p)", "",
            f"A level counts when its error exceeds {NOISE_FACTOR:g}× the seed noise (the range of the signed "
            "error over 3 seeds of the production default; coarser levels are noisier, so this is lenient). "
            "A verdict gives an order only for at least 3 such levels with the error falling at each "
            "refinement. `p (all)` is the least-squares slope over every level, shown even when it means "
            "little. The rising bubble's finest level is its own reference and is left out.", "",
            "| measure | resolution levels | errors | local orders | seed noise | p (all) | verdict |",
            "|---|---|---|---|---:|---:|---|"]
    for (case, metric), o in orders.items():
        out.append(f"| {case}: {metric} | {', '.join(str(n) for n in o['levels'])} | "
                   f"{', '.join(fmt(e, 2) for e in o['errors'])} | {', '.join(f'{q:.1f}' for q in o['local'])} | "
                   f"{fmt(noise.get((case, metric), np.nan), 2)} | {fmt(o['p_all'], 2)} | {o['verdict']} |")
    out += ["", CONVERGENCE_NOTE]
    return "\n".join(out) + "\n"


CONVERGENCE_NOTE = """\
Reading it (written for the runs recorded here; revisit if a rerun moves the numbers):

- The Minnaert frequency no longer depends on resolution: -0.7% to -1.5% at every level from 4
  to 16 cells per radius (-1.5%, -1.5%, -1.4% at 8, 12, 16; seed noise 0.17% at 8), an offset
  the grid does not remove. Before 100b05b (the gas takes its cells' volume change) the error
  fell from 10% at 4 to 3.5% at 16, at an order below one: that error was the gas's share of the
  compression going to the liquid beside it, not the grid.
- The dam break's volume drift no longer converges: -1.14%, -0.93%, -1.05%, -0.96% at 12, 16,
  24, 32 cells per a (batch 7, b45dea0). At ef88534 it shrank as dx^1 (-0.68% at 12 to -0.17% at
  32), but that was the old correction's share per step, whose strength per second grew as the
  finer grids' steps shrank. Since the correction is a rate (a relaxation time in seconds,
  design.md #volume-correction), the drift is set by that time: without the correction it is
  -2.8% to -3.2% at every level, at 3 ms -0.67% / -0.54% / -0.49% / -0.37%, at 1 ms about -0.1%
  to -0.2%, at the default 10 ms about -1% (scratch runs of this case). The clustering the
  correction undoes does not shrink with the grid here, so the drift is a model setting's, not a
  grid error. [solver].volume_correction_speed ties the time to the grid (tau = dx / U) and makes
  the drift converge: at U = 1 m/s -1.05%, -0.73%, -0.61%, -0.40%, -0.26%, -0.24% at 12 to 64
  cells per a (scratch runs; design.md #volume-correction says why it is not the default). The
  8-cell run's near-zero drift is presumably gains and losses cancelling.
- The dam break's front against Martin & Moyce does not converge: the front-speed error grows
  from 3% to 6% as the grid is refined and the position RMS stays at 0.03 a. What remains is the
  model against the experiment (inviscid 2D, the gate's lift, the one-particle tip), not
  discretization error, so neither measure can rank settings by numerical accuracy.
- The Laplace jump (since 159af47, curvature from height functions): -2.2%, -1.4%, -0.9% at 8,
  12, 16 cells per radius (seed 0; local orders 1.1 and 1.8), but each within 2x its seed noise
  (a range of 2.5% over 3 seeds at 8), so the verdict above cannot count them; the reference
  preset's three seeds at 16 average 0.63% against production's 1.39% at 8. At 6 cells per
  radius (-8.7%) the 7-cell height columns barely fit the drop.
- The rising bubble's speed against the 12-cell run: +2.5%, -3.6%, -3.9%, -3.2% at 3, 4, 6, 8
  cells per radius (seed noise 1.2%): it does not converge, as the free-surface case of
  benchmarks/convergence.py does not (docs/convergence.md; open in issue #12). The 2D bubble's
  wake and break-up make the speed chaotic.
"""


PRESETS_NOTE = """\
What the presets buy (the table above; written for the runs recorded here, revisit if a rerun
moves the numbers). Reference simulates a grid twice as fine along each axis (refine = 2), on top
of cfl 0.25 and cg_tolerance 1e-6. The cases with surface tension were re-measured at 9120f3f
(batch 5, the height-function curvature), the dam breaks at b45dea0 (batches 6-8); the closed
tanks of benchmarks/convergence.py, which converge, carry the presets too (docs/convergence.md,
"The quality presets"). Means over 3 seeds, production's first:

- Reference lowers the error, beyond the seed noise, on every measure that converges with the
  grid: the Laplace jump (0.63% against 1.39%; seed ranges 1.9% and 2.5%), the Minnaert frequency
  (1.29% against 1.53%; ranges 0.22% and 0.17%), the 3D front position (0.028 a against 0.034 a)
  and, in the convergence study, every metric of the 2D and 3D closed tanks.
- Not lowered: the dam break's volume drift (2D 0.93% against 0.94%, 3D 0.67% against 0.53%): it
  is set by the volume correction's relaxation time, not by the grid (the convergence notes); the
  front speed against Martin & Moyce (2D 5.4% against 4.2%, 3D 4.9% against 2.8%), which moves
  away from the experiment as the grid is refined in the sweep too: it measures the model against
  the experiment; and the free-surface rising bubble (3.7% against 3.4% of the 12-cell run, ranges
  2.8% and 1.2%), which does not converge (open in issue #12).
- Preview against production: the same errors to 3 digits where cfl does not set the step (the
  Laplace drop and the Minnaert bubble: the capillary limit and the sampling interval do; the closed
  tanks), for 0.8-1.2x the time there. Where it does, preview halves the steps: the dam break's
  drift rises (2D 1.11% against 0.94%, 3D 0.71% against 0.53%) and its front position's RMS (2D
  0.033 a against 0.029 a, 3D 0.041 a against 0.034 a); the rising bubble's error moves within its
  seed ranges (2.8% against 3.4%, ranges 4.9% and 1.2%).
- Cost, CPU seconds against production in the same batch: reference 3.6-4.9x for the 2D
  capillary-limited and sampled cases (4x the cells), 8.5-10x for the 2D dam break and the rising
  bubble (4x the cells, 3.7-4x the steps), 20x for the 3D dam break (8x the cells, 3.6x the
  steps). Preview costs 0.5-0.6x where cfl sets the step.

How the governed values were chosen (warp_mpm_bubbles/scene/quality.py), from the one-at-a-time
sweeps in accuracy_vs_time.md (the figures below are those of the batch that chose them, at
ef88534; the sweeps re-measured since moved the volume drifts, as the notes above say, not the
choice). Production was left as it was (the test suite is calibrated on it).

- cg_tolerance moved no error beyond its seed noise anywhere between 1e-3 and 1e-7: the dam break,
  Laplace and Minnaert errors agree to 3-4 digits, the rising bubble's move within its seed range.
  Each decade costs CG iterations (dam break: 3.1 per solve at 1e-3, 4.8 at 1e-5, 6.4 at 1e-7).
  Preview takes 1e-3; reference 1e-6, a decade below production as a margin (1e-7 bought nothing).
- cfl sets the step only in the free-surface and rising-bubble runs (the capillary limit and the
  sampling interval set it in the Laplace and Minnaert runs). Doubling it to 1.0 halves the steps;
  the 2D dam break's front is unchanged within the seed noise and its volume drift about doubles
  (0.9%, still under the tests' 1%); in 3D the front's RMS rises by a fifth (0.041 a against 0.034
  a). At 1.5 the 2D front moves too (0.041 a). Halving it to 0.25 lowers the volume drift (2D
  0.16% against 0.42%, 3D 0.35% against 0.46%, means over 3 seeds) and the 3D front's RMS. Hence
  preview 1.0 and reference 0.25.
- More particles per cell did not lower any error beyond its seed noise, except the dam break's
  front speed against the experiment, a measure that gauges no numerical error; they raised the
  dam break's volume loss (2D: 1.0% at 9 and 1.2% at 16 per cell against 0.5% at 4; 3D: 0.70% at
  27 against 0.46% at 8) and the 3D front's RMS. 2 per cell (2D) saved little or no time on these
  grids, where the pressure solve and kernel launches dominate (0.89× the CPU time at best), and
  raised the dam break's drift (+1.5%), the Laplace drop's spurious currents (46% of the
  capillary speed against 19%) and moved the Minnaert frequency to +1.6%. So every preset keeps
  4 per cell in 2D and 8 in 3D.
- Resolution (the convergence table) is the lever that lowers the 2D volume drift, and refine = 2
  is how reference takes it. It also lowers the 3D front's RMS (0.029 a at seed 0, against 0.031
  a with cfl 0.25 alone at 12 cells per a) but not the 3D drift (0.40% at seed 0, against 0.36%
  with cfl 0.25 alone); on the other measures it buys nothing beyond the seed noise.
"""


def presets_markdown(meta, rows) -> str:
    prows = [r for r in rows if r["setting"] in ("quality", "seed")]
    used = sorted({r["batch"] for r in prows})
    seeds = sorted({r["seed"] for r in prows})
    runs = "; ".join(
        f"{', '.join(dict.fromkeys(r['case'] for r in prows if r['batch'] == i))} on {b['device']}, {b['date']}, "
        f"warp {b['warp']}, code {b['code']}, by `{b['command']}` ({b['total_minutes']:.0f} min, batch {i})"
        for i, b in ((i, meta["batches"][i]) for i in used))
    out = ["# Quality presets: error and cost", "",
           f"Measured for {runs}: the `quality` and `seed` rows of `accuracy_vs_time.md`, each case at its "
           "default resolution, the preset applied with Scene.with_quality as `--quality` applies it (so "
           "reference also refines the grid: `grid` counts the cells simulated per a or per radius). Each preset "
           f"ran with seeds {', '.join(map(str, seeds))}: the error columns give seed 0, the mean magnitude over "
           "the seeds and their range (the noise floor). Cost is the median over the seeds of the simulation loop's "
           "seconds (each the fastest of its timings); the 2 CPU cores were shared with other work, so compare "
           "the ratios, each taken within one run (batch).",
           "", "| preset | particles per cell (2D, 3D) | cfl | cg_tolerance | refine (grid cells per cell_size) |",
           "|---|---|---:|---:|---:|"]
    for q, v in PRESETS.items():
        ppc = v["particles_per_cell"]
        out.append(f"| {q} | {ppc[0]}, {ppc[1]} | {v['cfl']} | {v['cg_tolerance']:.0e} | {v.get('refine', 1)} |")
    out += ["", "| case: measure | preset | grid | wall s | cpu s | × production (wall, cpu) | error (seed 0) | "
            f"mean \\|error\\| ({len(seeds)} seeds) | seed range |", "|---|---|---|---:|---:|---:|---:|---:|---:|"]
    ratios = {q: [] for q in PRESETS}
    for case in CASES.values():
        for metric in case.metrics:
            sel = {}
            for q in PRESETS:
                seeds = [r for r in prows if r["case"] == case.key and r["metric"] == metric
                         and r["setting"] == "seed" and r["quality"] == q]
                seeds = seeds or [r for r in prows if r["case"] == case.key and r["metric"] == metric
                                  and r["setting"] == "quality" and r["value"] == q]
                if seeds:
                    sel[q] = seeds
            for q, seeds in sel.items():
                wall, cpu = (float(np.median([r[k] for r in seeds])) for k in ("wall_s", "cpu_s"))
                e = [r["error_signed"] for r in seeds]
                base = sel.get("production")
                if base and {r["batch"] for r in base} == {r["batch"] for r in seeds}:
                    rw = wall / float(np.median([r["wall_s"] for r in base]))
                    rc = cpu / float(np.median([r["cpu_s"] for r in base]))
                else:  # timings of different runs: no ratio
                    rw = rc = np.nan
                if metric == next(iter(case.metrics)) and np.isfinite(rc):
                    ratios[q].append(rc)
                grid = f"{seeds[0]['resolution']} {case.unit}"
                out.append(f"| {case.key}: {metric} | {q} | {grid} | {wall:.2f} | {cpu:.2f} | {fmt(rw, 2)}, "
                           f"{fmt(rc, 2)} | {fmt(next(r['error_signed'] for r in seeds if r['seed'] == 0))} | "
                           f"{fmt(float(np.mean(np.abs(e))))} | {fmt(float(np.ptp(e)) if len(e) > 1 else np.nan, 2)} |")
    out += ["", "CPU time relative to production, geometric mean over the cases: " + ", ".join(
        f"{q} {math.exp(np.mean(np.log(v))):.2f}×" for q, v in ratios.items() if v and all(x > 0 for x in v)) + ".",
        "", PRESETS_NOTE]
    return "\n".join(out) + "\n"


def plot(path, rows, title):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.ticker import FuncFormatter, LogLocator, NullFormatter

    panels = [(c.key, m, t) for c in CASES.values() for m, t in c.metrics.items()
              if any(r["case"] == c.key and r["metric"] == m for r in rows)]
    ncol = min(3, len(panels))
    nrow = math.ceil(len(panels) / ncol)
    fig, axes = plt.subplots(nrow, ncol, figsize=(5.2 * ncol, 4.2 * nrow), squeeze=False)
    styles = {"resolution": ("C0", "o"), "particles_per_cell": ("C1", "s"), "cfl": ("C2", "^"),
              "cg_tolerance": ("C3", "v"), "interface": ("C4", "D"), "quality": ("k", "*"), "seed": ("0.6", "x")}
    for ax, (case, metric, ptitle) in zip(axes.flat, panels):
        sel = [r for r in rows if r["case"] == case and r["metric"] == metric]
        for setting, (color, marker) in styles.items():
            pts = [r for r in sel if r["setting"] == setting and np.isfinite(r["error"]) and r["error"] > 0
                   and (setting != "seed" or r["quality"] == "production")]
            if not pts:
                continue
            if setting not in ("quality", "interface"):  # numeric sweeps in value order
                pts.sort(key=lambda r: float(r["value"]))
            ls = "none" if setting in ("seed", "interface") else "-"
            ax.plot([r["wall_s"] for r in pts], [r["error"] for r in pts], color=color, marker=marker, ls=ls,
                    ms=8 if setting == "quality" else 5, label=setting, alpha=0.85)
            for r in pts:
                if setting != "seed":
                    label = value_label(setting, r["value"]) + (f" ×{r['refine']} grid" if r["refine"] > 1 else "")
                    ax.annotate(label, (r["wall_s"], r["error"]), fontsize=6,
                                xytext=(3, 3), textcoords="offset points", color=color)
        d = next((r for r in sel if r["is_default"] and np.isfinite(r["error"]) and r["error"] > 0), None)
        if d:
            ax.plot([d["wall_s"]], [d["error"]], marker="o", ms=13, mfc="none", mec="k", ls="none")
        ax.set_xscale("log")
        ax.set_yscale("log")
        for axis in (ax.xaxis, ax.yaxis):  # decades labelled, minor ticks unlabelled (they collide)
            axis.set_major_locator(LogLocator(base=10, subs=(1.0, 2.0, 5.0)))
            axis.set_major_formatter(FuncFormatter(lambda v, _: f"{v:g}"))
            axis.set_minor_formatter(NullFormatter())
        ax.set_title(ptitle, fontsize=8)
        ax.set_xlabel("wall seconds (simulation loop)", fontsize=8)
        ax.set_ylabel("error", fontsize=8)
        ax.tick_params(labelsize=7)
        ax.grid(True, which="both", alpha=0.3)
    for ax in list(axes.flat)[len(panels):]:
        ax.axis("off")
    legend = {}
    for ax in axes.flat:
        for h, lab in zip(*ax.get_legend_handles_labels()):
            legend.setdefault(lab, h)
    labels = [s for s in styles if s in legend]
    fig.legend([legend[k] for k in labels], [k if k != "seed" else "seed (production)" for k in labels],
               loc="lower center", ncol=len(labels), fontsize=8)
    fig.suptitle(title + "  (ringed: production default)", fontsize=9)
    fig.tight_layout(rect=(0, 0.05, 1, 0.96))
    fig.savefig(path, dpi=110)
    plt.close(fig)


def describe_code() -> str:
    """The commit measured, and the files that differed from it (others may be editing the tree)."""
    def git(*a):
        return subprocess.run(["git", *a], cwd=ROOT, capture_output=True, text=True).stdout.rstrip()
    try:
        head = git("rev-parse", "--short", "HEAD").strip()
        dirty = [line[3:] for line in git("status", "--porcelain", "--untracked-files=no").splitlines()]
    except OSError:
        return "unknown (no git)"
    return head + (f" with uncommitted changes to {', '.join(dirty)}" if dirty else "") if head else "unknown"



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
        warm_up(CASES[k], tmp)
    results = {}
    for rep in range(args.repeat):
        for i, (key, (case, over)) in enumerate(unique.items(), 1):
            if rep and results[key]["wall"] >= args.repeat_under:
                continue
            clock = Clock()
            sim = Simulation(build_scene(case, over, tmp), "cpu")
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


def measure_task(case_key: str, over: dict, tmp: str, repeat: int, repeat_under: float) -> dict:
    """One distinct run as a Dask task (in a worker process): warm up, run, re-time."""
    wp.config.log_level = getattr(wp, "LOG_WARNING", 30)
    case = CASES[case_key]
    warm_up(case, tmp)  # each worker loads the case's kernels untimed
    best = None
    for _ in range(repeat):
        clock = Clock()
        sim = Simulation(build_scene(case, over, tmp), "cpu")
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

    # The task by reference from this file imported as a module (the workers get this folder on
    # their sys.path), not pickled by value out of __main__ with everything it touches.
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    import accuracy_vs_time as study

    counts = [int(w) for w in args.workers.split(",")]
    by_count, walls = {}, {}
    for n in counts:
        start = time.perf_counter()
        with dask_client(workers=n) as client:
            futures = client.map(study.measure_task, [case.key for case, _ in unique.values()],
                                 [over for _, over in unique.values()], tmp=tmp, repeat=args.repeat,
                                 repeat_under=args.repeat_under, pure=False, retries=1)
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


def load_saved(out_dir: Path) -> tuple[dict, list[dict]]:
    """The saved measurements; a file from before batches (one run) becomes batch 0 at refine 1."""
    saved = json.loads((out_dir / "accuracy_vs_time.json").read_text())
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
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--quick", action="store_true", help="smoke run: two coarse levels, two values per setting")
    ap.add_argument("--cases", default=",".join(CASES), help=f"comma-separated subset of {', '.join(CASES)}")
    ap.add_argument("--only", default=None,
                    help=f"rerun only these sweeps ({', '.join(SETTINGS)}; 'presets' = quality,seed; 'all') of "
                         "the --cases and merge them into <out-dir>/accuracy_vs_time.json, keeping every other "
                         "saved row")
    ap.add_argument("--out-dir", default=None, help="where to write (default docs/, or "
                                                    "benchmarks/results/accuracy_quick/ with --quick)")
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
                    help="rewrite the CSV, Markdown and plot from <out-dir>/accuracy_vs_time.json without running")
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
    out_dir = Path(args.out_dir) if args.out_dir else (
        ROOT / "benchmarks" / "results" / "accuracy_quick" if args.quick else ROOT / "docs")
    out_dir.mkdir(parents=True, exist_ok=True)
    if args.render_only:
        meta, rows = load_saved(out_dir)
        render(out_dir, meta, rows, args)
        return 0
    mode = "quick" if args.quick else "full"
    saved_meta, saved_rows = load_saved(out_dir) if only else ({"batches": []}, [])
    if only and saved_meta.get("mode") != mode:
        ap.error(f"--only merges into the saved {saved_meta.get('mode')} run: run it in that mode")

    start = time.perf_counter()
    wp.config.quiet = True
    wp.init()
    dev = wp.get_device("cpu")
    production = {k: PRESETS["production"][k] for k in ("particles_per_cell", "cfl", "cg_tolerance")}
    cmd = shlex.join(["python", "benchmarks/accuracy_vs_time.py", *(sys.argv[1:] if argv is None else argv)])
    meta = {"mode": mode, "production": ", ".join(f"{k} = {v}" for k, v in production.items()) + ", interface = sharp",
            "batches": saved_meta["batches"]}
    batch = {"date": datetime.datetime.now().astimezone().isoformat(timespec="seconds"),
             "warp": wp.config.version, "python": platform.python_version(), "device": describe_device(dev),
             "code": describe_code(), "command": cmd, "repeat": args.repeat, "repeat_under_s": args.repeat_under,
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
    (out_dir / "accuracy_vs_time.json").write_text(json.dumps({"meta": meta, "rows": rows}, indent=1) + "\n")
    print(f"wrote {out_dir}/accuracy_vs_time.json (the measurements; --render-only rewrites the rest from it)",
          file=sys.stderr)
    render(out_dir, meta, rows, args)
    return 0


def batch_note(rows) -> str:
    """For a plot title: say so when the points come from runs timed at different loads."""
    n = len({r["batch"] for r in rows})
    return f"; points from {n} runs (batches) timed at different loads, see the .md" if n > 1 else ""


def render(out_dir: Path, meta: dict, rows: list[dict], args):
    """Write the CSV, the Markdown, presets.md and the plot from the measured rows."""
    keys = list(dict.fromkeys(r["case"] for r in rows))
    # seed noise and convergence orders
    noise, orders = {}, {}
    for case in (CASES[k] for k in keys):
        for metric in case.metrics:
            if len(case.levels if meta["mode"] == "full" else case.quick_levels) < 2:
                continue  # one resolution: nothing to fit
            seeds = [r["error_signed"] for r in rows if r["case"] == case.key and r["metric"] == metric
                     and r["setting"] == "seed" and r["quality"] == "production"]
            noise[(case.key, metric)] = float(np.ptp(seeds)) if len(seeds) > 1 else np.nan
            res_rows = sorted((r for r in rows if r["case"] == case.key and r["metric"] == metric
                               and r["setting"] == "resolution"), key=lambda r: r["resolution"])
            if case.self_referenced:
                res_rows = res_rows[:-1]  # the finest run is the reference itself
            pts = [(r["dx"], r["error"]) for r in res_rows]
            n = noise[(case.key, metric)]
            p_all, _, verdict, local = fit_order(pts, NOISE_FACTOR * n if np.isfinite(n) else 0.0)
            orders[(case.key, metric)] = dict(levels=[r["resolution"] for r in res_rows],
                                              errors=[r["error"] for r in res_rows], local=local, p_all=p_all,
                                              verdict=verdict)

    write_csv(out_dir / "accuracy_vs_time.csv", rows)
    text = markdown(meta, rows, orders, noise)
    (out_dir / "accuracy_vs_time.md").write_text(text)
    (out_dir / "presets.md").write_text(presets_markdown(meta, rows))
    if not args.no_plot:
        try:
            devices = ", ".join(dict.fromkeys(b["device"] for b in meta["batches"]))
            plot(out_dir / "accuracy_vs_time.png", rows, f"error against wall seconds, {devices}{batch_note(rows)}")
        except ImportError:
            args.no_plot = True
            print("matplotlib not installed (the [plots] extra): no PNG written", file=sys.stderr)
    print(text)
    print(f"wrote {out_dir}/accuracy_vs_time.{{csv,md{'' if args.no_plot else ',png'}}} and presets.md from the "
          f"{meta['mode']} run(s) of {', '.join(b['date'] for b in meta['batches'])}", file=sys.stderr)


if __name__ == "__main__":
    sys.exit(main())
