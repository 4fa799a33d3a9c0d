"""Bubbles of many sizes: entrained sub-grid bubbles drawn from a log-normal radius distribution,
each rising at its own drag law's terminal speed, and written to USD with its own radius, on
Warp's CPU device."""

import math

import numpy as np
import pytest
import warp as wp

from warp_mpm_bubbles.core.grid import PHASE_SUBGRID
from warp_mpm_bubbles.core.simulation import Simulation
from warp_mpm_bubbles import Box, SceneError
from warp_mpm_bubbles.scene.effects import Entrainment, SubgridBubbles

from benchmarks.cases import subgrid_tank

wp.config.quiet = True


def entraining_splash(tmp_path, spread):
    """benchmarks.cases.splash_scene with a denser seeding (more bubbles to measure sizes on)."""
    effects = {"subgrid_bubbles": SubgridBubbles(),
               "entrainment": Entrainment(rate=5000.0, min_speed=0.5, bubble_radius_spread=spread)}
    block = Box("water", min=(0.04, 0.045), max=(0.06, 0.065), velocity=(0.0, -2.0))
    return subgrid_tank(tmp_path, depth=0.03, shapes=[block], effects=effects)


def seeded_radii(sim, t_end):
    """The radius of every bubble entrainment seeded until t_end, from its rest volume as seeded."""
    radii = []
    stage = sim.stage("entrainment")
    while sim.time < t_end:
        n0, seeded = sim.num_particles, stage.seeded
        sim.advance_to(sim.time + sim.stable_dt() * 0.9999)  # one step
        vol0 = sim.particles.vol0.numpy()[n0: n0 + stage.seeded - seeded].astype(np.float64)
        radii.append(np.cbrt(0.75 * vol0 / math.pi))
    return np.concatenate(radii)


def test_entrained_bubbles_draw_log_normal_radii_and_their_gas_is_booked_exactly(tmp_path):
    sims, radii = [], []
    for _ in range(2):
        sim = Simulation(entraining_splash(tmp_path, 0.4), "cpu")
        before = sim.gas_budget()["total"]
        radii.append(seeded_radii(sim, 0.03))
        sims.append(sim)
    sim, r = sims[0], radii[0]
    s = sim.scene.effects["entrainment"]
    median, cap = s.bubble_radius, sim.scene.effects["subgrid_bubbles"].radius
    n = len(r)
    assert n >= 80 and n == sim.stage("entrainment").seeded
    # ln r is normal (mean ln median, sd 0.4) cut at 3 sd and at the sub-grid radius (here 2x the
    # median, 1.7 sd: the cut holds 4.2% of the draws at the cap). Bounds: 4 standard errors.
    ln = np.log(r / median)
    assert r.min() >= median * math.exp(-3 * 0.4) * (1 - 1e-6) and r.max() <= cap * (1 + 1e-6)
    assert abs(np.median(ln)) < 4 * 1.25 * 0.4 / math.sqrt(n)
    uncut = ln[r < cap * (1 - 1e-6)]
    assert 0.3 < uncut.std() < 0.45  # the uncut part of N(0, 0.4) (sd 0.37 for this cut)
    assert 0.01 < np.mean(r >= cap * (1 - 1e-6)) < 0.1
    # The air the seeds took from the atmosphere is booked with their own masses: the total holds.
    assert sim.gas_budget()["total"] == pytest.approx(before, rel=1e-9, abs=1e-15)
    # Draws are seeded (scene seed, step): the run repeats bit for bit.
    assert np.array_equal(radii[0], radii[1])
    m = sim.num_particles
    assert sims[1].num_particles == m
    assert np.array_equal(sims[1].particles.x.numpy()[:m], sim.particles.x.numpy()[:m])


def test_without_a_spread_every_entrained_bubble_has_the_median_radius(tmp_path):
    sim = Simulation(entraining_splash(tmp_path, 0.0), "cpu")
    r = seeded_radii(sim, 0.015)
    assert len(r) > 10
    assert np.all(r == r[0]) and r[0] == pytest.approx(sim.scene.effects["entrainment"].bubble_radius, rel=1e-6)


@pytest.mark.parametrize("value, words", [(-0.1, ">= 0"), (1.5, "<= 1"), ("wide", "got str")])
def test_a_bad_radius_spread_is_refused_by_name(tmp_path, value, words):
    with pytest.raises(SceneError) as e:
        entraining_splash(tmp_path, value).validate()
    assert "[effects.entrainment].bubble_radius_spread" in str(e.value) and words in str(e.value)
