"""Fluid sealed off by colliders and walls (core/sealed_regions.py): each region that no free
surface or gas reaches is solved on its own, and a frame that went non-finite stops the run
(exit 1) instead of reaching the writer as an internal error.
"""

import math

import numpy as np
import pytest
import warp as wp

from warp_mpm_bubbles import Box, Domain, Material, Output, Scene
from warp_mpm_bubbles.cli import main
from warp_mpm_bubbles.core import sealed_regions
from warp_mpm_bubbles.core.grid import EMPTY, FLUID, SOLID_NO_SLIP
from warp_mpm_bubbles.core.simulation import Simulation, SimulationError
from warp_mpm_bubbles.io.usd_output import StageWriter
from warp_mpm_bubbles.scene.effects import Collider
from scenes import SMALL_2D

wp.config.quiet = True
G = 9.81


def tank(tmp_path, depth, colliders, size=(0.32, 0.3), dx=0.02, walls="no_slip"):
    return Scene(domain=Domain(size=size, cell_size=dx, walls=walls), materials={"water": Material("water")},
                 shapes=[Box("water", (0.0, 0.0), (size[0], depth))], colliders=colliders,
                 output=Output(path=str(tmp_path / "s.usdc"), fps=60))


def rod_over_glass():
    """A rod on the right wall over a glass's wall: between them and the wall, a pocket of two cells."""
    return [Collider("cylinder", center=(0.32, 0.096), radius=0.05, length=0.092, axis="x"),
            Collider("glass", center=(0.235, 0.0), radius=0.07, height=0.065, wall_thickness=0.023)]


def region_counts(sim):
    """(regions, sealed regions) of the last step's pressure system, as the solve read them."""
    row = sim.fields.counters.numpy()
    return int(row[sealed_regions.SLOT_REGIONS]), int(row[sealed_regions.SLOT_SEALED])


def run_to(sim, t_end):
    while sim.time < t_end - 1e-12:
        sim.advance_to(min(t_end, sim.time + sim.stable_dt()))


@pytest.mark.parametrize("moves", ["positions", "velocities"])
def test_pocket_in_a_tank_full_to_the_lid_stays_at_rest(tmp_path, moves):
    # Nothing moves and nothing enters: the water must stay at rest. With one projection for the
    # whole system the pocket took a share of the main region's mean and the water reached 6 m/s
    # in the first step (then a CFL step of 1e-7 s). Where the volume correction moves positions
    # (the default) the seeding's drift moves no velocity: measured 2.6e-7 m/s with the rod alone,
    # 1.0e-6 with the pocket; bound 1e-5. Moving velocities the tank with the rod alone settles
    # from the seeding at a few cm/s, and the pocket must add nothing to that.
    speeds = []
    for colliders in (rod_over_glass()[:1], rod_over_glass()):
        scene = tank(tmp_path, 0.3, colliders)
        scene.solver.volume_correction_moves = moves
        sim = Simulation(scene, "cpu")
        run_to(sim, 3 / 60)
        p = sim.particles_numpy()
        assert np.isfinite(p["velocities"]).all() and sim.stats.cg_unconverged == 0
        speeds.append(np.abs(p["velocities"]).max())
    assert region_counts(sim) == (2, 2)
    print(f"{moves}: fastest particle, rod alone {speeds[0]:.2e} m/s, rod and pocket {speeds[1]:.2e} m/s")
    if moves == "positions":
        assert speeds[1] < 1e-5 and speeds[0] < 1e-5
    else:
        assert speeds[1] < 1.1 * speeds[0] < 0.05


def test_pocket_beside_a_free_surface_is_solved_on_its_own(tmp_path):
    # Water to 0.28: the main region reaches the air (pinned), the pocket does not.
    sim = Simulation(tank(tmp_path, 0.28, rod_over_glass()), "cpu")
    run_to(sim, 2 / 60)
    assert region_counts(sim) == (2, 1)
    assert sim.stats.cg_unconverged == 0
    assert np.abs(sim.particles_numpy()["velocities"]).max() < 0.1


@pytest.mark.parametrize("rod", [False, True])
def test_closed_tank_is_one_sealed_region(tmp_path, rod):
    # The closed tank keeps the solver's projection (singular=True): no region is settled apart.
    # Without colliders nothing inside the domain can seal a region off, so none is labelled.
    colliders = rod_over_glass()[:1] if rod else []
    sim = Simulation(tank(tmp_path, 0.3, colliders, size=(0.32, 0.3), dx=0.02, walls="free_slip"), "cpu")
    singular, solve = [], sim.solver.solve
    sim.solver.solve = lambda *args, **kwargs: singular.append(kwargs["singular"]) or solve(*args, **kwargs)
    sim.step(sim.stable_dt())
    assert singular and set(singular) == {True}  # the step's solve, and the shift's when positions move
    if rod:
        assert region_counts(sim) == (1, 1)
    else:
        assert sim.sealed is None and not any(k in sim.launches for k in ("start_labels", "count_regions"))


@pytest.mark.parametrize("motion", [{"acceleration": (0.0, -G), "stop": 0.043}, {"velocity": (0.0, -0.05)}])
def test_ball_moving_into_a_corner(tmp_path, motion):
    # A ball a quarter cell from both walls seals the corner cell and squeezes it: no incompressible
    # solution there. The pocket is compressed evenly instead (its mean divergence), not NaN.
    scene = tank(tmp_path, 0.075, [Collider("sphere", center=(0.0139, 0.0139), radius=0.0116, **motion)],
                 size=(0.16, 0.13), dx=0.01, walls="free_slip")
    sim = Simulation(scene, "cpu")
    run_to(sim, 3 / 60)
    p = sim.particles_numpy()
    assert np.isfinite(p["positions"]).all() and np.isfinite(p["velocities"]).all()
    assert sim.stats.cg_unconverged == 0
    # The ball reaches 0.42 m/s: the water it pushes moves at most a few times that.
    assert np.abs(p["velocities"]).max() < 2.0


def test_non_finite_frame_is_a_simulation_error(tmp_path):
    writer = StageWriter(str(tmp_path / "w.usdc"), fps=30, materials=[("water", (0.2, 0.4, 0.9))], particle_radius=0.01)
    pos, vel = np.zeros((3, 3), np.float32), np.zeros((3, 3), np.float32)
    ids, mat = np.arange(3), np.zeros(3, np.int32)
    with writer:
        writer.write_frame(0, pos, vel, ids, mat)
        vel[1, 2] = np.nan
        with pytest.raises(SimulationError,
                           match=r"velocities contains NaN or inf \(1 of 3 particles\).*\[solver\]\.cfl"):
            writer.write_frame(1, pos, vel, ids, mat)
        assert writer.last_frame == 0


def test_run_that_goes_non_finite_stops_with_exit_1(tmp_path, monkeypatch, capsys):
    # Whatever makes a frame non-finite, the run stops by name (exit 1) and keeps the frames before.
    out = tmp_path / "nan.usdc"
    (tmp_path / "nan.toml").write_text(SMALL_2D.format(out=out.as_posix(), frames=3))
    real = Simulation.particles_numpy

    def poisoned(self, *args, **kwargs):
        p = real(self, *args, **kwargs)
        if self.frame == 2:
            p["velocities"][0, 0] = np.inf
        return p

    monkeypatch.setattr(Simulation, "particles_numpy", poisoned)
    assert main(["run", str(tmp_path / "nan.toml"), "--quiet"]) == 1
    err = capsys.readouterr().err
    assert "velocities contains NaN or inf" in err and "frames 0-1 are written and kept" in err


def reference_regions(types, weights, extra, dim):
    """(regions, sealed regions) of a random system by a plain flood fill: cells joined by faces of
    weight; a region is pinned by a gas term or a face of weight to a cell that is not fluid."""
    fluid = types == FLUID
    seen = np.zeros(types.shape, bool)
    regions = sealed = 0
    for start in map(tuple, np.argwhere(fluid)):
        if seen[start]:
            continue
        regions += 1
        pinned, stack, seen[start] = False, [start], True
        while stack:
            c = stack.pop()
            pinned |= extra[c] > 0
            for a in range(dim):
                for side in (0, 1):
                    n, f = list(c), list(c)
                    n[a] += 2 * side - 1
                    f[a] += side
                    n, f = tuple(n), tuple(f)
                    if weights[a][f] <= 0:
                        continue
                    if not fluid[n]:
                        pinned = True
                    elif not seen[n]:
                        seen[n] = True
                        stack.append(n)
        sealed += not pinned
    return regions, sealed


def serpentine(shape, rng):
    """A corridor winding through walls at every other x, open at alternate ends, and a pocket."""
    types = np.full(shape, FLUID)
    for i in range(2, shape[0] - 2, 2):
        types[i] = SOLID_NO_SLIP
        types[i, 2 if i % 4 else shape[1] - 3] = FLUID
    types[1, 2] = SOLID_NO_SLIP  # the corner cell (1, 1): a pocket
    return types


def random_maze(shape, rng):
    return rng.choice([FLUID, EMPTY, SOLID_NO_SLIP], size=shape, p=[0.62, 0.01, 0.37])


@pytest.mark.parametrize("dim,seed,maze", [(2, 0, random_maze), (2, 1, random_maze), (3, 2, random_maze),
                                           (3, 3, random_maze), (2, 4, serpentine)])
def test_region_counts_match_a_flood_fill(tmp_path, dim, seed, maze):
    # Random cell types and face weights, and a winding corridor (which needs more than the two
    # rounds of sweeps a step does without a read): the device's counts against a flood fill.
    size = (0.16, 0.12, 0.1)[:dim]
    scene = Scene(domain=Domain(size=size, cell_size=0.01), materials={"water": Material("water")},
                  shapes=[Box("water", (0.0,) * dim, tuple(s / 2 for s in size))],
                  output=Output(path=str(tmp_path / "r.usdc")))
    sim = Simulation(scene, "cpu")
    sim.sealed = sealed_regions.SealedRegions(sim.grid.cells, sim.device)  # the labelling, on made-up mazes
    sim.region.whole_grid()
    rng = np.random.default_rng(seed)
    shape = sim.grid.cells
    interior = np.zeros(shape, bool)
    interior[tuple(slice(1, n - 1) if n > 1 else slice(None) for n in shape)] = True
    types = np.where(interior, maze(shape, rng), SOLID_NO_SLIP)
    weights = []  # random, some zero; none on a face of a solid cell (as the grid stage leaves them)
    for a, arr in enumerate(sim.fields.inv_rho):
        solid = np.ones(arr.shape, bool)
        if a < dim:
            pad = np.pad(types == SOLID_NO_SLIP, [(1, 1) if k == a else (0, 0) for k in range(3)], constant_values=True)
            solid = np.take(pad, range(arr.shape[a]), axis=a) | np.take(pad, range(1, arr.shape[a] + 1), axis=a)
        cut = rng.random(arr.shape) >= 0.9 if maze is random_maze else False
        weights.append(np.where(solid | cut, 0.0, 1.0).astype(np.float32))
    extra = np.where(rng.random(shape) < (0.002 if maze is random_maze else 0.0), 1.0, 0.0).astype(np.float32)
    f = sim.fields
    f.types.assign(types.astype(np.int32))
    for w, arr in zip(weights, f.inv_rho):
        arr.assign(w)
    f.extra_diag.assign(extra)
    f.counters.zero_()
    sim.sealed.count(sim, f)
    row = f.counters.numpy().copy()  # on the CPU a view, which finish_labels rewrites
    got = (int(row[sealed_regions.SLOT_REGIONS]), int(row[sealed_regions.SLOT_SEALED]))
    if row[sealed_regions.SLOT_UNSETTLED]:
        got = sim.sealed.finish_labels(sim, f.types, f.inv_rho, f.extra_diag, f.counters)
    expected = reference_regions(types, weights, extra, dim)
    if maze is serpentine:
        assert row[sealed_regions.SLOT_UNSETTLED] and expected == (3, 3)  # the corridor, column 1, the pocket
    else:  # sealed and pinned regions, several of each
        assert expected[1] > 2 and expected[0] > expected[1]
    assert got == expected


def test_collider_pushed_into_a_full_closed_box_stops_the_run(tmp_path):
    # A piston 0.04 m wide entering a closed box full of water at 0.2 m/s pushes in 0.008 m^2/s
    # (80 cells a second) that the water has no room for: the run stops once 5% of the fluid's
    # cells have been pushed in, naming what to change, instead of squeezing the water to 0.43.
    piston = Collider("box", center=(0.05, 0.12), size=(0.04, 0.06), velocity=(0.0, -0.2), stop=0.1)
    sim = Simulation(tank(tmp_path, 0.1, [piston], size=(0.1, 0.1), dx=0.01, walls="free_slip"), "cpu")
    with pytest.raises(SimulationError, match=r"colliders have pushed .* into liquid that fills a closed region.*"
                                              r"\[domain\]\.walls.*\[colliders\.N\]\.stop"):
        run_to(sim, 0.1)
    assert 0.04 < sim.time < 0.08
    # The booking is the piston's swept volume (the faces around the sealed water telescope to it).
    assert sim.sealed.squeezed.numpy()[0] / 1000 == pytest.approx(80 * sim.time, rel=0.02)
