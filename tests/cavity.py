"""A near-vacuum cavity collapsing in water (issue #12), shared by tests/test_cavity.py,
benchmarks/cavity_collapse.py and benchmarks/rate_invariance.py.

2D, so the reference is the cylindrical analogue of Rayleigh's collapse: an empty cylinder of radius
R0 in a liquid annulus whose outer surface (radius Rout, Rout^2 = Rout0^2 + R^2 - R0^2) is free at
p_inf. Kinetic energy per unit length pi rho R^2 R'^2 ln(Rout/R) (plus the outer surface's term)
equals the work p_inf pi (R0^2 - R^2), which is tests/rayleigh_plesset.py's 2D equation with the
gas pressure p_g -> 0; unlike 3D (t_c = 0.915 R0 sqrt(rho/dp)) no closed form exists because the
energy depends on ln(Rout/R): an unbounded liquid (Rout -> inf) never collapses. RK4 of it gives
the time to reach each radius.

The simulated radius is read two ways: from the gas, sqrt(gas volume / (pi dx)) (the cavity's gas
fills the room the liquid leaves, physics/cavity.py), and from the liquid alone, R_Q^2 = R(0)^2 +
2 int Q dt with Q = r u_r, the flux of the potential flow through the ring 1.8 R0 < r < 2.2 R0
(the liquid's particles there). The two differ by how well the gas tracks the liquid.
"""
from __future__ import annotations

import math

import numpy as np

from rayleigh_plesset import acceleration
from warp_mpm_bubbles import Box, Cylinder, Domain, Material, Output, Scene, SolverSettings
from warp_mpm_bubbles.core.simulation import Simulation

P_ATM = 101325.0
RHO = 1000.0
R0 = 0.01  # m
R_OUT0 = 3.0  # outer radius of the annulus, in R0
P_G0 = 1.0 / P_ATM  # gas at 1 Pa absolute: gauge -101324 Pa
T_UNIT = R0 * math.sqrt(RHO / P_ATM)  # s


def reference_times(radii=(0.5, 0.25), p_g0=P_G0, r_out0=R_OUT0, dt=1e-4) -> dict[float, float]:
    """t / T_UNIT at which the 2D Rayleigh-Plesset radius first falls to each of `radii` (in R0):
    RK4 from rest at R0 (tests/rayleigh_plesset.py's equation), stopped at the smallest radius."""
    f = lambda r, v: acceleration(r, v, p_g0, 2, r_out0)  # noqa: E731
    t, r, v, out = 0.0, 1.0, 0.0, {}
    for target in sorted(radii, reverse=True):
        while r > target:
            k1r, k1v = v, f(r, v)
            k2r, k2v = v + 0.5 * dt * k1v, f(r + 0.5 * dt * k1r, v + 0.5 * dt * k1v)
            k3r, k3v = v + 0.5 * dt * k2v, f(r + 0.5 * dt * k2r, v + 0.5 * dt * k2v)
            k4r, k4v = v + dt * k3v, f(r + dt * k3r, v + dt * k3v)
            r_new = r + dt / 6.0 * (k1r + 2 * k2r + 2 * k3r + k4r)
            v += dt / 6.0 * (k1v + 2 * k2v + 2 * k3v + k4v)
            if r_new <= target:
                out[target] = t + dt * (r - target) / (r - r_new)
            t, r = t + dt, r_new
    return out


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
    """The issue's case: a near-vacuum cavity 1/5 of the depth across, in a 2D tank under gravity.
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
