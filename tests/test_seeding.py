"""Particle seeding: counts, placement, material overrides, determinism, volumes."""
import math

import numpy as np
import pytest

from warp_mpm_bubbles.scene.model import (
    Box, Cylinder, Domain, Material, Output, Scene, SceneError, SolverSettings, Sphere,
)
from warp_mpm_bubbles.core.seeding import seed_particles, slab_samples, sub_cells_per_axis


@pytest.fixture(autouse=True)
def in_tmp(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)  # the default output path is relative


def make(size, h, shapes, ppc=None, seed=0, materials=("a", "b")):
    return Scene(Domain(size, h), {m: Material(m) for m in materials}, list(shapes),
                 solver=SolverSettings(particles_per_cell=ppc, seed=seed), output=Output("out.usdc"))


def test_box_count_2d():
    scene = make((0.4, 0.2), 0.02, [Box("a", (0.04, 0.02), (0.14, 0.12))])
    p = seed_particles(scene)
    assert len(p["positions"]) == 4 * 5 * 5  # ppc * cells inside the box
    assert {k: (v.dtype, v.shape[1:]) for k, v in p.items()} == {
        "positions": (np.float32, (3,)), "velocities": (np.float32, (3,)),
        "material": (np.int32, ()), "volume": (np.float32, ()), "pressure": (np.float32, ())}


@pytest.mark.parametrize("ppc", [1, 5, 8, 27])
def test_box_count_3d(ppc):
    box = Box("a", (0.05, 0.0, 0.025), (0.15, 0.1, 0.2))
    p = seed_particles(make((0.2, 0.2, 0.2), 0.025, [box], ppc=ppc))
    assert len(p["positions"]) == ppc * 4 * 4 * 7
    assert np.all(box.contains(p["positions"]))


def test_whole_domain_count_and_volume():
    scene = make((0.4, 0.2, 0.1), 0.02, [Box("a", (0, 0, 0), (0.4, 0.2, 0.1))])
    p = seed_particles(scene)
    assert len(p["positions"]) == 8 * 20 * 10 * 5
    assert p["volume"].astype(np.float64).sum() == pytest.approx(0.4 * 0.2 * 0.1, rel=1e-6)


def test_stratified_one_sample_per_sub_cell():
    # ppc = 5 in 2D: k = 3 sub-cells per axis, 5 of the 9 chosen, never twice the same
    p = slab_samples(Domain((0.08, 0.08), 0.02), 5, 0, 2)
    assert p.shape == (4 * 5, 2)
    assert np.all((p[:, 0] >= 0.04) & (p[:, 0] < 0.06))
    sub = np.floor(p / (0.02 / 3)).astype(int)  # global sub-cell index per axis
    for cell in sub.reshape(4, 5, 2):
        assert len({tuple(s) for s in cell}) == 5


def test_sub_cells_per_axis():
    assert [sub_cells_per_axis(n, 3) for n in (1, 8, 9, 27, 64)] == [1, 2, 3, 3, 4]
    assert [sub_cells_per_axis(n, 2) for n in (1, 4, 5, 9)] == [1, 2, 3, 3]


def test_positions_inside_shapes_and_domain_2d():
    shapes = [Sphere("a", (0.1, 0.1), 0.07), Cylinder("b", (0.3, 0.1), 0.05)]
    scene = make((0.4, 0.2), 0.01, shapes)
    p = seed_particles(scene)
    pos = p["positions"]
    assert np.all(pos[:, 2] == np.float32(0.5 * 0.01))  # 2D slab, exactly mid-cell
    assert np.all((pos[:, :2] >= 0) & (pos[:, :2] <= [0.4, 0.2]))
    for i, shape in enumerate(shapes):
        assert np.all(shape.contains(pos[p["material"] == i]))
    assert np.all(shapes[0].contains(pos) | shapes[1].contains(pos))


def test_later_shape_overrides_earlier():
    box = Box("a", (0.0, 0.0, 0.0), (0.2, 0.2, 0.2), velocity=(1.0, 0.0, 0.0))
    ball = Sphere("b", (0.1, 0.1, 0.1), 0.05, velocity=(0.0, 2.0, 0.0))
    p = seed_particles(make((0.2, 0.2, 0.2), 0.02, [box, ball]))
    assert len(p["positions"]) == 8 * 10**3  # carved, not duplicated
    in_ball = ball.contains(p["positions"])
    assert np.all(p["material"][in_ball] == 1) and np.all(p["material"][~in_ball] == 0)
    assert np.all(p["velocities"][in_ball] == [0, 2, 0]) and np.all(p["velocities"][~in_ball] == [1, 0, 0])
    ball_volume = p["volume"][in_ball].astype(np.float64).sum()
    assert ball_volume == pytest.approx(4 / 3 * math.pi * 0.05**3, rel=0.05)


def test_deterministic_and_seed_dependent():
    shapes = [Sphere("a", (0.1, 0.1), 0.06)]
    a = seed_particles(make((0.2, 0.2), 0.01, shapes, seed=1))
    b = seed_particles(make((0.2, 0.2), 0.01, shapes, seed=1))
    c = seed_particles(make((0.2, 0.2), 0.01, shapes, seed=2))
    for k in a:
        np.testing.assert_array_equal(a[k], b[k])
    assert len(a["positions"]) != len(c["positions"]) or not np.array_equal(a["positions"], c["positions"])


def test_order_is_cell_major():
    p = seed_particles(make((0.1, 0.1), 0.02, [Box("a", (0, 0), (0.1, 0.1))]))
    cell = np.floor(p["positions"][:, :2] / 0.02).astype(int)
    flat = cell[:, 0] * 5 + cell[:, 1]
    assert np.all(np.diff(flat) >= 0) and np.all(np.bincount(flat) == 4)


def test_volume_sums_to_box_volume_2d():
    h = 0.02
    p = seed_particles(make((0.4, 0.2), h, [Box("a", (0.1, 0.0), (0.3, 0.1))]))
    assert np.all(p["volume"] == np.float32(h**3 / 4))
    assert p["volume"].astype(np.float64).sum() == pytest.approx(0.2 * 0.1 * h, rel=1e-6)  # one cell thick


def test_validation_zero_particle_check_matches_seeding():
    # validation's zero-particle check uses exactly the samples the seeding makes
    accepted = refused = 0
    for r in np.linspace(0.001, 0.008, 8):
        for cx in (0.1, 0.105, 0.113):
            scene = make((0.2, 0.2), 0.02, [Sphere("a", (cx, 0.1), r)])
            try:
                scene.validate()
            except SceneError:
                refused += 1
                continue
            accepted += 1
            assert len(seed_particles(scene)["positions"]) >= 1
    assert accepted and refused
