"""What benchmarks/validation/accuracy_vs_time.py writes from its measured rows: convergence orders over
the seed noise, the CSV, the Markdown table with its notes, the presets' table and the plot."""

from __future__ import annotations

import csv
import math
import sys
from itertools import pairwise
from pathlib import Path

import numpy as np

from warp_mpm_bubbles.scene.quality import PRESETS

from benchmarks.validation.accuracy_cases import CASES

COLUMNS = ["case", "metric", "setting", "value", "is_default", "run_id", "batch", "quality", "resolution",
           "resolution_unit", "dx", "refine", "particles_per_cell", "cfl", "cg_tolerance", "interface", "seed",
           "particles", "cells", "steps", "cg_iterations_mean", "wall_s", "cpu_s", "measured", "reference", "error",
           "error_signed", "error_kind", "note"]


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
           "- data: the `.csv` of this file's name (one row per point and measure; the default run is repeated "
           "in every sweep with the same `run_id`; `batch` names the run that measured it); plot: the `.png` "
           "of this file's name.", ""]
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
of cfl 0.25 and cg_tolerance 1e-6. The Laplace drop was re-measured at 6adeb41 (batch 10, the
best-centred height columns), the Minnaert bubble and the rising bubble at b2f2d5f (batch 11, a
gas cell's compressibility the gas's share of the cell), the dam breaks at b45dea0 (batches 6-8);
the closed tanks of benchmarks/convergence.py, which converge, carry the presets too
(docs/convergence.md, "The quality presets"). Means over 3 seeds, production's first:

- Reference lowers the error on the measures that converge with the grid: the Minnaert frequency
  (1.33% against 1.54%, by about its seed ranges of 0.22% and 0.17%), the 3D front position
  (0.028 a against 0.034 a, ranges 0.0018 a and 0.0032 a) and, in the convergence study, every
  metric of the 2D and 3D closed tanks. The short Laplace drop (the jump over t = 0.035-0.06 s)
  sits at its seed noise in every preset (0.73% against 1.12%, ranges 2.1% and 2.2%): the finer
  grid has nothing left to lower there (docs/convergence.md, best-centred height columns).
- Not lowered: the dam break's volume drift (2D 0.93% against 0.94%, 3D 0.67% against 0.53%): it
  is set by the volume correction's relaxation time, not by the grid (the convergence notes); the
  front speed against Martin & Moyce (2D 5.4% against 4.2%, 3D 4.9% against 2.8%), which moves
  away from the experiment as the grid is refined in the sweep too: it measures the model against
  the experiment; and the free-surface rising bubble (4.0% against 4.4% of the 12-cell run, ranges
  1.8% and 1.4%), which does not converge: inviscid, it has no grid-converged answer
  (docs/convergence.md).
- Preview against production: the same errors to 3 digits where cfl does not set the step (the
  Laplace drop and the Minnaert bubble: the capillary limit and the sampling interval do; the closed
  tanks), for 0.8-0.9x the time there. Where it does, preview halves the steps: the dam break's
  drift rises (2D 1.11% against 0.94%, 3D 0.71% against 0.53%) and its front position's RMS (2D
  0.033 a against 0.029 a, 3D 0.041 a against 0.034 a); the rising bubble's error moves within its
  seed ranges (3.5% against 4.4%, ranges 5.1% and 1.4%).
- Cost, CPU seconds against production in the same batch: reference 4.3-4.6x for the 2D
  capillary-limited and sampled cases (4x the cells), 8.4-12x for the 2D dam break and the rising
  bubble (4x the cells, 3.7-4x the steps), 20x for the 3D dam break (8x the cells, 3.6x the
  steps). Preview costs 0.5-0.6x where cfl sets the step.

How the governed values were chosen (warp_mpm_bubbles/scene/quality.py), from the one-at-a-time
sweeps in the study's table (this file's name without `_presets`; the figures below are those of the batch that chose them, at
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
           f"Measured for {runs}: the `quality` and `seed` rows of the study's table, each case at its "
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


def batch_note(rows) -> str:
    """For a plot title: say so when the points come from runs timed at different loads."""
    n = len({r["batch"] for r in rows})
    return f"; points from {n} runs (batches) timed at different loads, see the .md" if n > 1 else ""


def render(stem: Path, meta: dict, rows: list[dict], args):
    """Write the CSV, the Markdown (stem.md), the presets' table (stem_presets.md) and the plot from the
    measured rows."""
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

    write_csv(stem.with_suffix(".csv"), rows)
    text = markdown(meta, rows, orders, noise)
    stem.with_suffix(".md").write_text(text)
    presets = stem.with_name(stem.name + "_presets.md")
    presets.write_text(presets_markdown(meta, rows))
    if not args.no_plot:
        try:
            devices = ", ".join(dict.fromkeys(b["device"] for b in meta["batches"]))
            plot(stem.with_suffix(".png"), rows, f"error against wall seconds, {devices}{batch_note(rows)}")
        except ImportError:
            args.no_plot = True
            print("matplotlib not installed (the [plots] extra): no PNG written", file=sys.stderr)
    print(text)
    print(f"wrote {stem}.{{csv,md{'' if args.no_plot else ',png'}}} and {presets.name} from the "
          f"{meta['mode']} run(s) of {', '.join(b['date'] for b in meta['batches'])}", file=sys.stderr)
