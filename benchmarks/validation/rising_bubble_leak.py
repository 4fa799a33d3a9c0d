"""The leak metric (water inside the gas, gas smeared into the water) on a rising bubble, interface
methods side by side, until it has risen five diameters.

    python -m benchmarks.validation.rising_bubble_leak        # 2D, 8 cells per radius: ~5 min on the CPU
    python -m benchmarks.validation.rising_bubble_leak --dim 3 --shape cap --variants own,own/passive,shared  # 3D, 5 cells per radius: ~6 min each
    python -m benchmarks.validation.rising_bubble_leak --dim 3 --shape cap --cells-per-radius 7 --variants own --label 3d_cap_7  # ~25 min
    python -m benchmarks.validation.rising_bubble_leak --dim 3 --shape cap --cells-per-radius 10 --device cuda:0
    python -m benchmarks.validation.rising_bubble_leak --quick   # 2D, 4 cells per radius, `own` to t = 0.05 s

A 2 cm air bubble (Eotvos 54, water's surface tension) starts at rest near the bottom of a tank tall
enough for it to rise five diameters before it nears the surface. Every frame (60 fps) the gas
particles are measured with `warp_mpm_bubbles.diagnostics`:

    liquid in gas   liquid volume at least one cell deep inside the gas, / gas volume (water leaked in)
    gas in liquid   gas volume at least one cell deep inside the liquid, / gas volume (gas smeared out)
    largest bubble  share of the gas in the largest connected bubble

Variants: `own` (the default: sharp interface, the liquid reads its own velocity field, gas films
thinner than a cell retract into their bubble), `own/passive` (the same with films left to ride the
liquid, the default before gas_films existed), `shared` (sharp interface, one velocity field for both
phases), `baseline` (the published method), `own+subgrid` (the default with the sub-grid bubble effect: gas shed below the grid's size becomes
Lagrangian bubbles, counted apart from the resolved gas in the `sub-grid` column).
Writes benchmarks/results/rising_bubble_leak/<device>_<dim>d[_cap].{json,md,png} (--label names another
configuration: <device>_<label>.*). A measurement, not a test.
"""

from __future__ import annotations

import json
import math
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import warp as wp

from warp_mpm_bubbles import (
    Box,
    Domain,
    Material,
    Output,
    Scene,
    SolverSettings,
    Sphere,
)
from warp_mpm_bubbles import diagnostics as D
from warp_mpm_bubbles.core.grid import PHASE_GAS
from warp_mpm_bubbles.scene.effects import SubgridBubbles
from warp_mpm_bubbles.core.simulation import Simulation

from benchmarks import harness

RADIUS = 0.01
TANK_WIDTH = {2: 0.08, 3: 0.06}  # m
CAP_ANGLE = math.radians(50.0)  # half-angle of a spherical-cap bubble (Davies & Taylor 1950 measured ~50 degrees)
VARIANTS = {  # name: (interface, liquid_velocity, gas_films, effects)
    "own": ("sharp", "own", "retract", {}),
    "own/passive": ("sharp", "own", "passive", {}),
    "shared": ("sharp", "shared", "retract", {}),
    "baseline": ("baseline", "shared", "passive", {}),  # the baseline has no sub-cell gas to retract
    "own+subgrid": ("sharp", "own", "retract", {"subgrid_bubbles": SubgridBubbles()}),
}


def tank(dim: int, cells_per_radius: int, variant: str, shape: str = "sphere") -> Scene:
    """Water 0.18 m deep (0.20 in 2D) and the bubble near the floor: a sphere of RADIUS centred 2.5 cm
    up, or Davies & Taylor's spherical cap (half-angle CAP_ANGLE) of the same volume. Released
    from rest, a large bubble becomes a spherical cap or a toroidal bubble depending on how it
    starts (Walters & Davidson 1963; Bonometti & Magnaudet 2006): the cap start is the one
    Davies & Taylor's rise speed describes."""
    interface, liquid_velocity, gas_films, effects = VARIANTS[variant]
    width, depth = TANK_WIDTH[dim], 0.20 if dim == 2 else 0.18
    lo, size = (0.0,) * dim, (width, depth + 0.02) + (width,) * (dim - 2)
    across = lambda y: (width / 2, y) + (width / 2,) * (dim - 2)  # noqa: E731
    shapes = [Box("water", lo, (width, depth) + (width,) * (dim - 2))]
    if shape == "sphere":
        shapes.append(Sphere("air", across(0.025), RADIUS))
    else:  # the cap: a ball of radius R_c cut by water refilled below its base
        c = math.cos(CAP_ANGLE)
        if dim == 3:  # pi R_c^3 (1 - c)^2 (2 + c) / 3 = 4/3 pi R^3
            r_c = RADIUS * (4.0 / ((1.0 - c) ** 2 * (2.0 + c))) ** (1.0 / 3.0)
        else:  # R_c^2 (theta - sin theta cos theta) = pi R^2
            r_c = RADIUS * math.sqrt(math.pi / (CAP_ANGLE - math.sin(CAP_ANGLE) * c))
        centre_y = 1.02 * r_c  # the ball must lie inside the domain
        shapes += [Sphere("air", across(centre_y), r_c),
                   Box("water", lo, (width, centre_y + r_c * c) + (width,) * (dim - 2))]
    return Scene(
        domain=Domain(size=size, cell_size=RADIUS / cells_per_radius, walls="free_slip"),
        materials={"water": Material("water", surface_tension=0.072), "air": Material("air", kind="gas")},
        shapes=shapes,
        solver=SolverSettings(interface=interface, liquid_velocity=liquid_velocity, gas_films=gas_films),
        effects=dict(effects),
        output=Output(path=str(Path(tempfile.gettempdir()) / "rising_bubble_leak_unused.usdc"), fps=60),
    )


def measure(sim: Simulation, dim: int) -> dict:
    p = sim.particles_numpy()
    air = p["material"] == list(sim.scene.materials).index("air")
    gas = air & (p["phase"] == PHASE_GAS)  # resolved gas; sub-grid bubbles are counted apart
    # In 2D the volumes are areas times the slab thickness dx: divide for the circle's diameter.
    area = p["volume"] / (sim.grid.dx if dim == 2 else 1.0)
    centroid, d_e = D.gas_centroid_and_diameter(p["positions"], gas, area, dim)
    # phase_leak is relative to the resolved gas; rescale everything to all the gas under water.
    resolved_share = float(p["volume"][gas].sum() / p["volume"][air].sum())
    leak = D.phase_leak(p["positions"], gas, p["volume"], sim.grid.dx, sim.grid.interior, dim)
    bubbles = D.bubble_volumes(p["positions"], gas, p["volume"], sim.grid.dx, sim.grid.interior, dim)
    budget = sim.gas_budget()
    return {"t": sim.time, "height": float(centroid[1]), "d_e": d_e,
            **{key: value * resolved_share for key, value in leak.items()},
            "largest_bubble": float(bubbles[0] / p["volume"][air].sum()) if len(bubbles) else 0.0,
            "vented": budget["vented"] / budget["total"], "subgrid": 1.0 - resolved_share}


def run(variant: str, args, device) -> dict:
    sim = Simulation(tank(args.dim, args.cells_per_radius, variant, args.shape), device)
    start = time.perf_counter()
    first = measure(sim, args.dim)
    frames = [first]
    while frames[-1]["height"] - first["height"] < args.diameters * first["d_e"] and sim.time < args.max_time:
        sim.advance_frame()
        row = measure(sim, args.dim)
        row["rise_diameters"] = (row["height"] - first["height"]) / first["d_e"]
        frames.append(row)
        print(f"  {variant:11s} t = {row['t']:.3f} s  rise {row['rise_diameters']:.2f} d  liquid in gas "
              f"{100 * row['liquid_in_gas']:.2f}%  gas in liquid {100 * row['gas_in_liquid']:.2f}%  largest "
              f"{100 * row['largest_bubble']:.0f}%", file=sys.stderr, flush=True)
    frames[0]["rise_diameters"] = 0.0
    wall = time.perf_counter() - start
    r = np.array([(f["t"], f["height"]) for f in frames])
    half = len(r) // 2
    speed = float(np.polyfit(r[half:, 0], r[half:, 1], 1)[0]) if len(r) > 3 else float("nan")
    last = frames[-1]
    return {
        "variant": variant, "interface": VARIANTS[variant][0], "liquid_velocity": VARIANTS[variant][1],
        "gas_films": VARIANTS[variant][2], "effects": sorted(VARIANTS[variant][3]), "subgrid_end": last["subgrid"],
        "particles": sim.num_particles, "steps": sim.stats.steps, "wall_seconds": wall,
        "rise_diameters": last["rise_diameters"], "time": last["t"], "rise_speed": speed,
        "liquid_in_gas_max": max(f["liquid_in_gas"] for f in frames), "liquid_in_gas_end": last["liquid_in_gas"],
        "gas_in_liquid_end": last["gas_in_liquid"], "largest_bubble_end": last["largest_bubble"],
        "vented_end": last["vented"], "frames": frames,
    }


def plot(results: list[dict], path: Path, title: str):
    try:
        import matplotlib
    except ImportError:
        print("matplotlib not installed (pip install -e .[plots]): no picture", file=sys.stderr)
        return
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 3, figsize=(13, 3.8))
    for res in results:
        x = [f["rise_diameters"] for f in res["frames"]]
        axes[0].plot(x, [100 * f["liquid_in_gas"] for f in res["frames"]], label=res["variant"])
        axes[1].plot(x, [100 * f["gas_in_liquid"] for f in res["frames"]], label=res["variant"])
        axes[2].plot(x, [100 * f["largest_bubble"] for f in res["frames"]], label=res["variant"])
    axes[0].axhline(1.0, color="k", lw=0.8, ls="--", label="the bar (1%)")
    for ax, name in zip(axes, ("liquid in gas, % of gas volume", "gas in liquid, % of gas volume",
                               "largest bubble, % of the gas")):
        ax.set_xlabel("rise, bubble diameters")
        ax.set_title(name, fontsize=10)
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize=8)
    fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def main(argv=None) -> int:
    parser = harness.parser(__doc__, quick="2D, 4 cells per radius, the `own` variant to t = 0.05 s")
    parser.add_argument("--dim", type=int, choices=(2, 3), default=2)
    parser.add_argument("--cells-per-radius", type=int, default=None, help="default 8 in 2D, 5 in 3D")
    parser.add_argument("--diameters", type=float, default=5.0, help="stop once the bubble has risen this far")
    parser.add_argument("--max-time", type=float, default=1.5, help="simulated seconds at most")
    parser.add_argument("--variants", default="own,own/passive,shared,baseline", help=f"comma list of {', '.join(VARIANTS)}")
    parser.add_argument("--shape", choices=("sphere", "cap"), default="sphere",
                        help="the bubble at rest: a sphere, or Davies & Taylor's spherical cap of the same volume")
    parser.add_argument("--render-only", action="store_true", help="rewrite the table and picture from the JSON")
    args = parser.parse_args(argv)
    if args.quick:
        args.dim, args.cells_per_radius, args.max_time, args.variants = 2, 4, 0.05, "own"
    args.cells_per_radius = args.cells_per_radius or (8 if args.dim == 2 else 5)
    variants = [v.strip() for v in args.variants.split(",") if v.strip()]
    unknown = [v for v in variants if v not in VARIANTS]
    if unknown:
        parser.error(f"--variants: unknown {unknown}; choose from {', '.join(VARIANTS)}")
    wp.config.quiet = True
    device = wp.get_device(args.device)
    args.label = args.label or f"{args.dim}d" + ("_cap" if args.shape == "cap" else "")
    stem = harness.result_stem("rising_bubble_leak", args)
    if args.render_only:  # the table and picture again from the saved figures (their provenance kept)
        saved = json.loads(stem.with_suffix(".json").read_text())
        results = saved.pop("results")
        prov = saved.get("provenance")
        made = harness.provenance_line(prov) if prov else (
            f"*{saved['date']}, warp {saved['warp_version']}; `{saved['command']}`*")  # files from before the harness
        stem.with_suffix(".md").write_text(f"# {title(saved)}\n\n{made}\n\n{markdown(results, saved)}")
        plot_results(results, saved, stem)
        return 0
    meta = {"device": harness.describe_device(args.device), "dim": args.dim,
            "cells_per_radius": args.cells_per_radius, "diameters": args.diameters, "shape": args.shape}
    results = []
    for v in variants:  # the files are rewritten after each variant: a long run keeps what it finished
        results.append(run(v, args, device))
        md = markdown(results, meta)
        print(md)
        harness.write_result("rising_bubble_leak", args, {**meta, "results": results}, md, title=title(meta))
        plot_results(results, meta, stem)
    return 0


def title(meta: dict) -> str:
    return f"Leak of a rising bubble, {meta['dim']}D, {meta['cells_per_radius']} cells per radius, on {meta['device']}"


def plot_results(results: list[dict], meta: dict, stem: Path):
    plot(results, stem.with_suffix(".png"), f"rising bubble, {meta['dim']}D, {meta['cells_per_radius']} cells per radius")


def wall_factor(d_over_width: float) -> float:
    """Rise speed in a tube over that in open water, spherical caps: 1.13 exp(-d/D) for
    0.125 <= d/D <= 0.6 (Wallis 1969, in Clift, Grace & Weber 1978, ch. 9); 1 below. The tank's
    width stands in for the tube's diameter."""
    return 1.0 if d_over_width < 0.125 else 1.13 * math.exp(-d_over_width)


def speed_as_one_bubble(frames: list[dict], start: float = 0.1) -> float:
    """The centroid's rise speed from `start` (past the start-up) while the largest bubble still
    holds half the gas: the speed of a bubble, not of the pieces it may break into. NaN under 3 frames."""
    kept = []
    for f in frames:
        if f["largest_bubble"] < 0.5:
            break
        if f["t"] >= start - 1e-9:
            kept.append((f["t"], f["height"]))
    return float(np.polyfit(*np.array(kept).T, 1)[0]) if len(kept) >= 3 else float("nan")


def markdown(results: list[dict], meta: dict) -> str:
    dim, d_e = meta["dim"], results[0]["frames"][0]["d_e"]
    lines = [
        (f"- 2 cm air bubble in water ({meta.get('shape', 'sphere')} at rest), surface tension 0.072 N/m; measured every frame until it has risen "
         f"{meta.get('diameters', 5.0):g} diameters (d_e = {100 * d_e:.2f} cm)"),
        ("- liquid in gas: liquid at least one cell deep inside the gas (water leaked into bubbles); gas in "
         "liquid: gas at least one cell deep inside the liquid; both, the largest bubble and the sub-grid "
         "bubbles relative to all the gas under water"),
        "", ("| variant | interface | liquid velocity | gas films | rise | time | rise speed | liquid in gas (max) | "
             "liquid in gas (end) | gas in liquid (end) | largest bubble (end) | sub-grid | vented | steps | wall s | "
             "speed while one bubble |"),
        "|---|---|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for r in results:
        lines.append(
            # runs saved before gas_films existed (commit ee0dea8 and older) all left films passive
            f"| {r['variant']} | {r['interface']} | {r['liquid_velocity']} | {r.get('gas_films', 'passive')} | "
            f"{r['rise_diameters']:.2f} d | "
            f"{r['time']:.3f} s | {r['rise_speed']:.3f} m/s | {100 * r['liquid_in_gas_max']:.2f}% | "
            f"{100 * r['liquid_in_gas_end']:.2f}% | {100 * r['gas_in_liquid_end']:.1f}% | "
            f"{100 * r['largest_bubble_end']:.0f}% | {100 * r.get('subgrid_end', 0.0):.1f}% | "
            f"{100 * r['vented_end']:.1f}% | {r['steps']} | "
            f"{r['wall_seconds']:.0f} | {speed_as_one_bubble(r['frames']):.3f} m/s |")
    if dim == 3:
        open_water = 0.711 * math.sqrt(9.81 * d_e)
        factor = wall_factor(d_e / TANK_WIDTH[3])
        lines += ["", (f"Davies & Taylor: 0.711 sqrt(g d_e) = {open_water:.3f} m/s in open water; in this tank "
                       f"(d/D = {d_e / TANK_WIDTH[3]:.2f}, wall factor {factor:.2f}) {factor * open_water:.3f} m/s. "
                       "Rise speed: the centroid's slope over the second half of the run; while one bubble: "
                       "from 0.1 s until the largest bubble holds less than half the gas.")]
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    sys.exit(main())
