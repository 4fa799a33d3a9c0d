"""Surface tension: the Laplace pressure jump (docs/design.md#tension), spurious currents, and that the stage
runs only when a scene asks for it. 2D, 8 cells per radius, water-air sigma, no gravity."""

import math

import numpy as np
import pytest
import warp as wp

from warp_mpm_bubbles import Cylinder, Domain, Material, Output, Scene
from warp_mpm_bubbles.core.simulation import Simulation

wp.config.quiet = True
SIGMA, R = 0.072, 0.01
CAPILLARY_SPEED = math.sqrt(SIGMA / (1000.0 * R))  # 85 mm/s: the speed scale of capillary motion


def settle(scene, until=0.06, every=0.005):
    sim = Simulation(scene, "cpu")
    speeds, pressures = [], []
    while sim.time < until - 1e-12:
        sim.advance_to(sim.time + every)
        speeds.append(np.linalg.norm(sim.particles_numpy()["velocities"], axis=1).max())
        pressures.append(sim.pressure_numpy()[:, :, 0].copy())  # (a view of the solver's array)
    size = scene.domain.size[0]
    centres = sim.grid.cell_centres()[sim.grid.interior_slice()][:, :, 0, :2]
    return sim, np.linalg.norm(centres - size / 2, axis=-1), np.array(speeds), np.array(pressures)


@pytest.fixture(scope="module")
def drop(tmp_path_factory):
    L = 0.04
    scene = Scene(domain=Domain(size=(L, L), cell_size=R / 8, gravity=(0.0, 0.0)),
                  materials={"water": Material("water", surface_tension=SIGMA)},
                  shapes=[Cylinder("water", center=(L / 2, L / 2), radius=R)],
                  output=Output(path=str(tmp_path_factory.mktemp("drop") / "d.usdc")))
    return settle(scene, until=0.12)  # two capillary times: the currents' growth is judged past the start-up


@pytest.fixture(scope="module")
def bubble(tmp_path_factory):
    L, r_out = 0.1, 0.04
    scene = Scene(domain=Domain(size=(L, L), cell_size=R / 8, gravity=(0.0, 0.0)),
                  materials={"water": Material("water", surface_tension=SIGMA), "air": Material("air", kind="gas")},
                  shapes=[Cylinder("water", center=(L / 2, L / 2), radius=r_out),
                          Cylinder("air", center=(L / 2, L / 2), radius=R)],
                  output=Output(path=str(tmp_path_factory.mktemp("bubble") / "b.usdc")))
    return (*settle(scene), r_out)


def test_drop_pressure_is_laplace(drop):
    # p_inside = sigma / R in 2D, at the end (t = 0.12 s). Measured -1.35% at 8 cells per radius
    # (seeds 1-3: -0.29%, +1.35%, +1.48%; height-function curvature from best-centred columns); bound
    # 2.5%, so sigma x0.97 fails (-4.4%). With the grid (mean of t = 0.1-0.2 s): -1.5%, +0.8%, -0.8%
    # at 8, 16, 32 cells per radius; uncentred columns read -1.5%, -1.6%, -2.0% (away), div(n) of the
    # smoothed fraction +1.0%, -1.8%, -5.2%. sigma x1.03 is caught by test_bubble_pressure_jump_is_laplace
    # and tests/test_physics_3d.py.
    sim, r, _, _ = drop
    inside = sim.pressure_numpy()[:, :, 0][r < R - 2 * sim.grid.dx].mean()
    print(f"2D drop: p_inside / (sigma/R) = {inside / (SIGMA / R):.4f}")
    assert inside == pytest.approx(SIGMA / R, rel=0.025)


def test_drop_spurious_currents_are_small_and_not_growing(drop):
    # Measured 14 mm/s at most, 17% of the capillary speed (seeds 1-3: up to 28%; uncentred columns
    # 20%, div(n) 18-37%); bound 25%, and the last third of the run no faster than the first: 10.0
    # against 13.5 mm/s (they do not grow). Over the first 0.06 s alone the two thirds were 14.1 and
    # 13.5: the start-up is no calmer than the settling, so the run is two capillary times long.
    _, _, speeds, _ = drop
    assert speeds.max() < 0.25 * CAPILLARY_SPEED
    n = len(speeds) // 3
    assert speeds[-n:].max() <= speeds[:n].max() * 1.05


def test_bubble_pressure_jump_is_laplace(bubble):
    # Gas minus liquid = sigma / R0, the mean over the run's second half (t = 0.035-0.06 s; single
    # samples move by up to 6% as the bubble breathes). Measured +1.17% (seeds 1-3: +0.49%, +0.87%,
    # +2.10%; uncentred columns +0.22%, -1.33%, -1.43%, +1.60%; div(n) +3.4% to +4.1% on every seed);
    # bound 2.5%, so sigma x1.03 fails (+4.1%); x0.97 (-1.9%) is caught by the drop and the 3D tests.
    # The liquid disc itself sits at sigma / R_out (its own surface's jump; measured -4.3%; seeds
    # 1-3: -2.1%, -6.5%, -0.6%; docs/convergence.md, "The curvature estimate"); bound 10%: a
    # difference of two jumps on the same grid.
    sim, r, _, pressures, r_out = bubble
    late = pressures[len(pressures) // 2:].mean(axis=0)
    dx = sim.grid.dx
    gas = late[r < R - 2 * dx].mean()
    liquid = late[(r > R + 2 * dx) & (r < r_out - 2 * dx)].mean()
    print(f"2D bubble: jump / (sigma/R) = {(gas - liquid) / (SIGMA / R):.4f}, liquid / (sigma/R_out) = "
          f"{liquid / (SIGMA / r_out):.4f}")
    assert (gas - liquid) / (SIGMA / R) == pytest.approx(1.0, abs=0.025)
    assert liquid == pytest.approx(SIGMA / r_out, rel=0.10)


def test_bubble_spurious_currents_decay(bubble):
    _, _, speeds, _, _ = bubble
    # measured 40 mm/s during the initial compression (seeds 1-3: 22-25; uncentred columns 30, div(n) 40)
    assert speeds.max() < 0.5 * CAPILLARY_SPEED
    assert speeds[-3:].max() < 0.3 * CAPILLARY_SPEED  # measured 21 mm/s once settled (seeds 1-3: 12-15)


def test_tension_runs_only_when_asked_and_limits_the_step(drop, tmp_path):
    sim, _, _, _ = drop
    assert "tension" in sim.timer.phases_run
    dx = sim.grid.dx
    assert max(sim.stats.dt_history) <= math.sqrt(1000.0 * dx**3 / (4 * math.pi * SIGMA)) * (1 + 1e-9)
    plain = Scene(domain=Domain(size=(0.04, 0.04), cell_size=R / 8, gravity=(0.0, 0.0)),
                  materials={"water": Material("water")},
                  shapes=[Cylinder("water", center=(0.02, 0.02), radius=R)],
                  output=Output(path=str(tmp_path / "p.usdc")))
    other = Simulation(plain, "cpu")
    other.step(other.stable_dt())
    assert "tension" not in other.timer.phases_run


def test_gas_films_retract_into_the_bubble_beside_them():
    # The sub-cell part of surface tension (physics/tension.retract_gas_films), on a hand-made 2D grid
    # of fluid cells whose left half is gas: a gas particle in a liquid cell next to the gas, on the
    # liquid's side of the interface, moves towards it by min(sqrt(2 sigma / (rho dx)) dt, dx/4); a
    # gas particle with no gas cell in its 3x3 neighbourhood, one on the gas's side of the interface
    # (the resolved bubble, in the cell the interface crosses), and any liquid particle stay.
    from warp_mpm_bubbles.core.geometry import GridGeometry
    from warp_mpm_bubbles.core.grid import FLUID, PHASE_GAS, PHASE_LIQUID
    from warp_mpm_bubbles.core.kernel_args import CellPhases, Particles
    from warp_mpm_bubbles.physics.tension import Films, retract_gas_films

    dx, n = 0.001, 8
    types = np.full((n, n, 1), FLUID, dtype=np.int32)
    phase = np.full((n, n, 1), PHASE_LIQUID, dtype=np.int32)
    phase[:4] = PHASE_GAS
    gas_volume = np.where(phase == PHASE_GAS, dx**3, 0.0).astype(np.float32)
    # The level set: -1 in the gas, +1 in the liquid, 0.2 in column 4, which the interface crosses:
    # linear between the centres, it is 0 at x = 3.5 + 1/1.2 = 4.33 cells.
    level = np.where(phase == PHASE_GAS, -1.0, 1.0).astype(np.float32)
    level[4] = 0.2
    x = np.array([[4.45, 4.5, 0.5], [7.5, 4.5, 0.5], [4.3, 2.5, 0.5], [4.2, 5.5, 0.5]], dtype=np.float32) * dx
    particle_phase = np.array([PHASE_GAS, PHASE_GAS, PHASE_LIQUID, PHASE_GAS], dtype=np.int32)
    speed = math.sqrt(2.0 * SIGMA / (1000.0 * dx))  # 0.38 m/s: a one-cell film's Taylor-Culick speed
    geo = GridGeometry()
    geo.origin, geo.dx, geo.dim, geo.domain_hi = wp.vec3(0.0), dx, 2, wp.vec3(n * dx, n * dx, dx)
    films = Films()
    films.cells = CellPhases()
    films.cells.types, films.cells.phase = wp.array(types, device="cpu"), wp.array(phase, device="cpu")
    films.gas_volume, films.level = wp.array(gas_volume, device="cpu"), wp.array(level, device="cpu")
    films.capillary_speed = speed
    for dt, expected in ((1.0e-4, speed * 1.0e-4), (1.0e-2, 0.25 * dx)):
        xs = wp.array(x, dtype=wp.vec3, device="cpu")
        particles = Particles()
        particles.x, particles.phase = xs, wp.array(particle_phase, device="cpu")
        particles.active = wp.ones(len(x), dtype=wp.int32, device="cpu")
        wp.launch(retract_gas_films, len(x), device="cpu", inputs=[
            0, dt, geo, films, wp.full((n, n, 1), 9, dtype=wp.int32, device="cpu"),  # every cell keeps a particle
            wp.zeros((n, n, 1), dtype=wp.int32, device="cpu"), wp.zeros((n, n, 1), dtype=wp.int32, device="cpu"),
            particles])
        moved = xs.numpy() - x
        # the pull points at the gas-weighted centroid of the gas cells (3, 3..5): straight to -x
        assert moved[0, 0] == pytest.approx(-expected, rel=1e-4) and abs(moved[0, 1]) < 1e-9
        assert np.all(moved[1:] == 0.0)
