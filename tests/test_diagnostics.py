"""The phase-leak metric on hand-made particle sets whose answer is known."""

import numpy as np

from warp_mpm_bubbles.diagnostics import bubble_volumes, gas_centroid_and_diameter, phase_leak

DX = 0.1
CELLS = (20, 20, 1)


def block(lo, hi, per_axis=2):
    """Particles on a lattice filling the 2D box [lo, hi) (z at mid-slab), per_axis^2 per cell."""
    h = DX / per_axis
    xs = np.arange(lo[0] + h / 2, hi[0], h)
    ys = np.arange(lo[1] + h / 2, hi[1], h)
    x, y = np.meshgrid(xs, ys, indexing="ij")
    return np.column_stack([x.ravel(), y.ravel(), np.full(x.size, DX / 2)])


def scene(extra_liquid=None):
    """A 0.8 x 0.8 gas square in the middle of a 2 x 2 liquid domain."""
    liquid = block((0, 0), (2, 2))
    gas = block((0.6, 0.6), (1.4, 1.4))
    keep = ~((liquid[:, 0] > 0.6) & (liquid[:, 0] < 1.4) & (liquid[:, 1] > 0.6) & (liquid[:, 1] < 1.4))
    parts = [liquid[keep], gas] + ([np.array([extra_liquid])] if extra_liquid is not None else [])
    pos = np.concatenate(parts)
    is_gas = np.zeros(len(pos), bool)
    is_gas[keep.sum():keep.sum() + len(gas)] = True
    return pos, is_gas, np.full(len(pos), DX * DX / 4 * DX)


def test_separated_phases_do_not_leak():
    pos, is_gas, vol = scene()
    assert phase_leak(pos, is_gas, vol, DX, CELLS, 2) == {"liquid_in_gas": 0.0, "gas_in_liquid": 0.0}


def test_a_liquid_particle_deep_in_the_bubble_is_a_leak():
    pos, is_gas, vol = scene(extra_liquid=(1.0, 1.0, DX / 2))
    leak = phase_leak(pos, is_gas, vol, DX, CELLS, 2)
    assert np.isclose(leak["liquid_in_gas"], vol[0] / vol[is_gas].sum())
    assert leak["gas_in_liquid"] == 0.0


def test_a_liquid_particle_on_the_interface_is_not_counted():
    pos, is_gas, vol = scene(extra_liquid=(0.62, 1.0, DX / 2))
    assert phase_leak(pos, is_gas, vol, DX, CELLS, 2)["liquid_in_gas"] == 0.0


def test_centroid_and_equivalent_diameter():
    pos, is_gas, vol = scene()
    centroid, d_e = gas_centroid_and_diameter(pos, is_gas, vol / DX, 2)
    np.testing.assert_allclose(centroid[:2], (1.0, 1.0))
    assert np.isclose(d_e, 2 * np.sqrt(0.64 / np.pi))


def test_bubble_volumes_counts_separate_bubbles():
    pos, is_gas, vol = scene()
    second = block((0.1, 0.1), (0.3, 0.3))  # a second, smaller gas square far from the first
    inside = (pos[:, 0] > 0.1) & (pos[:, 0] < 0.3) & (pos[:, 1] > 0.1) & (pos[:, 1] < 0.3)
    pos = np.concatenate([pos[~inside], second])
    is_gas = np.concatenate([is_gas[~inside], np.ones(len(second), bool)])
    vol = np.full(len(pos), vol[0])
    volumes = bubble_volumes(pos, is_gas, vol, DX, CELLS, 2)
    np.testing.assert_allclose(volumes, [0.64 * DX, 0.04 * DX])  # areas 0.8^2 and 0.2^2, slab DX thick


def test_void_cells_are_empty_cells_not_open_to_the_air():
    from warp_mpm_bubbles.core.grid import EMPTY, FLUID, SOLID_FREE_SLIP
    from warp_mpm_bubbles.diagnostics import void_cells

    # A closed 2D tank (ghost layer solid), 10 x 10 interior cells, up = +y, water to y = 6.
    types = np.full((12, 12, 1), SOLID_FREE_SLIP, np.int32)
    types[1:11, 1:11] = EMPTY
    types[1:11, 1:7] = FLUID
    ghost, up = (1, 1, 0), (1, 1)
    assert void_cells(types, ghost, up) == 0  # the air above the surface is open
    types[3:5, 2:4] = EMPTY  # a 2 x 2 hole under water
    types[8, 3] = EMPTY  # one more, apart
    assert void_cells(types, ghost, up) == 5
    types[8, 3:7] = EMPTY  # that one now reaches the air above: a dimple, not a void
    assert void_cells(types, ghost, up) == 4
    types[1:11, 7:11] = FLUID  # filled tank: every empty cell is a void
    assert void_cells(types, ghost, up) == 8
    types[0, 3] = EMPTY  # an opening in the left wall (its ghost cell empty), not yet reached
    assert void_cells(types, ghost, up) == 8
    types[1:3, 3] = EMPTY  # a channel from that opening to the 2 x 2 hole: the hole drains to the air
    assert void_cells(types, ghost, up) == 4  # the column at x = 8 is left


def test_a_filled_tank_and_a_free_surface_tank_have_no_voids(tmp_path):
    import warp as wp

    from scenes import tank_2d
    from warp_mpm_bubbles.core.simulation import Simulation
    from warp_mpm_bubbles.diagnostics import void_cells

    wp.config.quiet = True
    for depth in (0.5, 1.0):
        sim = Simulation(tank_2d(cells=16, depth=depth, out=tmp_path / "t.usdc"), "cpu")
        for _ in range(3):
            sim.step(sim.stable_dt())
        assert void_cells(sim.fields.types.numpy(), sim.grid.ghost, sim.up) == 0, depth
