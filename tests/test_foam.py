"""Foam at the free surface (issue #4, item 2): gas reaching open air becomes foam that rides the
surface, lives an exponential lifetime and bursts; on Warp's CPU device."""

import math

import numpy as np
import pytest
import warp as wp
from pxr import Usd, UsdGeom

from warp_mpm_bubbles import Box, Domain, Material, Output, Scene, SolverSettings, Sphere
from warp_mpm_bubbles.core.grid import PHASE_FOAM, PHASE_GAS, PHASE_LIQUID
from warp_mpm_bubbles.io.runner import run_scene
from warp_mpm_bubbles.scene.effects import Foam
from warp_mpm_bubbles.core.simulation import Simulation
from warp_mpm_bubbles.io.usd_output import INSTANCER, read_frames

wp.config.quiet = True
FOAM_KERNELS = {"advance_foam", "gas_to_foam", "splat_foam", "drain_columns", "gather_foam"}
AIR_AND_WATER = lambda: {"water": Material("water"), "air": Material("air", kind="gas")}  # noqa: E731


# ------------------------------------------ a layer of gas on the water: foam at once, then bursts
TAU = 0.1  # s, mean lifetime
W, H, DX = 0.2, 0.03, 0.2 / 64  # tank width, water depth, cell size


def layer_scene(tmp_path, frames=4, fps=30.0):
    """Water H deep with a gas layer 4 cells thick on it: 64 x 4 cells x 4 particles = 1024 become foam."""
    return Scene(
        domain=Domain(size=(W, 0.05), cell_size=DX),
        materials=AIR_AND_WATER(),
        shapes=[Box("water", min=(0.0, 0.0), max=(W, H)), Box("air", min=(0.0, H), max=(W, H + 4 * DX))],
        solver=SolverSettings(particles_per_cell=4),
        output=Output(path=str(tmp_path / "layer.usdc"), frames=frames, fps=fps),
        effects={"foam": Foam(lifetime=TAU)},
    )


@pytest.fixture(scope="module")
def layer(tmp_path_factory):
    sim = Simulation(layer_scene(tmp_path_factory.mktemp("foam")), "cpu")
    n = sim.num_particles
    budget0 = sim.gas_budget()
    gas0 = int((sim.particles.phase.numpy()[:n] == PHASE_GAS).sum())
    birth, death = np.full(n, np.nan), np.full(n, np.nan)
    times, alive, totals, heights = [], [], [], []
    while sim.time < 4 * TAU:
        sim.advance_to(sim.time + sim.stable_dt() * 0.9999)  # one step at a time
        phase, active = sim.particles.phase.numpy()[:n], sim.particles.active.numpy()[:n]
        birth[(phase == PHASE_FOAM) & np.isnan(birth)] = sim.time
        death[(phase == PHASE_FOAM) & (active == 0) & np.isnan(death)] = sim.time
        times.append(sim.time)
        alive.append(((phase == PHASE_FOAM) & (active == 1)).sum())
        totals.append(sim.gas_budget()["total"])
        heights.append(sim.particles.x.numpy()[:n][(phase == PHASE_FOAM) & (active == 1), 1].copy())
    return dict(sim=sim, n=n, gas0=gas0, birth=birth, death=death, t=np.array(times), alive=np.array(alive),
                totals=np.array(totals), heights=heights, budget0=budget0)


def test_gas_in_open_air_becomes_foam(layer):
    # Row by row, one step each: measured 88% of the layer in the first 4 steps (32 ms), 95% by 0.4 s.
    # The rest (50 of 1034) was pushed into the top liquid cell of its column and surfaces slowly:
    # the vent test (shared with the vent stage, which leaves the same particles there) takes gas
    # strictly above the highest liquid cell.
    sim, n, birth = layer["sim"], layer["n"], layer["birth"]
    born = ~np.isnan(birth)
    assert (birth[born] < 0.035).sum() >= 0.85 * layer["gas0"] > 850
    assert born.sum() >= 0.92 * layer["gas0"]
    left = (sim.particles.phase.numpy()[:n] == PHASE_GAS) & (sim.particles.active.numpy()[:n] == 1)
    assert born.sum() + left.sum() == layer["gas0"]
    top_cell = math.floor(H / DX)  # the top water row: the ceiling of every column
    assert (np.floor(sim.particles.x.numpy()[:n][left, 1] / DX) == top_cell).all()


def test_foam_counts_follow_the_set_lifetime(layer):
    # Each foam particle lives L ~ Exp(TAU) from its birth (the end of the step that made it), and
    # bursts in the first step that ends after birth + L; counted at step ends, a particle is alive
    # exactly when t - birth < L, so the expected count is sum exp(-(t - birth)/TAU) with binomial
    # variance sum p (1 - p). Bound: 4 standard deviations at every step (counting statistics);
    # measured at most 1.9 over 54 steps.
    birth, t, alive = layer["birth"], layer["t"], layer["alive"]
    born = birth[~np.isnan(birth)]
    checked = 0
    for tk, nk in zip(t, alive):
        p = np.exp(-(tk - born[born <= tk]) / TAU)
        expected, sd = p.sum(), math.sqrt((p * (1 - p)).sum())
        if expected > 5:
            assert abs(nk - expected) <= 4 * sd, (tk, nk, expected, sd)
            checked += 1
    assert checked >= 30
    # The decay it implies: maximum-likelihood mean lifetime, each burst known to a step (its interval's
    # midpoint), the survivors censored at the end. Standard error TAU/sqrt(bursts) = 3.2% (956 bursts);
    # bound 4 of them. Measured 0.0990 s (-1.0%).
    death = layer["death"]
    burst = ~np.isnan(death)
    steps = np.diff(np.concatenate([[0.0], t]))
    step_of = np.searchsorted(t, death[burst])
    lived = (death[burst] - 0.5 * steps[step_of] - birth[burst]).sum()
    survivors = ~np.isnan(birth) & ~burst
    tau_hat = (lived + (t[-1] - birth[survivors]).sum()) / burst.sum()
    assert tau_hat == pytest.approx(TAU, rel=4 / math.sqrt(burst.sum())), (tau_hat, burst.sum())


@wp.kernel
def _exponential_draws(seed: int, ids: wp.array(dtype=wp.int64), mean: float, out: wp.array(dtype=float)):
    p = wp.tid()
    state = wp.rand_init(seed, int(ids[p]))  # the hash effects/foam.py documents: (scene seed, particle id)
    out[p] = -mean * wp.log(1.0 - wp.randf(state))


def test_each_foam_particle_lives_its_own_drawn_lifetime(layer):
    # Issue #17: the lifetime statistics above cannot see a 10% error in the mean lifetime (their
    # bound is 4 standard errors, 12.9%). Each particle's lifetime is a deterministic draw from
    # (seed, id), so it is checked one by one: a particle born at the end of a step bursts in the
    # first step that ends at or after birth + L (its clock runs down by dt each step). Measured:
    # every one of the bursts inside that window (to float32 rounding of the clock); bound: all of
    # them, with 1e-6 s of slack. The mean lifetime 10% (or 3%) off moves most of them out.
    sim, birth, death, t = layer["sim"], layer["birth"], layer["death"], layer["t"]
    n = layer["n"]
    ids = wp.array(sim.particles.ids.numpy()[:n], dtype=wp.int64, device="cpu")
    drawn = wp.zeros(n, dtype=float, device="cpu")
    wp.launch(_exponential_draws, n, inputs=[int(sim.scene.solver.seed) & 0x7FFFFFFF, ids, TAU, drawn], device="cpu")
    life = drawn.numpy().astype(np.float64)
    burst = ~np.isnan(death)
    steps = np.diff(np.concatenate([[0.0], t]))
    step_of = np.searchsorted(t, death[burst])
    due = birth[burst] + life[burst]
    inside = (death[burst] >= due - 1e-6) & (death[burst] - steps[step_of] < due + 1e-6)
    print(f"foam: {inside.sum()} of {burst.sum()} bursts in the step their drawn lifetime ends")
    assert burst.sum() > 500
    assert inside.all(), np.flatnonzero(~inside)[:10]
    survivors = ~np.isnan(birth) & ~burst
    assert np.all(birth[survivors] + life[survivors] > t[-1] - 1e-6)  # and none of the living is overdue


def test_foam_rides_the_surface(layer):
    # The gas layer started up to 4 cells above the water; foam settles where the interpolated liquid
    # fraction is 1/2 (the fraction taken over non-solid cells, so beside the walls too), the water's
    # surface (H; the tank is at rest, its surface within +-0.5 cell of H). Measured within 0.52 cell
    # of H from 0.07 s on; bound one cell.
    for tk, y in zip(layer["t"], layer["heights"]):
        if tk > 0.07 and len(y):
            assert np.abs(y - H).max() < DX, (tk, (y.min() - H) / DX, (y.max() - H) / DX)


def test_gas_mass_is_conserved_exactly_through_foam_and_bursting(layer):
    b0, sim = layer["budget0"], layer["sim"]
    np.testing.assert_allclose(layer["totals"], b0["total"], rtol=1e-12, atol=0.0)
    b = sim.gas_budget()
    assert b["inside"] + b["foam"] + b["vented"] == pytest.approx(b0["total"], rel=1e-12, abs=0.0)
    # After 4 mean lifetimes: measured 92.5% burst, 2.7% still foam, 4.8% gas that never left the
    # top liquid cell (see test_gas_in_open_air_becomes_foam).
    assert b["vented"] > 0.9 * b0["total"] and 0.0 < b["foam"] < 0.05 * b0["total"]


# ------------------------------------------------------------------ foam on/off: only the gas changes
def bubble_scene(tmp_path, foam: bool):
    """An 8 mm bubble 1.5 cm under the surface of a 2D tank: it surfaces after ~0.1 s."""
    return Scene(
        domain=Domain(size=(0.1, 0.1), cell_size=0.1 / 32),
        materials=AIR_AND_WATER(),
        shapes=[Box("water", min=(0.0, 0.0), max=(0.1, 0.06)), Sphere("air", center=(0.05, 0.045), radius=0.008)],
        solver=SolverSettings(particles_per_cell=4),
        output=Output(path=str(tmp_path / "b.usdc")),
        effects={"foam": Foam(lifetime=0.05)} if foam else {},
    )


def test_foam_on_changes_only_what_becomes_of_the_surfaced_gas(tmp_path):
    # Foam is one-way coupled and stays out of the CFL limit, so the liquid, and every gas particle
    # still under water, evolves bit for bit as without foam; the particles the vent stage retires
    # without foam are exactly those that became foam with it. Measured at 0.2 s (79 steps): 68
    # particles foamed, 50 of them already burst.
    runs = {}
    for foam in (False, True):
        sim = runs[foam] = Simulation(bubble_scene(tmp_path, foam), "cpu")
        budget0 = sim.gas_budget()
        sim.advance_to(0.2)
    off, on = runs[False], runs[True]
    n = off.num_particles
    assert on.num_particles == n and on.stats.dt_history == off.stats.dt_history
    phase_on, phase_off = on.particles.phase.numpy()[:n], off.particles.phase.numpy()[:n]
    active_off = off.particles.active.numpy()[:n]
    foamed = phase_on == PHASE_FOAM
    vented = (phase_off == PHASE_GAS) & (active_off == 0)
    assert foamed.sum() > 20 and np.array_equal(foamed, vented)
    same = ~foamed  # the liquid and the gas still under water
    assert (phase_on[same] != PHASE_FOAM).all() and (phase_on[same] == PHASE_LIQUID).sum() > 0
    for name in ("x", "v", "J", "C", "active", "material"):
        assert np.array_equal(on.particles.numpy(name)[same], off.particles.numpy(name)[same]), name
    assert (on.particles.material.numpy()[:n][foamed] == list(on.scene.materials).index("foam")).all()
    # The gas's mass: foam plus burst on one side, vented on the other; both totals exact.
    b_on, b_off = on.gas_budget(), off.gas_budget()
    assert b_on["foam"] > 0.0 and b_on["vented"] > 0.0 and b_off["foam"] == 0.0
    assert b_on["foam"] + b_on["vented"] == pytest.approx(b_off["vented"], rel=1e-12, abs=0.0)
    assert b_on["total"] == pytest.approx(budget0["total"], rel=1e-12, abs=0.0)
    # Launches: foam's kernels only when asked, and then no vent kernel.
    assert not FOAM_KERNELS & set(off.launches) and "vent_exposed_gas" in off.launches
    assert FOAM_KERNELS <= set(on.launches) and "vent_exposed_gas" not in on.launches
    assert "foam" in on.timer.phases_run and "vent" not in on.timer.phases_run


def test_foam_in_a_liquid_only_scene_launches_nothing(tmp_path):
    scene = Scene(domain=Domain(size=(0.1, 0.1), cell_size=0.1 / 16), materials={"water": Material("water")},
                  shapes=[Box("water", min=(0.0, 0.0), max=(0.1, 0.05))], output=Output(path=str(tmp_path / "l.usdc")),
                  effects={"foam": Foam()})
    sim = Simulation(scene, "cpu")
    for _ in range(3):
        sim.step(sim.stable_dt())
    assert not FOAM_KERNELS & set(sim.launches) and not sim.has_gas


# ------------------------------------------------------------------------------------- USD output
def test_foam_is_written_as_its_own_prototype_with_its_own_radius(tmp_path):
    scene = layer_scene(tmp_path, frames=2, fps=100.0)
    result = run_scene(scene, device="cpu", progress=False)
    names = list(scene.materials)
    stage = Usd.Stage.Open(result.stage_path)
    protos = UsdGeom.PointInstancer.Get(stage, INSTANCER).GetPrototypesRel().GetTargets()
    assert [p.name for p in protos] == names == ["water", "air", "foam"]
    frame = read_frames(result.stage_path)["frames"][2]
    sim = result.simulation
    p = sim.particles_numpy()
    is_foam = frame["proto_indices"] == names.index("foam")
    assert is_foam.sum() == (p["phase"] == PHASE_FOAM).sum() > 0
    # Foam: the sphere of its own gas volume (2D particles hold dx^3/ppc: r = 0.39 dx); water keeps
    # the output radius.
    np.testing.assert_allclose(frame["scales"][is_foam, 0], np.cbrt(0.75 / np.pi * p["volume"][is_foam]), rtol=1e-6)
    water = frame["proto_indices"] == names.index("water")
    assert np.all(frame["scales"][water] == np.float32(scene.output.particle_radius))
    assert frame["extent"][1][1] >= (frame["positions"][:, 1] + frame["scales"][:, 0]).max() - 1e-7
