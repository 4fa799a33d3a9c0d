"""Grid convergence of a rising bubble: a closed, filled tank in 2D against Hysing et al.'s
published benchmark and in 3D against Adelsberger et al.'s, and the free-surface rising bubble of
accuracy_vs_time.py against itself.

    python -m benchmarks.validation.convergence                      # full study: about 40 min on 2 CPU cores
    python -m benchmarks.validation.convergence --quick              # smaller grids, shorter runs: about 40 s
    python -m benchmarks.validation.convergence --cases hysing_2d --resolutions 20,40,80,160
    python -m benchmarks.validation.convergence --report-only        # re-render from the saved runs
    python -m benchmarks.validation.convergence --device cuda:0 --cases adelsberger_3d --resolutions 18,27,40
    python -m benchmarks.validation.convergence --cases hysing_2d --resolutions 40 --quality preview,production,reference --seeds 0,1,2
    python -m benchmarks.validation.convergence --cases hysing_2d --set volume_relaxation_time=0 --label no_correction

Cases (docs/convergence.md explains the mapping):
- hysing_2d: Hysing et al. 2009, test case 1: a 1 x 2 tank, no-slip top and bottom, free-slip sides,
  a bubble of radius 0.25 at (0.5, 0.5); rho 1000 / 100, mu 10 / 1, sigma 24.5, g 0.98, t_end 3
  (Re 35, Eo 10). Run with every density, viscosity and sigma divided by 10 (sigma 2.45 fits
  [materials].surface_tension <= 3): the same Re, Eo and ratios, so the same motion in the same
  seconds and metres; pressures are 10x smaller. Gas law "incompressible" (density ratio only).
- adelsberger_3d: Adelsberger et al. 2014, test case 1: a 1 x 2 x 1 box, all walls no-slip, radius
  0.25 at (0.5, 0.5, 0.5), the same fluids and scaling; against the DROPS / NaSt3DGPF series.
- free_surface_2d: accuracy_vs_time.py's rising bubble: a 2 cm air bubble (isothermal gas) in water
  (sigma 0.072, inviscid) in a 0.08 x 0.16 m tank filled to 0.14 m; no published reference: the
  successive differences and the observed order are the result.

Per run, sampled 60 times: gas centroid, rise speed (the centroid's rate of change; the gas
particles' mean velocity too), circularity / sphericity (diagnostics.gas_shape), the gas contour's
area / volume over the gas particles' (diagnostics.field_shape unsmoothed), void cells
(diagnostics.void_cells) and bubble gaps; wall time. After every step: the gas centroid (the rise
speed's peak and its time come from it, through a fixed window: `windowed`, `extremum`). Each run
is saved on its own (benchmarks/results/convergence/<device>_runs/<case>_<resolution>.json, replaced
when rerun), so cases and resolutions can be run separately and the report merges what is there.
Writes benchmarks/results/convergence/<device>.{json,csv,md,png} (--quick: <device>_quick*).

Other settings: --set NAME=VALUE (repeatable) changes a [solver] setting from the preset's in every
run, e.g. `--set volume_relaxation_time=0` (no volume correction) or `--set
volume_correction_moves=velocities`; with --label, so the runs are saved in
<device>_<label>_runs/ and reported apart from the study's.

Quality presets: --quality runs the cases at each preset as a scene's
[solver].quality sets it (reference also refines the grid: `refine` cells per cell_size), --seeds
at other particle seeds (the noise floor). The convergence tables take the production runs at seed
0; the presets table puts each preset's error (against the published value, or for the
free-surface case against its finest production run) beside its cost. Runs at another preset or
seed are saved as <case>_<resolution>_<quality>_s<seed>.json.
"""

from __future__ import annotations

import csv
import dataclasses
import datetime
import json
import math
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import warp as wp

import warp_mpm_bubbles
from warp_mpm_bubbles import Box, Domain, Material, Output, Scene, SolverSettings, Sphere
from warp_mpm_bubbles.core.simulation import Simulation
from warp_mpm_bubbles.core.timing import describe_device
from warp_mpm_bubbles.io.wedge import parse_value
from warp_mpm_bubbles.diagnostics import field_shape, gap_cells, gas_fraction, void_cells
from warp_mpm_bubbles.scene.checks import SceneError
from warp_mpm_bubbles.scene.quality import PRESETS

from benchmarks import harness

ROOT = harness.ROOT
SAMPLES = 60
SCALE = 0.1  # densities, viscosities and sigma of the benchmark fluids times this: same Re, Eo, motion


@dataclass
class Case:
    key: str
    dim: int
    size: tuple
    unit: str  # what the resolution counts
    levels: tuple
    quick_levels: tuple
    t_end: float
    quick_t_end: float
    reference: dict  # metric -> (value, time or None, source)
    trough: bool = True  # the shape's minimum is a trough it recovers from (else a plateau: no time of minimum)


HYSING = "Hysing et al. 2009, Int. J. Numer. Meth. Fluids 60:1259, test case 1 (TP2D/FreeLIFE/MooNMD)"
# The benchmark groups' own time series (DROPS, NaSt3DGPF), as distributed with the benchmark (Bonn INS
# archive; mirrored in chaos-polymtl/lethe examples/multiphysics/rising-bubble/3D/reference-data/case_1);
# docs/convergence.md gives each code's value (OpenFOAM's run 1-2% lower).
ADELSBERGER = ("Adelsberger et al. 2014, WCCM XI, test case 1 (DROPS / NaSt3DGPF series: peak 0.3570 / 0.3587, "
               "centroid 1.471 / 1.468, min sphericity 0.959 / 0.9596)")
CASES = {c.key: c for c in [
    Case("hysing_2d", 2, (1.0, 2.0), "cells across", (20, 40, 80, 160), (10, 20, 40), 3.0, 1.0,
         {"circularity_min": (0.9013, 1.9, HYSING), "rise_speed_max": (0.2417, 0.92, HYSING),
          "centroid_end": (1.081, 3.0, HYSING)}),
    Case("adelsberger_3d", 3, (1.0, 2.0, 1.0), "cells across", (12, 18, 27, 36, 48), (8, 12, 16), 3.0, 1.0,
         {"circularity_min": (0.959, 1.9, ADELSBERGER), "rise_speed_max": (0.358, 0.89, ADELSBERGER),
          "centroid_end": (1.470, 3.0, ADELSBERGER)}, trough=False),
    Case("free_surface_2d", 2, (0.08, 0.16), "cells per radius", (4, 8, 16, 32), (3, 6, 12), 0.15, 0.08, {}),
]}


def scene(case: Case, res: int, tmp: str, quality: str = "production", seed: int = 0,
          settings: dict | None = None) -> Scene:
    """The case's scene at one grid; `settings`: SolverSettings fields changed from the preset's (--set)."""
    settings = SolverSettings(quality=quality, seed=seed, **(settings or {}))
    if case.key == "free_surface_2d":
        r = 0.01
        return Scene(domain=Domain(size=case.size, cell_size=r / res),
                     materials={"water": Material("water", surface_tension=0.072), "air": Material("air", kind="gas")},
                     shapes=[Box("water", (0.0, 0.0), (0.08, 0.14)), Sphere("air", (0.04, 0.03), r)],
                     solver=settings, output=Output(path=f"{tmp}/c.usdc"), name=case.key)
    dim = case.dim
    walls = "no_slip" if dim == 3 else {"x_min": "free_slip", "x_max": "free_slip", "y_min": "no_slip",
                                        "y_max": "no_slip"}
    fluids = {"liquid": Material("liquid", density=1000 * SCALE, viscosity=10 * SCALE, surface_tension=24.5 * SCALE),
              "bubble": Material("bubble", kind="gas", density=100 * SCALE, viscosity=1 * SCALE,
                                 eos="incompressible")}
    return Scene(domain=Domain(size=case.size, cell_size=1.0 / res, walls=walls,
                               gravity=(0.0, -0.98, 0.0)[:dim]),
                 materials=fluids,
                 shapes=[Box("liquid", (0.0,) * dim, case.size), Sphere("bubble", (0.5, 0.5, 0.5)[:dim], 0.25)],
                 solver=settings, output=Output(path=f"{tmp}/c.usdc"), name=case.key)


def sample(sim: Simulation, gas_index: int) -> dict:
    p = sim.particles_numpy()
    g = p["material"] == gas_index
    dim, dx, cells = sim.grid.dim, sim.grid.dx, sim.grid.cells
    v = p["volume"][g] / (dx if dim == 2 else 1.0)  # 2D: a slab one cell thick, so areas
    centroid = (p["positions"][g, :dim] * v[:, None]).sum(0) / v.sum()
    speed = float((p["velocities"][g, 1] * v).sum() / v.sum())
    frac = gas_fraction(p["positions"], g, p["volume"], dx, cells, dim)
    shape = field_shape(frac, dx, smooth=1)
    enclosed = field_shape(frac, dx, smooth=0)["area" if dim == 2 else "volume"]
    return {"t": sim.time, "centroid_y": float(centroid[1]), "particle_speed": speed,
            "roundness": shape["circularity" if dim == 2 else "sphericity"],
            "gas_region_ratio": enclosed / float(v.sum()),
            # voids apart from the bubble gaps (particle-free cells beside compressible gas: its own to fill)
            "voids": void_cells(sim.fields.types.numpy(), sim.grid.ghost, sim.up, sim.voids.gap_mask()),
            "gaps": gap_cells(sim), "steps": sim.stats.steps}


def tracker(sim: Simulation, gas_index: int, track: dict):
    """A per-step callback: the time, the gas centroid's height and the gas particles' mean vertical
    velocity after every step (on the CPU device views on the particle arrays; on a GPU six small
    copies a step), for the rise speed's peak."""
    def on_step(dt, remaining):
        start = time.perf_counter()
        p = sim.particles
        g = (p.numpy("material") == gas_index) & (p.numpy("active") == 1)
        vol = (p.numpy("vol0") * p.numpy("J"))[g].astype(np.float64)
        track["t"].append(sim.time)
        track["centroid_y"].append(float((p.numpy("x")[g, 1] * vol).sum() / vol.sum()))
        track["particle_speed"].append(float((p.numpy("v")[g, 1] * vol).sum() / vol.sum()))
        track["cost_s"] += time.perf_counter() - start
    return on_step


def run_one(case: Case, res: int, t_end: float, device, quality: str = "production", seed: int = 0,
            settings: dict | None = None) -> dict:
    with tempfile.TemporaryDirectory() as tmp:
        sim = Simulation(scene(case, res, tmp, quality, seed, settings), device)
        gas_index = [m.is_gas for m in sim.scene.materials.values()].index(True)
        series = [sample(sim, gas_index)]
        track = {"t": [sim.time], "centroid_y": [series[0]["centroid_y"]], "particle_speed": [0.0], "cost_s": 0.0}
        on_step = tracker(sim, gas_index, track)
        wall = 0.0
        for k in range(1, SAMPLES + 1):
            start = time.perf_counter()
            sim.advance_to(t_end * k / SAMPLES, on_step)
            wall += time.perf_counter() - start
            series.append(sample(sim, gas_index))
            s = series[-1]
            print(f"  {case.key} {res} {quality} s{seed}: t {s['t']:.3f} y {s['centroid_y']:.4f} v {s['particle_speed']:.4f} "
                  f"round {s['roundness']:.4f} voids {s['voids']} ({wall:.0f} s)", file=sys.stderr, flush=True)
        wall -= track.pop("cost_s")  # the solver's time only
        return {"case": case.key, "resolution": res, "quality": quality, "seed": seed, "settings": settings or {},
                "refine": sim.scene.solver.refine, "t_end": t_end, "dx": sim.grid.dx,
                "particles": sim.num_particles, "steps": sim.stats.steps, "wall_s": wall,
                "device": describe_device(device), "series": series, "track": track,
                "summary": summarize(series, track, case.trough)}


def centroid_speed(series: list[dict]) -> np.ndarray:
    """Rise speed as the centroid's rate of change (central differences over the samples): Hysing's
    mean bubble velocity averaged over +-1 sample (0.05 s at t_end 3), which an MPM particle velocity
    field, noisy from step to step, needs; the particles' own mean is kept in the series."""
    return np.gradient([s["centroid_y"] for s in series], [s["t"] for s in series])


def windowed(t, y, half_width: float, t_from: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The series seen through a window of +-half_width: at each centre (steps of half_width / 50,
    from t_from + half_width to the end less half_width) a least-squares quadratic through the
    points within the window; returns the centres, the fits' values and their slopes there. The
    same window at every grid makes each a functional of the trajectory, which converges when the
    trajectory does; an extremum of the raw series does not: the speed jitters by 0.6-2% between
    steps (the volume correction answering the particles' sampling noise; it shrinks with dx, see
    particle_speed_noise) and the peaks are flat (the rise speed within 0.1% over 0.15 s in
    hysing_2d), so the 60 samples' own argmax jumped a sample either way between grids."""
    t, y = np.asarray(t), np.asarray(y)
    centres = np.arange(t_from + half_width, t[-1] - half_width + 1e-9, half_width / 50)
    fits = [np.polyfit((t[near] - at) / half_width, y[near], 2) for at in centres
            for near in [np.abs(t - at) <= half_width]]
    return centres, np.array([f[2] for f in fits]), np.array([f[1] / half_width for f in fits])


def extremum(t, y, half_width: float, t_from: float, kind: str) -> dict:
    """The windowed series' (see `windowed`) largest slope (kind "peak_slope": the rise speed from
    the centroid) or smallest value ("trough": the shape), its time, and the spread of that time:
    the centres whose windowed figure lies within two standard errors of the extremum's (the
    scatter about a cubic through the extremum's window, through the quadratic fit's covariance),
    contiguous around it. A flat extremum of a noisy series has a wide spread: its time is known only that well."""
    t, y = np.asarray(t), np.asarray(y)
    centres, values, slopes = windowed(t, y, half_width, t_from)
    series = slopes if kind == "peak_slope" else -values
    i = int(series.argmax())
    near = np.abs(t - centres[i]) <= half_width
    tau = (t[near] - centres[i]) / half_width
    # the noise: the scatter about a cubic (a quadratic's own misfit to a smooth peak is not noise)
    scatter = np.sum((y[near] - np.polyval(np.polyfit(tau, y[near], 3), tau)) ** 2) / max(len(tau) - 4, 1)
    basis = np.vstack([tau**2, tau, np.ones_like(tau)]).T
    cov = scatter * np.linalg.inv(basis.T @ basis)
    error = np.sqrt(cov[1, 1]) / half_width if kind == "peak_slope" else np.sqrt(cov[2, 2])
    within = series >= series[i] - 2.0 * error
    lo = hi = i
    while lo > 0 and within[lo - 1]:
        lo -= 1
    while hi < len(within) - 1 and within[hi + 1]:
        hi += 1
    return {"value": float(slopes[i] if kind == "peak_slope" else values[i]), "t": float(centres[i]),
            "spread": float(centres[hi] - centres[lo] + centres[1] - centres[0])}  # at least the centres' step


def summarize(series: list[dict], track: dict | None = None, trough: bool = True) -> dict:
    t = np.array([s["t"] for s in series])
    col = {k: np.array([s[k] for s in series]) for k in ("centroid_y", "roundness", "gas_region_ratio", "voids")}
    col["rise_speed"] = centroid_speed(series)
    col["particle_speed"] = np.array([s.get("particle_speed", s.get("rise_speed")) for s in series])
    width = t[-1] / 20  # 0.15 s at t_end 3: 3 samples either side, hundreds of steps
    # every step's centroid (runs saved before the track: the samples); the shape only at the samples
    rising = (track["t"], track["centroid_y"]) if track and len(track["t"]) > 20 else (t, col["centroid_y"])
    peak = extremum(*rising, width, t[1], "peak_slope")
    trough_ = extremum(t, col["roundness"], width, t[1], "trough")
    out = {"rise_speed_max": peak["value"], "t_rise_speed_max": peak["t"], "t_rise_speed_max_spread": peak["spread"],
           # the particles' mean velocity about the centroid's rate: MPM's step-to-step noise, 0 in the limit
           "particle_speed_noise": float(np.sqrt(np.mean((col["particle_speed"] - col["rise_speed"])[1:-1] ** 2))),
           "rise_speed_end": float(col["rise_speed"][-1]),  # the last sample interval's mean
           # over the last two thirds (free_surface_2d: accuracy_vs_time.py's 0.05-0.15 s window)
           "rise_speed_mean_late": float((col["centroid_y"][-1] - col["centroid_y"][len(t) // 3])
                                         / (t[-1] - t[len(t) // 3])), "centroid_end": float(col["centroid_y"][-1]),
           "roundness_min": trough_["value"],
           "gas_region_ratio_end": float(col["gas_region_ratio"][-1]),
           # against the perfectly seeded bubble at t = 0: the contour's own bias at this grid cancels
           "gas_region_change_end": float(col["gas_region_ratio"][-1] / col["gas_region_ratio"][0] - 1.0),
           "voids_max": int(col["voids"].max())}
    if all("gaps" in x for x in series):  # runs saved before the field: voids and gaps counted together
        out["gaps_max"] = int(max(x["gaps"] for x in series))
    if trough:  # a plateau's minimum (adelsberger_3d's terminal shape) has no time
        out["t_roundness_min"], out["t_roundness_min_spread"] = trough_["t"], trough_["spread"]
    return out


METRICS = ["rise_speed_max", "t_rise_speed_max", "t_rise_speed_max_spread", "particle_speed_noise", "rise_speed_end",
           "rise_speed_mean_late", "centroid_end", "roundness_min", "t_roundness_min", "t_roundness_min_spread",
           "gas_region_ratio_end", "voids_max", "gaps_max"]
# Metrics whose converged value is known: no noise, the gas region exactly the gas particles' area
# (volume), no voids, an extremum's time known exactly (its spread 0). (gas_region_change_end, in the
# summary, is not a convergence metric: docs/convergence.md.)
LIMITS = {"particle_speed_noise": 0.0, "gas_region_ratio_end": 1.0, "voids_max": 0, "gaps_max": 0,
          "t_rise_speed_max_spread": 0.0, "t_roundness_min_spread": 0.0}
# An extremum's time and its spread (`extremum`): where its differences do not shrink, they may still
# lie within the spreads (each pair of estimates agrees within what either run determines): "within spread".
SPREADS = {"t_rise_speed_max": "t_rise_speed_max_spread", "t_roundness_min": "t_roundness_min_spread"}
REF_KEY = {"rise_speed_max": "rise_speed_max", "centroid_end": "centroid_end", "roundness_min": "circularity_min"}


def convergence(values: list[float], ratios: list[float], limit: float | None = None,
                spreads: list[float] | None = None) -> dict:
    """Successive differences and the observed order p = log(d_k / d_k+1) / log(r_k+1), the refinement
    ratio r between the two finer levels (equal ratios give the textbook log2 form for r = 2). For a
    metric whose converged value is known (`limit`: the noise and the void cells, 0), the errors
    e_k = |m_k - limit| themselves must shrink, with p = log(e_k / e_k+1) / log(r_k); "exact" when
    every level is at the limit. With `spreads` (an extremum's time), differences that do not shrink
    but each lie within the two levels' mean spread are "within spread"."""
    d = [b - a for a, b in zip(values, values[1:])]
    if len(values) < 2:  # one level (a run of one resolution): nothing to compare yet
        return {"differences": d, "orders": [], "shrinking": False, "verdict": "-"}
    if limit is not None:
        e = [abs(v - limit) for v in values]
        orders = [math.log(e0 / e1) / math.log(r) if e0 and e1 else float("nan") for e0, e1, r in zip(e, e[1:], ratios)]
        shrinking = all(b < a or b == 0 for a, b in zip(e, e[1:]))  # at the limit and staying there counts
        verdict = "exact" if not any(e) else "no" if not shrinking else \
            "barely" if min(orders) < 0.5 else "yes"
        return {"differences": d, "orders": orders, "shrinking": shrinking or verdict == "exact",
                "verdict": verdict, "limit": limit}
    orders = [math.log(abs(d0) / abs(d1)) / math.log(r) if d0 and d1 else float("nan")
              for d0, d1, r in zip(d, d[1:], ratios[1:])]
    shrinking = all(abs(b) < abs(a) for a, b in zip(d, d[1:]))
    # "barely": every difference smaller than the last, but by less than r^0.5 (order < 0.5)
    verdict = "no" if not shrinking else "barely" if orders and min(orders) < 0.5 else "yes"
    if verdict == "no" and spreads and all(abs(x) <= 0.5 * (a + b) for x, a, b in zip(d, spreads, spreads[1:])):
        verdict = "within spread"
    out = {"differences": d, "orders": orders, "shrinking": shrinking, "verdict": verdict}
    if orders and 0.5 <= orders[-1] <= 4 and d[-1] * d[-2] > 0:  # monotone, a plausible order: Richardson
        out["richardson"] = values[-1] + d[-1] / (ratios[-1] ** orders[-1] - 1.0)
    return out


def git_describe() -> str:
    """The last commit that changed the solver (diagnostics.py only measures), and whether it is dirty."""
    return harness.last_change("warp_mpm_bubbles", ":!warp_mpm_bubbles/diagnostics.py")


def is_study_run(r: dict) -> bool:
    """The convergence tables' runs: production settings, seed 0 (runs saved before the fields were)."""
    return r.get("quality", "production") == "production" and r.get("seed", 0) == 0


def run_file(key: str, res: int, quality: str, seed: int) -> str:
    tail = "" if quality == "production" and seed == 0 else f"_{quality}_s{seed}"
    return f"{key}_{res}{tail}.json"


# Solver commits that changed no result, mapped to the earlier commit whose runs they reproduce
# bit for bit (checked by re-running: every sample of the series equal), so runs of both still
# make one study. b45dea0: the tension kernels walk lines; hysing_2d 40, adelsberger_3d 18 and
# free_surface_2d 8 re-ran identical to 159af47.
SAME_RESULTS = {"b45dea0": "159af47"}
PRESET_METRICS = ("rise_speed_max", "centroid_end", "roundness_min")


def presets_report(runs: list[dict]) -> dict:
    """Per case and base resolution with runs at more than one preset: each preset's error on the
    metrics, seed by seed, and its wall time. The error is against the published value where there
    is one (at the case's full t_end), else against the case's finest production run (named)."""
    out = {}
    for key, case in CASES.items():
        t_end = max((r["t_end"] for r in runs if r["case"] == key), default=None)
        mine = [r for r in runs if r["case"] == key and r["t_end"] == t_end]
        finest = max((r for r in mine if is_study_run(r)), key=lambda r: r["resolution"], default=None)
        published = case.reference if t_end is not None and t_end >= case.t_end else {}
        for res in sorted({r["resolution"] for r in mine}):
            at = [r for r in mine if r["resolution"] == res]
            if len({r.get("quality", "production") for r in at}) < 2:
                continue
            rows = []
            finest_summary = summarize(finest["series"], finest.get("track"), case.trough) if finest else None
            for r in sorted(at, key=lambda r: (list(PRESETS).index(r.get("quality", "production")),
                                               r.get("seed", 0))):
                summary, errors = summarize(r["series"], r.get("track"), case.trough), {}
                for m in PRESET_METRICS:
                    ref = published.get(REF_KEY[m])
                    target = ref[0] if ref else (finest_summary[m] if finest_summary else float("nan"))
                    errors[m] = summary[m] / target - 1.0
                rows.append({"quality": r.get("quality", "production"), "seed": r.get("seed", 0),
                             "grid": res * r.get("refine", 1), "wall_s": r["wall_s"], "steps": r["steps"],
                             "values": {m: summary[m] for m in PRESET_METRICS}, "errors": errors})
            out[f"{key}_{res}"] = {"case": key, "resolution": res, "unit": case.unit, "rows": rows,
                                   "against": "published" if published else
                                   f"the production run at {finest['resolution']} {case.unit}" if finest else "-"}
    return out



def report(runs: list[dict], command: str) -> dict:
    out = {"date": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
           "code": git_describe(), "command": command, "cases": {}, "presets": presets_report(runs)}
    for key, case in CASES.items():
        mine = sorted((r for r in runs if r["case"] == key and is_study_run(r)), key=lambda r: r["resolution"])
        if not mine:
            continue
        levels = [r["resolution"] for r in mine]
        ratios = [b / a for a, b in zip(levels, levels[1:])]
        entry = {"levels": levels, "unit": case.unit, "wall_s": [r["wall_s"] for r in mine],
                 "code": [r.get("code", "b8f0711") for r in mine],  # runs before the field: the baseline
                 "steps": [r["steps"] for r in mine], "particles": [r["particles"] for r in mine],
                 "t_end": mine[-1]["t_end"], "metrics": {}}
        summaries = [summarize(r["series"], r.get("track"), case.trough) for r in mine]  # metrics can change later
        for m in (m for m in METRICS if all(m in s for s in summaries)):
            vals = [s[m] for s in summaries]
            spreads = [s[SPREADS[m]] for s in summaries] if m in SPREADS else None
            entry["metrics"][m] = {"values": vals, **convergence(vals, ratios, LIMITS.get(m), spreads)}
            # the finest three alone: the asymptotic range, where a coarse level's pre-asymptotic step is left out
            entry["metrics"][m]["verdict_finest3"] = convergence(vals[-3:], ratios[-2:], LIMITS.get(m),
                                                                 spreads and spreads[-3:])["verdict"]
            ref = case.reference.get(REF_KEY.get(m, ""))
            if ref and mine[-1]["t_end"] >= case.t_end:
                entry["metrics"][m]["reference"] = ref[0]
                entry["metrics"][m]["error"] = [v / ref[0] - 1 for v in vals]
                entry["metrics"][m]["source"] = ref[2]
        out["cases"][key] = entry
    return out


def fmt(x, digits=4):
    return "-" if x is None or (isinstance(x, float) and math.isnan(x)) else (
        f"{x:d}" if isinstance(x, int) else f"{x:.{digits}g}")


VERDICT = {"yes": "yes", "barely": "barely", "no": "**no**", "exact": "exact (0)", "within spread": "within spread",
           "-": "-"}  # one level: nothing to compare yet


def markdown(rep: dict) -> str:
    lines = [f"Solver at {rep['code']}.", ""]
    for key, e in rep["cases"].items():
        lv = e["levels"]
        mixed = len({SAME_RESULTS.get(c, c) for c in e["code"]}) > 1
        lines += [f"## {key} ({e['unit']} {', '.join(map(str, lv))}; t_end {e['t_end']:g})", ""]
        lines += [f"**Runs from different solver versions: {', '.join(e['code'])}.** Re-run them all.", ""] \
            if mixed else []
        lines += ["| metric | " + " | ".join(map(str, lv)) + " | differences | shrinking | finest three | "
                  "observed order | Richardson | reference |", "|---|" + "---:|" * (len(lv) + 6)]
        for m, d in e["metrics"].items():
            ref = f"{d['reference']:g} (errors {', '.join(f'{100 * x:+.1f}%' for x in d['error'])})" \
                if "reference" in d else ""
            lines.append(f"| {m} | " + " | ".join(fmt(v) for v in d["values"]) + " | "
                         + ", ".join(fmt(x, 2) for x in d["differences"]) + " | "
                         + " | ".join(VERDICT[v] for v in (d["verdict"], d["verdict_finest3"])) + " | "
                         + ", ".join(fmt(x, 2) for x in d["orders"]) + " | " + fmt(d.get("richardson")) + f" | {ref} |")
        lines += ["| wall s | " + " | ".join(f"{w:.0f}" for w in e["wall_s"]) + " |" * 7,
                  "| steps | " + " | ".join(map(str, e["steps"])) + " |" * 7,
                  "| particles | " + " | ".join(map(str, e["particles"])) + " |" * 7, ""]
    for e in rep.get("presets", {}).values():
        lines += [f"## Presets: {e['case']} at {e['resolution']} {e['unit']} (errors against {e['against']})", "",
                  "| preset | seed | grid | " + " | ".join(PRESET_METRICS) + " | wall s | steps |",
                  "|---|---:|---:|" + "---:|" * (len(PRESET_METRICS) + 2)]
        for row in e["rows"]:
            lines.append(f"| {row['quality']} | {row['seed']} | {row['grid']} | " + " | ".join(
                f"{fmt(row['values'][m])} ({100 * row['errors'][m]:+.2f}%)" for m in PRESET_METRICS)
                + f" | {row['wall_s']:.0f} | {row['steps']} |")
        lines.append("")
    return "\n".join(lines)


def plot(runs: list[dict], path: Path):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    keys = [k for k in CASES if any(r["case"] == k and is_study_run(r) for r in runs)]
    fig, axes = plt.subplots(len(keys), 3, figsize=(13, 3.2 * len(keys)), squeeze=False)
    for row, key in zip(axes, keys):
        case = CASES[key]
        for r in sorted((r for r in runs if r["case"] == key and is_study_run(r)), key=lambda r: r["resolution"]):
            s = r["series"]
            t = [x["t"] for x in s]
            label = f"{r['resolution']} {case.unit}"
            if r.get("track") and len(r["track"]["t"]) > 20:  # the windowed speed the peak is read from
                centres, _, speed = windowed(r["track"]["t"], r["track"]["centroid_y"], t[-1] / 20, t[1])
                row[0].plot(centres, speed, label=label)
            else:
                row[0].plot(t, centroid_speed(s), label=label)
            for ax, y in zip(row[1:], ([x["centroid_y"] for x in s], [x["roundness"] for x in s])):
                ax.plot(t, y, label=label)
        for ax, m, ref in zip(row, ("rise speed", "centroid y", "circularity" if case.dim == 2 else "sphericity"),
                              ("rise_speed_max", "centroid_end", "circularity_min")):
            ax.set_title(f"{key}: {m}", fontsize=9)
            ax.set_xlabel("t (s)")
            if ref in case.reference and case.reference[ref][1] is not None:
                value, when, _ = case.reference[ref]
                ax.plot([when], [value], "k*", ms=10, label="published")
            elif ref in case.reference:
                ax.axhline(case.reference[ref][0], color="k", ls=":", label="published max")
        row[0].legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def solver_settings(pairs: list[str]) -> dict:
    """--set NAME=VALUE pairs as SolverSettings fields, each value read as `wedge --vary` reads one
    (a TOML literal, a bare word as text); a name that is not a field, or a value the settings
    refuse, raises ValueError."""
    fields = {f.name for f in dataclasses.fields(SolverSettings)} - {"quality", "seed"}
    out = {}
    for pair in pairs:
        name, sep, text = pair.partition("=")
        name = name.strip()
        if not sep or not text.strip():
            raise ValueError(f"expected NAME=VALUE, e.g. volume_relaxation_time=0; got {pair!r}")
        if name in ("quality", "seed"):  # their own flags
            raise ValueError(f"{name} has its own flag: --{name if name == 'quality' else 'seeds'}")
        if name not in fields:
            raise ValueError(f"{name!r} is not a [solver] setting; choose from {', '.join(sorted(fields))}")
        out[name] = parse_value(text.strip())
    try:  # the checks a scene's settings get, on the smallest of the studies' scenes
        with tempfile.TemporaryDirectory() as tmp:
            scene(CASES["hysing_2d"], 4, tmp, settings=out).validate()
    except SceneError as error:
        raise ValueError(str(error).removeprefix("<python>: ")) from None
    return out


def main(argv=None) -> int:
    ap = harness.parser(__doc__, quick="smaller grids and a shorter t_end")
    ap.add_argument("--cases", default=",".join(CASES))
    ap.add_argument("--resolutions", default=None, help="comma list (default: the case's levels)")
    ap.add_argument("--t-end", type=float, default=None)
    ap.add_argument("--quality", default="production",
                    help=f"comma list of quality presets to run ({', '.join(PRESETS)}; default production)")
    ap.add_argument("--seeds", default="0", help="comma list of particle seeds (default 0)")
    ap.add_argument("--set", action="append", default=[], metavar="NAME=VALUE",
                    help="a [solver] setting changed from the preset's, e.g. volume_relaxation_time=0 (repeatable; "
                         "needs --label, so the runs are saved apart from the study's)")
    ap.add_argument("--report-only", action="store_true", help="no runs: re-render from the saved ones")
    args = ap.parse_args(argv)
    try:
        settings = solver_settings(args.set)
    except ValueError as error:
        print(f"--set: {error}", file=sys.stderr)
        return 2
    if settings and not args.label:
        print("--set: give --label too (e.g. --label no_correction), so that these runs are saved apart and do "
              "not replace the study's", file=sys.stderr)
        return 2
    wp.config.quiet = True  # older Warp; 1.19 reads log_level
    wp.config.log_level = getattr(wp, "LOG_WARNING", 30)
    stem = harness.result_stem("convergence", args)
    run_dir = stem.with_name(stem.name + "_runs")
    run_dir.mkdir(parents=True, exist_ok=True)
    keys = [] if args.report_only else args.cases.split(",")
    for key in keys:
        if key not in CASES:
            print(f"--cases: unknown case {key!r}; choose from {', '.join(CASES)}", file=sys.stderr)
            return 2
    qualities = args.quality.split(",")
    bad = [q for q in qualities if q not in PRESETS]
    if bad:
        print(f"--quality: unknown preset {bad[0]!r}; choose from {', '.join(PRESETS)}", file=sys.stderr)
        return 2
    try:
        seeds = [int(x) for x in args.seeds.split(",")]
        if min(seeds) < 0:
            raise ValueError
    except ValueError:
        print(f"--seeds: expected whole numbers >= 0 separated by commas, e.g. 0,1,2; got {args.seeds!r}",
              file=sys.stderr)
        return 2
    try:
        chosen = [int(x) for x in args.resolutions.split(",")] if args.resolutions else None
        if chosen is not None and min(chosen) < 2:
            raise ValueError
    except ValueError:
        print(f"--resolutions: expected whole numbers of at least 2 separated by commas (cells across, or per "
              f"radius for free_surface_2d), e.g. 20,40,80; got {args.resolutions!r}", file=sys.stderr)
        return 2
    if args.t_end is not None and not (math.isfinite(args.t_end) and args.t_end > 0):
        print(f"--t-end: expected a time in seconds > 0, e.g. 1.5; got {args.t_end!r}", file=sys.stderr)
        return 2
    for key in keys:
        case = CASES[key]
        levels = chosen or (case.quick_levels if args.quick else case.levels)
        t_end = args.t_end or (case.quick_t_end if args.quick else case.t_end)
        for res in levels:
            for quality in qualities:
                for seed in seeds:
                    r = run_one(case, res, t_end, wp.get_device(args.device), quality, seed, settings)
                    r["command"], r["code"] = harness.command_line(), git_describe()
                    r["package"] = str(Path(warp_mpm_bubbles.__file__).resolve().parent.relative_to(ROOT))
                    (run_dir / run_file(key, res, quality, seed)).write_text(json.dumps(r, indent=1))
                    print(f"{key} {res} {quality} seed {seed}: {r['wall_s']:.0f} s, {r['steps']} steps, "
                          f"{r['summary']}", flush=True)
    runs = [json.loads(p.read_text()) for p in sorted(run_dir.glob("*.json"))]
    rep = report(runs, harness.command_line())
    md = markdown(rep)
    harness.write_result("convergence", args, rep, md, title="Convergence study")
    with open(stem.with_suffix(".csv"), "w", newline="") as fh:
        w = csv.writer(fh)
        keys = ("t", "centroid_y", "particle_speed", "roundness", "gas_region_ratio", "voids", "gaps", "steps")
        w.writerow(["case", "resolution", "quality", "seed", *keys, "rise_speed"])
        for r in runs:
            speed = centroid_speed(r["series"])
            for s, v in zip(r["series"], speed):
                w.writerow([r["case"], r["resolution"], r.get("quality", "production"), r.get("seed", 0),
                            *(s.get(k, s.get("rise_speed")) for k in keys), v])
    plot(runs, stem.with_suffix(".png"))
    print(md)
    return 0


if __name__ == "__main__":
    sys.exit(main())
