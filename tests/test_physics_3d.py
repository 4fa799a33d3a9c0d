"""3D checks with power (issue #17): the Laplace jump of a drop and of a bubble against 2 sigma / R,
and a collapsing liquid block that keeps its volume and whose projected velocity is divergence-free
in all three directions. Small grids (16^3-32^3, a few seconds each on Warp's CPU device); every test
prints what it measures, and each bound says where it comes from."""

import math

import numpy as np
import pytest
import warp as wp

from warp_mpm_bubbles import Box, Domain, Material, Output, Scene, SolverSettings, Sphere
from warp_mpm_bubbles.core.grid import FLUID
from warp_mpm_bubbles.core.simulation import Simulation

wp.config.quiet = True
SIGMA, R = 0.072, 0.01
SAMPLES = (0.01, 0.02, 0.03, 0.04, 0.05)  # s: the drop oscillates by about 1%; the mean over these is steady


def laplace_run(tmp_path, cells, bubble):
    """A drop (or a bubble in a liquid ball of radius 2R) at rest without gravity; the interior
    pressure (gas minus liquid for the bubble) over 2 sigma / R at each sample time."""
    L = 0.04 if not bubble else 0.05
    c = (L / 2,) * 3
    materials = {"water": Material("water", surface_tension=SIGMA)}
    shapes = [Sphere("water", c, R)]
    if bubble:
        materials["air"] = Material("air", kind="gas")
        shapes = [Sphere("water", c, 2 * R), Sphere("air", c, R)]
    scene = Scene(domain=Domain(size=(L,) * 3, cell_size=L / cells, gravity=(0.0, 0.0, 0.0)),
                  materials=materials, shapes=shapes, output=Output(path=str(tmp_path / "l.usdc")))
    sim = Simulation(scene, "cpu")
    dx = sim.grid.dx
    r = np.linalg.norm(sim.grid.cell_centres()[sim.grid.interior_slice()] - L / 2, axis=-1)
    ratios, shell = [], []
    for t in SAMPLES:
        sim.advance_to(t)
        p = sim.pressure_numpy()
        inside = p[r < R - 1.5 * dx].mean()
        if bubble:
            liquid = p[(r > R + 1.5 * dx) & (r < 2 * R - 1.5 * dx)].mean()
            ratios.append((inside - liquid) / (2 * SIGMA / R))
            shell.append(liquid / (2 * SIGMA / (2 * R)))
        else:
            ratios.append(inside / (2 * SIGMA / R))
    return sim, np.array(ratios), np.array(shell)


def test_3d_drop_pressure_is_two_sigma_over_r(tmp_path):
    # 24^3, R = 6 cells. Mean over SAMPLES of p_inside / (2 sigma / R), measured (seeds 0-3):
    # 0.9769, 0.9837, 0.9819, 0.9848 (height-function curvature, best-centred columns). Low by 2% at
    # 6 cells per radius; with the grid (the same samples): 0.977, 0.990, 0.993, 0.9955 at 6, 8, 10,
    # 12 cells (uncentred columns, over 0.02-0.2 s: 0.963, 0.979, 0.982, 0.988; div(n) of the smoothed
    # fraction 1.007, 1.000, 0.992, 0.986, away from 1). Bound [0.955, 0.99]: the seeds with 0.5%
    # margin above, and tight enough that sigma x0.97 (-> 0.948) or x1.03 (-> 1.006) fails; the
    # curvature without its z terms gives 0.84.
    sim, ratios, _ = laplace_run(tmp_path, 24, bubble=False)
    print(f"3D drop, 24^3: p_inside / (2 sigma/R) = {np.round(ratios, 4)}, mean {ratios.mean():.4f}")
    assert 0.955 < ratios.mean() < 0.99, ratios
    assert "tension" in sim.timer.phases_run


def test_3d_bubble_jump_is_two_sigma_over_r(tmp_path):
    # 32^3, R = 6.4 cells, the bubble inside a liquid ball of 2R. Mean jump / (2 sigma / R), measured
    # (seeds 0-3): 1.0188, 1.0172, 1.0166, 1.0190 (height-function curvature, best-centred columns).
    # With the grid: 1.059, 1.051, 1.019, 1.012 at 4, 5, 6.4, 8 cells per radius (uncentred columns
    # 1.061, 1.042, 1.011, 1.003; div(n) of the smoothed fraction 1.107, 1.090, 1.067, 1.053). Bound
    # [0.995, 1.03]: the seeds with 1% margin, so sigma x0.97 (-> 0.988) and x1.03 (-> 1.049) fail.
    # The liquid ball sits at its own 2 sigma / (2R): measured 0.983-0.996, bound 5% (a difference of
    # two jumps on the same grid).
    sim, ratios, shell = laplace_run(tmp_path, 32, bubble=True)
    print(f"3D bubble, 32^3: jump / (2 sigma/R) = {np.round(ratios, 4)}, mean {ratios.mean():.4f}; "
          f"liquid / (2 sigma/2R) = {np.round(shell, 4)}")
    assert 0.995 < ratios.mean() < 1.03, ratios
    assert shell.mean() == pytest.approx(1.0, abs=0.05), shell
    # gas films retract at the Taylor-Culick speed of a one-cell film, derived once from sigma and rho
    assert sim.stage("surface_tension").film_speed == pytest.approx(math.sqrt(2 * SIGMA / (1000.0 * sim.grid.dx)), rel=1e-6)


# ---------------------------------------------------- a 3D block collapsing into a corner of its tank
def block_scene(tmp_path, volume_relaxation_time, seed=0):
    """Water 0.04 x 0.05 x 0.04 in the corner of a 0.1 x 0.075 x 0.1 free-slip tank, 16 x 12 x 16
    cells: it spreads along x and z at once, so every axis of the projection is exercised."""
    return Scene(domain=Domain(size=(0.1, 0.075, 0.1), cell_size=0.1 / 16),
                 materials={"water": Material("water")},
                 shapes=[Box("water", (0.0, 0.0, 0.0), (0.04, 0.05, 0.04))],
                 solver=SolverSettings(volume_relaxation_time=volume_relaxation_time, seed=seed),
                 output=Output(path=str(tmp_path / "b.usdc"), fps=60))


def divergence_ratio(sim):
    """max |div u| over fluid cells after the projection, relative to max |dw/dz| there."""
    u, v, w = (a.numpy() for a in sim.fields.vel)
    fluid = sim.fields.types.numpy() == FLUID
    div = (u[1:] - u[:-1]) + (v[:, 1:] - v[:, :-1]) + (w[:, :, 1:] - w[:, :, :-1])
    return np.abs(div[fluid]).max() / np.abs(w[:, :, 1:] - w[:, :, :-1])[fluid].max()


def test_3d_projection_is_divergence_free_in_x_y_and_z(tmp_path):
    # Volume correction off, so the projection's target is exactly div u = 0. Measured: at most
    # 6.7e-6 of the largest dw/dz over 0.1 s (30 steps; the CG tolerance is 1e-5). Bound 1e-3: the
    # z part of the divergence scaled by 0.95 leaves 5e-2.
    sim = Simulation(block_scene(tmp_path, 0.0), "cpu")
    worst = 0.0
    while sim.time < 0.1 - 1e-12:
        sim.advance_to(min(0.1, sim.time + sim.stable_dt()))
        worst = max(worst, divergence_ratio(sim))
    print(f"3D block: max |div u| / max |dw/dz| = {worst:.2e} over {sim.stats.steps} steps")
    assert worst < 1e-3
    assert sim.particles_numpy()["positions"][:, 2].max() > 0.045  # it did spread along z


def test_3d_collapsing_block_keeps_its_volume(tmp_path):
    # Default volume correction (0.01 s). liquid_volume() (sum of min(phi, 1) dx^3) every frame to
    # 0.15 s, the front reaching the far walls at 0.1 s: measured -0.30%..+0.58% (seeds 0-2; the
    # late rise is the thin sheet along the far walls, which min(phi, 1) counts generously).
    # Bound 1% either side.
    sim = Simulation(block_scene(tmp_path, 0.01), "cpu")
    v0 = sim.liquid_volume()
    drift = []
    for _ in range(9):
        sim.advance_frame()
        drift.append(sim.liquid_volume() / v0 - 1.0)
    drift = np.array(drift)
    print(f"3D block: liquid volume drift per frame {np.round(100 * drift, 3)} %")
    assert np.abs(drift).max() < 0.01, drift
