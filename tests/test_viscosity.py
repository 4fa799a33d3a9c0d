"""Viscosity: a Taylor-Green cell decays at the analytic rate; without viscosity it holds."""

import math

import numpy as np
import pytest
import warp as wp

from warp_mpm_bubbles import Box, Domain, Material, Output, Scene, SolverSettings
from warp_mpm_bubbles.core.simulation import Simulation

wp.config.quiet = True
L, U, N, NU, T_END = 0.1, 0.01, 32, 1e-3, 0.5
DT = (L / N) ** 2 / (4 * NU)  # the explicit viscous limit in 2D, used by both runs


def taylor_green_amplitude(tmp_path, viscosity):
    """u = U sin(pi x/L) cos(pi y/L), v = -U cos(pi x/L) sin(pi y/L) in a full free-slip box, no
    gravity (a steady Euler flow that meets the walls); its amplitude at T_END."""
    scene = Scene(domain=Domain(size=(L, L), cell_size=L / N, gravity=(0.0, 0.0)),
                  materials={"water": Material("water", viscosity=viscosity)},
                  shapes=[Box("water", (0.0, 0.0), (L, L))], solver=SolverSettings(max_dt=DT),
                  output=Output(path=str(tmp_path / "v.usdc")))
    sim = Simulation(scene, "cpu")

    def mode(x):
        kx, ky = np.pi * x[:, 0] / L, np.pi * x[:, 1] / L
        m = np.zeros_like(x)
        m[:, 0], m[:, 1] = np.sin(kx) * np.cos(ky), -np.cos(kx) * np.sin(ky)
        return m

    sim.particles.v = wp.array((U * mode(sim.particles.x.numpy())).astype(np.float32), dtype=wp.vec3, device=sim.device)
    sim.advance_to(T_END)
    p = sim.particles_numpy()
    m = mode(p["positions"])
    return float((p["velocities"] * m).sum() / (m * m).sum()) / U, sim


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    return {mu: taylor_green_amplitude(tmp_path_factory.mktemp(f"tg{mu}"), mu) for mu in (0.0, NU * 1000.0)}


def test_taylor_green_cell_decays_at_the_viscous_rate(runs):
    # Both runs take the same steps, so the transfers' own damping (next test) cancels, and the
    # difference of the decay exponents is the viscous one: 2 nu (pi/L)^2 t = 0.987. Measured
    # +1.08% at 16, 32 and 64 cells (constant: the free-slip wall rows); bound -0.5%..+2.5% (was
    # +-3%), so viscosity x0.97 (-1.9%) or x1.03 (+4.1%) fails.
    (inviscid, _), (viscous, sim) = runs[0.0], runs[1.0]
    expected = 2 * NU * (math.pi / L) ** 2 * T_END
    ratio = math.log(inviscid / viscous) / expected
    print(f"Taylor-Green: viscous decay exponent / 2 nu (pi/L)^2 t = {ratio:.4f}")
    assert 0.995 < ratio < 1.025
    assert "viscosity" in sim.timer.stages_run


def test_inviscid_taylor_green_cell_holds(runs):
    # 205 steps of APIC transfers lose 3.6% of the amplitude here (measured 0.9639; fewer steps,
    # less: 1% in the 4 steps the CFL limit alone would take). Bound 0.95-0.975 (was one-sided,
    # > 0.95, which a velocity gain of 0.2% per step passed at 1.455).
    amplitude, sim = runs[0.0]
    print(f"Taylor-Green, inviscid: amplitude {amplitude:.4f} after {sim.stats.steps} steps")
    assert 0.95 < amplitude < 0.975
    assert "viscosity" not in sim.timer.stages_run
