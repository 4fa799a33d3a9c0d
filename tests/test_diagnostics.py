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
