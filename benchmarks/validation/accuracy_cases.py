"""The reference cases of benchmarks/accuracy_vs_time.py (its docstring describes each): a scene
builder and a measure per case, and the Clock that times only the simulation loop."""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from warp_mpm_bubbles import Box, Cylinder, Domain, Material, Output, Scene, SolverSettings, Sphere
from warp_mpm_bubbles.diagnostics import gas_centroid_and_diameter
from warp_mpm_bubbles.core.simulation import Simulation

from benchmarks.harness import ROOT

MARTIN_MOYCE = ROOT / "tests" / "data" / "martin_moyce_1952_n2_2_a2.25in.csv"
G, P_ATM, RHO_W, SIGMA = 9.81, 101325.0, 1000.0, 0.072


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
