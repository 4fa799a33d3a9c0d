"""Particles sorted by cell (ParticleState.sort_by_cell, every Simulation.sort_every steps): the sort
moves every field with its particle, runs the same on every run, and changes results only by the
float rounding of the transfers' sums in another order."""

import numpy as np
import warp as wp

from scenes import dam_break_2d
from warp_mpm_bubbles import Box, Domain, Material, Output, Scene, SolverSettings
from warp_mpm_bubbles.core.simulation import Simulation

wp.config.quiet = True


def shuffled(sim, seed=1):
    """Every field permuted by one random permutation, as after a long splash has mixed them."""
    p = sim.particles
    perm = np.random.default_rng(seed).permutation(p.count)
    for name, dtype in p.fields.items():
        getattr(p, name)[: p.count].assign(wp.array(p.numpy(name)[perm].copy(), dtype=dtype, device=sim.device))


def by_id(sim):
    """Every field (stages' too) of the particles, in id order."""
    order = np.argsort(sim.particles.numpy("ids"))
    return {name: sim.particles.numpy(name)[order].copy() for name in sim.particles.fields}


def block_3d(tmp_path):
    return Scene(
        name="sort_block",
        domain=Domain(size=(0.25, 0.25, 0.25), cell_size=1.0 / 32.0, walls="free_slip"),
        materials={"water": Material("water")},
        shapes=[Box("water", min=(0.0, 0.0, 0.0), max=(0.125, 0.1875, 0.25))],
        solver=SolverSettings(particles_per_cell=8),
        output=Output(path=str(tmp_path / "b.usdc")),
    )


def cell_index(sim):
    g = sim.grid
    c = np.floor((sim.particles.numpy("x") - np.asarray(g.origin)) / g.dx).astype(np.int64)
    return np.ravel_multi_index(c.T, g.cells)


def test_sort_moves_every_field_with_its_particle(tmp_path):
    sim = Simulation(block_3d(tmp_path), "cpu")
    sim.particles.add_field("tag", wp.vec3)  # a stage's own field moves too
    n = sim.num_particles
    sim.particles.tag[:n].assign(np.random.default_rng(0).random((n, 3)).astype(np.float32))
    for _ in range(2):
        sim.step(sim.stable_dt())  # velocities, C and J of a running state
    shuffled(sim)
    active = sim.particles.numpy("active")
    active[::7] = 0  # some retired particles: they go last
    before = by_id(sim)
    assert (np.diff(cell_index(sim)) < 0).any()  # shuffled: out of cell order

    sim.sort_particles()
    after = by_id(sim)
    assert set(after) == set(before) and len(after["ids"]) == n
    for name in before:
        np.testing.assert_array_equal(after[name], before[name], err_msg=name)
    keys = cell_index(sim)
    live = sim.particles.numpy("active") == 1
    assert (np.diff(keys[live]) >= 0).all()
    assert live[: live.sum()].all() and not live[live.sum():].any()
    # Read-outs stay in id order whatever the memory order.
    assert (np.diff(sim.particles_numpy(include_retired=True)["ids"]) > 0).all()


def run(scene, sort_every, steps=40, shuffle=True):
    sim = Simulation(scene, "cpu")
    sim.sort_every = sort_every
    if shuffle:
        shuffled(sim)
    for _ in range(steps):
        sim.step(sim.stable_dt())
    return sim


def test_sorted_run_is_deterministic_and_close_to_unsorted(tmp_path):
    scene = dam_break_2d(cells_per_a=8, out=tmp_path / "d.usdc")
    a, b, plain = run(scene, 2), run(scene, 2), run(scene, 0)
    assert not (np.diff(a.particles.numpy("ids")) > 0).all()  # memory order changed
    assert (np.diff(plain.particles.numpy("ids")) != 0).all()
    pa, pb, pp = a.particles_numpy(), b.particles_numpy(), plain.particles_numpy()
    for key in pa:
        np.testing.assert_array_equal(pa[key], pb[key], err_msg=key)  # bit-identical on re-run
    np.testing.assert_array_equal(pa["ids"], pp["ids"])
    # Only the order of the float sums differs: float32 rounding. Measured after 40 steps of the
    # collapsing column (512 particles, dx = 12.5 mm, speeds up to 1.9 m/s): positions 1.6e-7 m,
    # velocities 1.5e-6 m/s, J 4.8e-6 apart; the bounds are about 10x that.
    assert 0.0 < np.abs(pa["positions"] - pp["positions"]).max() < 2e-6
    assert np.abs(pa["velocities"] - pp["velocities"]).max() < 2e-5
    assert np.abs(pa["J"] - pp["J"]).max() < 5e-5


def test_advance_to_returns_the_arrays_in_id_order(tmp_path):
    # Between frames a particle keeps its index (code that indexes the arrays across frames relies
    # on it); inside advance_to the steps ran on particles sorted by cell.
    sim = Simulation(dam_break_2d(cells_per_a=8, out=tmp_path / "d.usdc"), "cpu")
    sim.sort_every = 2
    x0 = sim.particles.numpy("x").copy()
    sim.advance_to(0.05)
    assert sim.launches["cell_keys"] >= 2 and sim.launches["id_keys"] == 1
    ids = sim.particles.numpy("ids")
    np.testing.assert_array_equal(ids, np.arange(len(ids)))
    assert np.abs(sim.particles.numpy("x") - x0).max() < 0.05 * 2.5  # each particle near where it started
