"""The validation cases shared by the tests and the benchmarks, importable from both without path
editing (`from benchmarks.cases import ...`; pytest puts the repository root on the path, and the
benchmarks run as modules from it): small scenes built with the Python API, the Rayleigh-Plesset
reference radius of a bubble, and the near-vacuum cavity with its 2D reference."""

from __future__ import annotations

import math

import numpy as np

from warp_mpm_bubbles import Box, Cylinder, Domain, Material, Output, Scene, SolverSettings
from warp_mpm_bubbles.core.simulation import Simulation
from warp_mpm_bubbles.references import (P_ATM, P_G0, R0, R_OUT0, RHO, T_UNIT, acceleration,  # noqa: F401
                                         first_minimum, radius_history, reference_times)
from warp_mpm_bubbles.scene.effects import Entrainment, Foam, SubgridBubbles


# ------------------------------------------------------------------ small scenes
WATER = {"water": Material("water", density=1000.0)}


def tank_2d(width=1.0, height=1.0, depth=0.5, cells=32, ppc=4, out="tank.usdc", **solver):
    """Water at rest, `depth` deep, in a closed free-slip tank."""
    return Scene(
        domain=Domain(size=(width, height), cell_size=width / cells),
        materials=dict(WATER),
        shapes=[Box("water", min=(0.0, 0.0), max=(width, depth))],
        solver=SolverSettings(particles_per_cell=ppc, **solver),
        output=Output(path=str(out), frames=4),
        name="tank_2d",
    )


def dam_break_2d(a=0.1, cells_per_a=16, length=6.0, ppc=4, out="dam.usdc", **solver):
    """Martin & Moyce's column: width a, height 2a, against the left wall of a tank `length` a long."""
    dx = a / cells_per_a
    return Scene(
        domain=Domain(size=(length * a, 2.5 * a), cell_size=dx),
        materials=dict(WATER),
        shapes=[Box("water", min=(0.0, 0.0), max=(a, 2 * a))],
        solver=SolverSettings(particles_per_cell=ppc, **solver),
        output=Output(path=str(out), frames=4),
        name="dam_break_2d",
    )


# ------------------------------------------------------------------ Rayleigh-Plesset reference
# In the package (warp_mpm_bubbles/references.py), re-exported here for the tests and benchmarks.


# ------------------------------------------------------------------ the near-vacuum cavity
# 2D, so the reference is the cylindrical analogue of Rayleigh's collapse: an empty cylinder of radius
# R0 in a liquid annulus whose outer surface (radius Rout, Rout^2 = Rout0^2 + R^2 - R0^2) is free at
# p_inf. Kinetic energy per unit length pi rho R^2 R'^2 ln(Rout/R) (plus the outer surface's term)
# equals the work p_inf pi (R0^2 - R^2), which is the Rayleigh-Plesset section's 2D equation with the
# gas pressure p_g -> 0; unlike 3D (t_c = 0.915 R0 sqrt(rho/dp)) no closed form exists because the
# energy depends on ln(Rout/R): an unbounded liquid (Rout -> inf) never collapses. RK4 of it gives
# the time to reach each radius.
#
# The simulated radius is read two ways: from the gas, sqrt(gas volume / (pi dx)) (the cavity's gas
# fills the room the liquid leaves, physics/cavity.py), and from the liquid alone, R_Q^2 = R(0)^2 +
# 2 int Q dt with Q = r u_r, the flux of the potential flow through the ring 1.8 R0 < r < 2.2 R0
# (the liquid's particles there). The two differ by how well the gas tracks the liquid.

def cavity_scene(cells_per_radius: int, out_dir, p_g0: float = P_G0, density: float = RHO, **solver) -> Scene:
    """A gas cylinder R0 at absolute pressure p_g0 p_inf in a free water annulus Rout0 across, no
    gravity; `density` is the water's (a mutation check sets it off the reference's RHO)."""
    dx = R0 / cells_per_radius
    L = 2 * (R_OUT0 + 0.5) * R0
    return Scene(
        domain=Domain(size=(L, L), cell_size=dx, gravity=(0.0, 0.0), walls="open", ambient_pressure=P_ATM),
        materials={"water": Material("water", density=density), "air": Material("air", kind="gas")},
        shapes=[Cylinder("water", center=(L / 2, L / 2), radius=R_OUT0 * R0),
                Cylinder("air", center=(L / 2, L / 2), radius=R0, pressure=(p_g0 - 1.0) * P_ATM)],
        solver=SolverSettings(**solver), output=Output(path=str(out_dir / "cavity.usdc")),
    )


def ring_flux(sim) -> float:
    """Q = r u_r of the liquid particles in the ring 1.8 R0 < r < 2.2 R0, in R0 sqrt(p_inf/rho)."""
    p = sim.particles_numpy()
    liquid = p["phase"] == 0
    d = p["positions"][liquid, :2] - np.array(sim.grid.domain_size[:2]) / 2
    r = np.linalg.norm(d, axis=1)
    ring = (r > 1.8 * R0) & (r < 2.2 * R0)
    return float((p["velocities"][liquid, :2] * d).sum(1)[ring].mean()) / (R0 * math.sqrt(P_ATM / RHO))


def crossings(t, R, radii) -> dict:
    """The first time the sampled R(t) falls below each of radii (linear between samples; None: never)."""
    R, out = np.asarray(R), {}
    for r in radii:
        i = int(np.argmax(R < r))
        out[r] = float(np.interp(r, [R[i], R[i - 1]], [t[i], t[i - 1]])) if R[i] < r else None
    return out


def collapse_time(cells_per_radius: int = 8, out_dir=None, radii=(0.5, 0.25), t_end: float = 1.6,
                  max_steps: int = 5_000, p_g0: float = P_G0, density: float = RHO, to_end: bool = False, **solver):
    """Run the cavity with the default steps (the gas_expansion limit must resolve the start) until
    both radii have passed the smallest of `radii` (unless to_end) or t_end (in T_UNIT). Returns the crossing times
    of each radius (t / T_UNIT, None if not reached) by the gas ("t") and by the liquid's flux
    ("t_flux"), the reference's, and the states of the liquid and the gas ledger."""
    import tempfile
    from pathlib import Path

    out_dir = Path(out_dir or tempfile.mkdtemp())
    sim = Simulation(cavity_scene(int(cells_per_radius), out_dir, p_g0, density, **solver), "cpu")
    dx = sim.grid.dx
    radius = lambda: math.sqrt(sim.gas_budget()["volume"] / (math.pi * dx)) / R0  # noqa: E731
    liquid0, budget0 = liquid_extent(sim), sim.gas_budget()
    t, R, RQ = [0.0], [radius()], [radius()]
    q_area, q_last = RQ[0] ** 2, 0.0  # R_Q^2, integrated by the trapezoid rule
    while (to_end or max(R[-1], RQ[-1]) > min(radii)) and sim.time < t_end * T_UNIT and sim.stats.steps < max_steps:
        sim.advance_to(sim.time + sim.stable_dt())
        q = ring_flux(sim)
        q_area += (sim.time / T_UNIT - t[-1]) * (q + q_last)
        q_last = q
        t.append(sim.time / T_UNIT)
        R.append(radius())
        RQ.append(math.sqrt(max(q_area, 0.0)))
    return {"cells_per_radius": int(cells_per_radius), "p_g0": p_g0, "steps": sim.stats.steps,
            "first_dt": sim.stats.dt_history[:3], "t": crossings(t, R, radii), "t_flux": crossings(t, RQ, radii),
            "t_ref": reference_times(radii, p_g0), "R0_seeded": R[0], "liquid_before": liquid0,
            "liquid_after": liquid_extent(sim), "gas_before": budget0, "gas_after": sim.gas_budget()}


def liquid_extent(sim) -> dict[str, float]:
    """The liquid's outer radius (95th percentile of the particles' distance from the centre, in R0),
    its volume share of the seeded annulus, and its fastest particle (m/s)."""
    p = sim.particles_numpy()
    liquid = p["phase"] == 0
    centre = np.array(sim.grid.domain_size[:2]) / 2
    r = np.linalg.norm(p["positions"][liquid, :2] - centre, axis=1) / R0
    annulus = math.pi * ((R_OUT0 * R0) ** 2 - R0**2) * sim.grid.dx
    return {"outer_radius": float(np.percentile(r, 95)), "volume_share": float(p["volume"][liquid].sum() / annulus),
            "max_speed": float(np.linalg.norm(p["velocities"][liquid], axis=1).max())}


def cavity_in_tank(cells: int, out_dir, t_end: float = 0.3, max_steps: int = 20_000, **solver) -> dict:
    """The case the cavity model was built for: a near-vacuum cavity 1/5 of the depth across, in a 2D tank under gravity.
    Returns the water's surface (99th percentile of its particles' height), centroid height, volume
    and fastest particle before and after t_end (or max_steps), and the gas ledger before and after."""
    W = 0.1
    dx = W / cells
    scene = Scene(
        domain=Domain(size=(W, W), cell_size=dx),
        materials={"water": Material("water"), "air": Material("air", kind="gas")},
        shapes=[Box("water", (0.0, 0.0), (W, 0.6 * W)),
                Cylinder("air", center=(W / 2, 0.3 * W), radius=0.1 * W, pressure=(P_G0 - 1.0) * P_ATM)],
        solver=SolverSettings(**solver), output=Output(path=str(out_dir / "tank.usdc"), fps=60),
    )
    sim = Simulation(scene, "cpu")

    def state():
        p = sim.particles_numpy()
        y = p["positions"][p["phase"] == 0, 1]
        return {"surface": float(np.percentile(y, 99)), "centroid": float(y.mean()), "volume": sim.liquid_volume(),
                "max_speed": float(np.linalg.norm(p["velocities"][p["phase"] == 0], axis=1).max())}

    before, gas_before = state(), sim.gas_budget()
    while sim.time < t_end - 1e-9 and sim.stats.steps < max_steps:
        sim.advance_to(min(t_end, sim.time + sim.stable_dt()))
    return {"before": before, "after": state(), "t": sim.time, "steps": sim.stats.steps, "limits": sim.dt_limits(),
            "gas_before": gas_before, "gas": sim.gas_budget()}


# ------------------------------------------------------------------ sub-grid bubbles and entrainment
L = 0.1  # m: the side of the sub-grid tests' tank


def subgrid_tank(tmp_path, dim=2, cells=32, depth=0.09, shapes=(), effects=None, **solver):
    """Water `depth` deep in a closed L x L (x L) tank with an air material for the gas shapes and effects."""
    size = (L,) * dim
    water = Box("water", min=(0.0,) * dim, max=(L, depth) + (L,) * (dim - 2))
    return Scene(
        domain=Domain(size=size, cell_size=L / cells),
        materials={"water": Material("water", viscosity=solver.pop("viscosity", 0.0)),
                   "air": Material("air", kind="gas")},
        shapes=[water, *shapes],
        solver=SolverSettings(particles_per_cell=4 if dim == 2 else 8, **solver),
        output=Output(path=str(tmp_path / "s.usdc")),
        effects={} if effects is None else effects,
    )


def splash_scene(tmp_path, falling=True, foam=False):
    """A 2 cm block of water thrown at 2 m/s into a 3 cm pool (or the pool alone, at rest)."""
    shapes = [Box("water", min=(0.04, 0.045), max=(0.06, 0.065), velocity=(0.0, -2.0))] if falling else []
    effects = {"subgrid_bubbles": SubgridBubbles(), "entrainment": Entrainment(rate=1000.0, min_speed=0.5)}
    if foam:
        effects["foam"] = Foam(lifetime=0.01)
    return subgrid_tank(tmp_path, depth=0.03, shapes=shapes, effects=effects)
