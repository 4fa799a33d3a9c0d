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


@pytest.mark.parametrize("r0", [1.0e-4, 3.0e-4, 1.0e-3])
def test_each_size_rises_at_its_own_drag_law_terminal_speed(tmp_path, r0):
    # One sub-grid bubble in a quiet 2D tank (32 cells of 3.1 mm, water's viscosity 1e-3 Pa s) at three
    # radii across the drag law: 0.1 mm (U_t = 1.6 cm/s, Re = 3.2, near Stokes: Schiller-Naumann's
    # correction 0.15 Re^0.687 is 34%), 0.3 mm (6.7 cm/s, Re = 40) and 1 mm (0.21 m/s, Re = 416).
    # The law is Schiller & Naumann (1933), C_D = 24/Re (1 + 0.15 Re^0.687) below Re = 1000, a rigid
    # sphere (effects/subgrid.py says why); the reference is that law's force balance at the bubble's
    # measured J. Slip (rise speed minus the liquid's velocity where the drag was computed), measured:
    # -1.7e-5, -1.8e-4, -2.6e-4 of it; bound 1e-3. With C_D 3% too large the slips were -2.5%, -2.0%
    # and -1.8% off. The rise itself adds the liquid the bubble drags along (2D: +2.3% at 1 mm).
    from test_subgrid import AIR, rise, terminal_speed

    sim = Simulation(subgrid_tank(tmp_path, effects={"subgrid_bubbles": SubgridBubbles()}), "cpu")
    i = sim.stage("subgrid_bubbles").add_bubbles(sim.ctx, np.array([[0.05, 0.01]]), np.array([r0]),
                                                 np.zeros((1, 2)), AIR).start
    t, y, J, u_l = rise(sim, i, 0.3)
    window = t >= 0.1  # relaxation m_eff / k: 1 ms (0.1 mm) to 12 ms (1 mm)
    speed = np.polyfit(t[window], y[window], 1)[0]
    reference = terminal_speed(r0 * np.cbrt(J[window].mean()))
    slip = speed - u_l[window].mean()
    print(f"r0 {r0:g}: U_t {reference:.5g}, slip {slip:.5g} ({slip / reference - 1:+.2e}), rise {speed:.5g}")
    assert slip == pytest.approx(reference, rel=1e-3)


def test_the_usd_file_gives_each_bubble_its_own_radius(tmp_path):
    # A run of the splash written to USD: each sub-grid bubble's instance `scales` is the radius of
    # its own volume (as the simulation held it when the frame was written), so a render shows the
    # drawn sizes; the other particles (liquid, resolved gas) keep the output radius. Read back from
    # the file, by particle id.
    from warp_mpm_bubbles.core.grid import sphere_radius
    from warp_mpm_bubbles.io.runner import run_scene
    from warp_mpm_bubbles.io.usd_output import read_frames

    scene = entraining_splash(tmp_path, 0.4)
    scene.output.fps, scene.output.frames = 100.0, 4  # about 40 bubble instances (28-32 in the first 3 frames)
    held = {}

    def remember(sim):
        p = sim.particles_numpy()
        bubbles = p["phase"] == PHASE_SUBGRID
        held[sim.frame] = dict(zip(p["ids"][bubbles].tolist(), sphere_radius(p["volume"][bubbles]).tolist()))

    run_scene(scene, device="cpu", progress=False, on_frame=remember)
    frames = read_frames(scene.output.path)["frames"]
    written, own, liquid = [], [], []
    for frame in (1, 2, 3, 4):
        f = frames[frame]
        assert np.all(f["scales"][:, 0] == f["scales"][:, 1]) and np.all(f["scales"][:, 1] == f["scales"][:, 2])
        scales = dict(zip(f["ids"].tolist(), f["scales"][:, 0].tolist()))
        written += [scales[i] for i in held[frame]]
        own += list(held[frame].values())
        liquid += [s for i, s in scales.items() if i not in held[frame]]
    written, own = np.array(written), np.array(own)
    assert len(own) >= 30
    np.testing.assert_allclose(written, own, rtol=1e-6)
    # The drawn spread shows: log-normal, median 1.56 mm, sd 0.4, cut at the 3.1 mm sub-grid radius.
    print(f"{len(own)} bubble instances, radii {written.min():.3g}..{written.max():.3g} m, sd ln {np.log(written).std():.3f}")
    assert written.max() > 2.0 * written.min() and 0.2 < np.log(written).std() < 0.5
    assert np.all(np.array(liquid) == np.float32(scene.output.particle_radius))


def test_a_gas_injector_releases_sub_grid_bubbles_of_the_sizes_it_draws(tmp_path):
    # An air stone whose bubbles (median 1 mm, radius_spread 0.4) are under the sub-grid radius
    # (one 3.1 mm cell): each becomes one sub-grid bubble holding its drawn volume (2D: the disk's
    # through the one-cell slab, pi r^2 dx), so their sizes follow the emitter's own draws, one by
    # one (seeded by scene seed, emitter and count: effects/emitters.py).
    from warp_mpm_bubbles.scene.effects import GasInjector

    scene = subgrid_tank(tmp_path, effects={"subgrid_bubbles": SubgridBubbles()})
    scene.emitters = [GasInjector("air", (0.05, 0.01), rate=100.0, radius=1.0e-3, radius_spread=0.4, spread=0.02)]
    sim = Simulation(scene, "cpu")
    sim.advance_to(0.2)
    p = sim.particles_numpy()
    bubbles = p["phase"] == PHASE_SUBGRID
    order = np.argsort(p["ids"][bubbles])
    vol0 = sim.particles.vol0.numpy()[: sim.num_particles][bubbles][order].astype(np.float64)
    n = len(vol0)
    assert n == 20 and sim.stage("subgrid_bubbles").conversions["gathered"] == 0
    drawn = np.array([1.0e-3 * math.exp(0.4 * np.random.default_rng([scene.solver.seed, 0, k]).standard_normal())
                      for k in range(n)])
    np.testing.assert_allclose(vol0, math.pi * drawn**2 * scene.domain.cell_size, rtol=1e-6)
    assert drawn.max() > 2.0 * drawn.min()


def test_a_resumed_run_draws_the_same_sizes(tmp_path):
    # The draws are keyed by (scene seed, step), both restored from a checkpoint, so a run resumed
    # mid-splash seeds bubbles of the same sizes as one that never stopped.
    from warp_mpm_bubbles.io.checkpoint import load_checkpoint, save_checkpoint

    a = Simulation(entraining_splash(tmp_path, 0.4), "cpu")
    a.advance_to(0.012)
    save_checkpoint(a, tmp_path / "c.npz")
    b = Simulation(entraining_splash(tmp_path, 0.4), "cpu")
    load_checkpoint(b, tmp_path / "c.npz")
    seeded = a.stage("entrainment").seeded
    for sim in (a, b):
        sim.advance_to(0.03)
    assert a.stage("entrainment").seeded > seeded + 20  # seeds drawn after the resume
    n = a.num_particles
    assert b.num_particles == n and b.gas_budget() == a.gas_budget()
    for name in ("x", "vol0", "mass"):
        assert np.array_equal(a.particles.numpy(name), b.particles.numpy(name)), name
