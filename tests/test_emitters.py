"""Emitters (issue #4): emitted mass matches the set rate, and runs with emitters stay
deterministic and resumable (their progress is part of the checkpoint)."""

import math

import numpy as np
import pytest
import warp as wp

from warp_mpm_bubbles import Box, Domain, Material, Output, Scene, SceneError
from warp_mpm_bubbles.io.checkpoint import load_checkpoint, save_checkpoint
from warp_mpm_bubbles.io.runner import RunResult, summary
from warp_mpm_bubbles.scene.effects import GasInjector, LiquidInflow
from warp_mpm_bubbles.core.simulation import Simulation

wp.config.quiet = True
DX = 0.01


def scene(tmp_path, emitters, dim=2):
    size = (0.3, 0.3) if dim == 2 else (0.2, 0.2, 0.2)
    floor = (0.0,) * dim
    top = (size[0], 0.1) + ((size[2],) if dim == 3 else ())
    return Scene(domain=Domain(size=size, cell_size=DX),
                 materials={"water": Material("water"), "air": Material("air", kind="gas")},
                 shapes=[Box("water", floor, top)], emitters=emitters,
                 output=Output(path=str(tmp_path / "e.usdc"), fps=30))


def emitted(sim, n0, material):
    p = sim.particles_numpy(include_retired=True)
    new = np.arange(len(p["mass"])) >= n0
    return p["mass"][new & (p["material"] == material)].astype(np.float64).sum()


@pytest.mark.parametrize("dim", [2, 3])
def test_stream_mass_matches_the_set_rate(tmp_path, dim):
    r, speed = 0.02, 1.5
    centre = (0.15, 0.25) if dim == 2 else (0.1, 0.18, 0.1)
    direction = (0.0, -1.0) + ((0.0,) if dim == 3 else ())
    sim = Simulation(scene(tmp_path, [LiquidInflow("water", centre, direction, r, speed, stop=0.1)], dim), "cpu")
    n0 = sim.num_particles
    sim.advance_to(0.15)  # the stream runs for 0.1 s of it
    rate = sim.scene.emitters[0].volume_rate * (DX if dim == 2 else 1.0) * 1000.0  # kg/s (2D: one-cell slab)
    layer = rate * (DX / sim.scene.solver.particles_per_cell ** (1 / dim)) / speed  # mass of one layer
    # Layers are emitted whole: the total is the rate times the duration, short by under one layer
    # (1e-6: particle masses are float32).
    assert rate * 0.1 - layer <= emitted(sim, n0, 0) <= rate * 0.1 * (1 + 1e-6)


def test_air_stone_releases_bubbles_at_the_set_rate(tmp_path):
    rate, r = 40.0, 0.012
    sim = Simulation(scene(tmp_path, [GasInjector("air", (0.15, 0.03), rate=rate, radius=r)]), "cpu")
    n0 = sim.num_particles
    sim.advance_to(0.2)
    bubbles = math.floor(rate * 0.2 + 1e-9)  # 8: the 8th is due exactly at 0.2 s
    # Each bubble's particles share its disk's volume (one-cell slab), at the gas's rest density.
    expected = bubbles * 1.2 * math.pi * r * r * DX
    assert emitted(sim, n0, 1) == pytest.approx(expected, rel=1e-6)
    assert sim.gas_budget()["total"] == pytest.approx(expected, rel=1e-6)


def test_runs_with_emitters_resume_to_the_same_state(tmp_path):
    emitters = [LiquidInflow("water", (0.1, 0.25), (0.3, -1.0), 0.015, 1.0),
                GasInjector("air", (0.2, 0.03), rate=30.0, radius=0.011, radius_spread=0.3, spread=0.02)]
    straight = Simulation(scene(tmp_path, emitters), "cpu")
    for _ in range(4):
        straight.advance_frame()
    first = Simulation(scene(tmp_path, emitters), "cpu")
    for _ in range(2):
        first.advance_frame()
    save_checkpoint(first, tmp_path / "ck.npz")
    resumed = Simulation(scene(tmp_path, emitters), "cpu")
    load_checkpoint(resumed, tmp_path / "ck.npz")
    for _ in range(2):
        resumed.advance_frame()
    a, b = straight.particles_numpy(True), resumed.particles_numpy(True)
    assert straight.num_particles > first.num_particles  # both emitters kept emitting after the save
    for key in ("positions", "velocities", "material", "mass"):
        np.testing.assert_array_equal(a[key], b[key])
    np.testing.assert_array_equal(straight.stage("emitters").state.inflow, resumed.stage("emitters").state.inflow)


def test_a_submerged_nozzle_delivers_what_the_water_lets_in(tmp_path):
    """A nozzle under water, 3 m/s into a tank with an open side: laying every layer into cells
    already full crowded the liquid into 0.86 of its rest volume; the stream delivers only where
    its cells have room, and the ledger and the summary say how much less than it owed."""
    sc = Scene(domain=Domain(size=(0.1, 0.1), cell_size=DX, walls={"x_max": "open"}),
               materials={"water": Material("water")}, shapes=[Box("water", (0.0, 0.0), (0.1, 0.07))],
               emitters=[LiquidInflow("water", (0.03, 0.04), (0.0, -1.0), 0.015, 3.0)],
               output=Output(path=str(tmp_path / "s.usdc"), fps=30))
    sim = Simulation(sc, "cpu")
    seeded = sim.ledger.liquid_added
    while sim.time < 0.1:
        sim.advance_to(sim.time + 0.01)
        rest = sim.particles_numpy()["mass"].astype(np.float64).sum() / 1000.0
        assert sim.liquid_volume() >= 0.9 * rest, (sim.time, sim.liquid_volume() / rest)
    owed, delivered = sim.stage("emitters").state.inflow[0]
    h = DX / sim.scene.solver.particles_per_cell ** 0.5
    assert owed == pytest.approx(sim.stage("emitters").state.progress[0, 1] * 2 * 0.015 * h * DX)  # every layer owed
    assert 0.0 < delivered < 0.5 * owed
    # The mass ledger counts only what entered (float32 particle masses).
    assert sim.ledger.liquid_added - seeded == pytest.approx(1000.0 * delivered, rel=1e-5)
    text = summary(RunResult(sim, str(tmp_path / "s.usdc"), 3, 1.0))
    assert f"[emitters.0] delivered {100 * delivered / owed:.0f}% of its stream" in text


@pytest.mark.parametrize("emitter, words", [
    (LiquidInflow("air", (0.1, 0.2), (0.0, -1.0), 0.01, 1.0), ["[emitters.0].material", "'air'", "liquid"]),
    (LiquidInflow("water", (0.1, 0.5), (0.0, -1.0), 0.01, 1.0), ["[emitters.0].center", "outside the domain"]),
    (LiquidInflow("water", (0.1, 0.2), (0.0, 0.0), 0.01, 1.0), ["[emitters.0].direction", "zero"]),
    (LiquidInflow("water", (0.1, 0.2), (0.0, -1.0), 0.01, -1.0), ["[emitters.0].speed", "> 0"]),
    (GasInjector("air", (0.1, 0.1), rate=5.0, radius=0.004), ["[emitters.0].radius", "subgrid_bubbles"]),
    (GasInjector("air", (0.1, 0.1), rate=5.0, radius=0.02, start=1.0, stop=0.5), ["[emitters.0].stop", "> 1"]),
])
def test_bad_emitters_are_refused_by_name(tmp_path, emitter, words):
    with pytest.raises(SceneError) as err:
        scene(tmp_path, [emitter]).validate()
    for w in words:
        assert w in str(err.value)


@pytest.mark.parametrize("emitter, words", [
    (GasInjector("air", (0.1, 0.1), rate=5.0, radius=50.0), ["[emitters.0].radius", "<= 0.15"]),
    (GasInjector("air", (0.1, 0.1), rate=1e12, radius=0.02), ["[emitters.0].rate", "<= 100000"]),
    (GasInjector("air", (0.1, 0.1), rate=5.0, radius=0.02, spread=10.0), ["[emitters.0].spread", "<= 0.15"]),
    (LiquidInflow("water", (0.1, 0.2), (1e200, 0.0), 0.01, 1.0), None),  # valid: huge but finite
    (LiquidInflow("water", (0.1, 0.2), (1e-200, 1e-200), 0.01, 1.0), None),  # valid: tiny but not zero
])
def test_emitter_sizes_and_rates_are_bounded(tmp_path, emitter, words):
    if words is None:
        assert scene(tmp_path, [emitter]).validate().emitters[0].direction[0] > 0.7
        return
    with pytest.raises(SceneError) as err:
        scene(tmp_path, [emitter]).validate()
    for w in words:
        assert w in str(err.value)
