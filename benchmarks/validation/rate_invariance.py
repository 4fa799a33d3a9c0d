"""Does the state at a time depend on the frame rate, max_dt or the gas's step?

    python -m benchmarks.validation.rate_invariance rest       # water at rest under tiny steps (max_dt 1e-6 s)
    python -m benchmarks.validation.rate_invariance fps        # a 2D dam break at fps 24 / 240 and max_dt none / 1 ms
    python -m benchmarks.validation.rate_invariance expansion  # gas seeded at 10 atm: first steps, gas speeds, work
    python -m benchmarks.validation.rate_invariance cavity     # a near-vacuum cavity in water vs Rayleigh's time
    python -m benchmarks.validation.rate_invariance tank       # the same cavity in a tank under gravity
    python -m benchmarks.validation.rate_invariance --quick    # the rest case

Extra solver settings: --solver key=value (repeatable). Prints one JSON object per case and merges it
into benchmarks/results/rate_invariance/<device>.{json,md} (each case with its own provenance and
solver settings). CPU, a few minutes in all.
"""
from __future__ import annotations

import json
import sys
import tempfile
from pathlib import Path

import numpy as np
import warp as wp

from warp_mpm_bubbles import Box, Domain, Material, Output, Scene, SolverSettings, Sphere
from warp_mpm_bubbles.core.simulation import Simulation

from benchmarks import harness
from benchmarks.cases import cavity_in_tank, collapse_time, dam_break_2d, tank_2d

wp.config.quiet = True
P_ATM = 101325.0
TMP = Path(tempfile.mkdtemp())


def liquid_state(sim):
    """Centroid, mean and max speed of the liquid particles."""
    p = sim.particles_numpy()
    liquid = ~np.array([m.is_gas for m in sim.scene.materials.values()])[p["material"]]
    speed = np.linalg.norm(p["velocities"][liquid], axis=1)
    c = p["positions"][liquid].mean(0)
    return {"centroid": [round(float(a), 6) for a in c[: sim.grid.dim]], "mean_speed": float(speed.mean()),
            "max_speed": float(speed.max())}


def rest(solver):
    out = {}
    for max_dt in (None, 1e-4, 1e-6):
        sim = Simulation(tank_2d(depth=0.5, cells=32, out=TMP / "r.usdc", max_dt=max_dt, **solver), "cpu")
        for _ in range(20):
            sim.step(sim.stable_dt())
        out[f"max_dt={max_dt}"] = {"steps": 20, "t": sim.stats.steps and sum(sim.stats.dt_history),
                                   **liquid_state(sim)}
    return out


def dam(fps, max_dt, solver, t_end=0.25, cells_per_a=8):
    """A 2D dam break run frame by frame (steps land on frame times) to t_end, a whole number of frames."""
    scene = dam_break_2d(cells_per_a=cells_per_a, out=TMP / "d.usdc", max_dt=max_dt, **solver)
    scene.output.fps = fps
    sim = Simulation(scene, "cpu")
    v0 = sim.liquid_volume()
    while sim.time < t_end - 1e-9:
        sim.advance_frame()
    return {"t": sim.time, "steps": sim.stats.steps, "volume_drift": sim.liquid_volume() / v0 - 1.0,
            **liquid_state(sim)}


def fps_case(solver):
    return {f"fps={fps},max_dt={m}": dam(fps, m, solver) for fps, m in ((24, None), (240, None), (24, 1e-3))}


def expansion(solver, t_end=0.0015):
    """tests/test_hard_cases.py's bubble compressed tenfold: gas at 10 atm in a 2D tank."""
    dx, radius = 0.0025, 0.004
    scene = Scene(domain=Domain(size=(0.1, 0.2), cell_size=dx),
                  materials={"water": Material("water"), "air": Material("air", kind="gas")},
                  shapes=[Box("water", (0.0, 0.0), (0.1, 0.1)), Sphere("air", (0.05, 0.03), radius, pressure=9 * P_ATM)],
                  solver=SolverSettings(**solver), output=Output(path=str(TMP / "e.usdc"), fps=60))
    sim = Simulation(scene, "cpu")
    gas_speed, steps = 0.0, []
    while sim.time < t_end - 1e-12:
        sim.advance_to(min(t_end, sim.time + sim.stable_dt()))
        p = sim.particles_numpy()
        gas = np.array([m.is_gas for m in sim.scene.materials.values()])[p["material"]]
        gas_speed = max(gas_speed, float(np.linalg.norm(p["velocities"][gas], axis=1).max()))
        steps.append(sim.stats.dt_history[-1])
    return {"t_end": t_end, "steps": sim.stats.steps, "first_dt": [float(f"{d:.3g}") for d in steps[:5]],
            "max_gas_speed": gas_speed, "gas_J_mean": float(sim.particles_numpy()["J"][gas].mean()),
            **liquid_state(sim)}


def main(argv=None) -> int:
    ap = harness.parser(__doc__.split("\n")[0], quick="the rest case (20 steps of a 2D tank)")
    ap.add_argument("case", nargs="?", choices=["rest", "fps", "expansion", "cavity", "tank"])
    ap.add_argument("--solver", action="append", default=[], help="key=value")
    ap.add_argument("--t-end", type=float, default=None)
    a = ap.parse_args(argv)
    if a.device != "cpu":
        ap.error(f"--device {a.device}: these cases run on the CPU only")
    a.case = a.case or ("rest" if a.quick else None)
    if a.case is None:
        ap.error("name a case: rest, fps, expansion, cavity or tank")
    if a.quick and a.case != "rest":
        ap.error("--quick runs the rest case only")
    solver = {k: (None if v == "None" else float(v)) for k, v in (s.split("=") for s in a.solver)}
    if a.case == "rest":
        res = rest(solver)
    elif a.case == "fps":
        res = fps_case(solver)
    elif a.case == "expansion":
        res = expansion(solver, *([a.t_end] if a.t_end else []))
    elif a.case == "cavity":
        res = {f"{n} cells per radius": collapse_time(n, **solver) for n in (8, 12, 16)}
    else:
        res = cavity_in_tank(32, TMP, **solver)
    print(json.dumps({a.case: res, "solver": solver}, indent=1))
    stored = harness.read_result("rate_invariance", a) or {}
    cases = stored.get("cases", {})
    cases[a.case] = {"solver": solver, "result": res, "provenance": harness.provenance(a.device)}
    tables = [f"## {name} (solver settings {c['solver'] or 'default'})\n\n"
              + harness.records_table(c["result"] if all(isinstance(v, dict) for v in c["result"].values())
                                      else {name: c["result"]})
              for name, c in cases.items()]
    harness.write_result("rate_invariance", a, {"cases": cases}, "\n".join(tables),
                         title="Rate invariance: the state at a time against the frame rate and step")
    return 0


if __name__ == "__main__":
    sys.exit(main())
