"""Host round trips inside a step (issue #13, item 4; docs/host_syncs.md), counted on the CPU
device: there a read costs nothing, but each is what a GPU would wait for."""

import numpy as np
import pytest
import warp as wp

from warp_mpm_bubbles import Box, Domain, Material, Output, Scene, SolverSettings, Sphere
from warp_mpm_bubbles.core.host_reads import HostReads
from warp_mpm_bubbles.core.grid import PHASE_GAS, PHASE_SUBGRID
from warp_mpm_bubbles.core.simulation import Simulation
from warp_mpm_bubbles.core.threads import CACHE_LINE_FLOATS
from warp_mpm_bubbles.effects.subgrid import CANDIDATE_COLUMNS
from warp_mpm_bubbles.io.checkpoint import load_checkpoint, save_checkpoint
from warp_mpm_bubbles.scene.effects import Collider, Entrainment, Foam, GasInjector, LiquidInflow, SubgridBubbles

from benchmarks.cases import splash_scene

wp.config.quiet = True
SOLVER_MODULES = ("core.pressure", "core.multigrid")  # CG: the convergence work's (branch active), bounded here
# The step's own reads: the solve's cell counts with the non-finite count (3 ints in a cache line per
# part of the system's assembly: one part a CPU thread), and the read-back at its end, the fastest
# particle with entrainment's count, the gas's two step measures and whether a cavity may exist
# (5 floats).
STEP_READS = 2


def step_elements(sim):
    return CACHE_LINE_FLOATS * sim.parallel.threads + 5


def liquid_scene(tmp_path):
    return Scene(domain=Domain(size=(0.1, 0.1), cell_size=0.1 / 24), materials={"water": Material("water")},
                 shapes=[Box("water", (0.0, 0.0), (0.05, 0.07))], solver=SolverSettings(particles_per_cell=4),
                 output=Output(path=str(tmp_path / "l.usdc")))


def full_scene(tmp_path):
    """All eight optional stages (benchmarks/performance/compile_time.py's scene, smaller); conversions every 2 steps."""
    return Scene(
        domain=Domain(size=(0.1, 0.1), cell_size=0.1 / 24),
        materials={"water": Material("water", surface_tension=0.072, viscosity=1.0e-3),
                   "air": Material("air", kind="gas", viscosity=1.8e-5)},
        shapes=[Box("water", (0.0, 0.0), (0.1, 0.05)), Sphere("air", center=(0.03, 0.02), radius=0.01),
                Box("water", (0.06, 0.06), (0.08, 0.08), velocity=(0.0, -2.0))],
        effects={"foam": Foam(), "subgrid_bubbles": SubgridBubbles(convert_every=2),
                 "entrainment": Entrainment(rate=1000.0, min_speed=0.5)},
        emitters=[LiquidInflow("water", center=(0.02, 0.09), direction=(0.0, -1.0), radius=0.005, speed=1.0),
                  GasInjector("air", center=(0.08, 0.01), rate=200.0, radius=0.002, spread=0.005)],
        colliders=[Collider("sphere", center=(0.05, 0.085), radius=0.006, velocity=(0.0, -0.5), stop=0.02)],
        solver=SolverSettings(particles_per_cell=4),
        output=Output(path=str(tmp_path / "f.usdc"), frames=10),  # the pour fills the box in 14 frames
    )


def counted_steps(sim, steps):
    """One advance_to per step (stable_dt included): yields its host reads and CG iterations and solves."""
    for _ in range(steps):
        iterations, solves = sim.stats.cg_iterations, sim.stats.cg_solves
        with sim.count_host_reads() as reads:
            sim.advance_to(sim.time + sim.stable_dt() * 0.9999)
        yield reads, sim.stats.cg_iterations - iterations, sim.stats.cg_solves - solves


def assert_solver_within_bound(reads, iterations, solves):
    # Today's PCG reads two sums per iteration and one per V-cycle, six more per solve: the
    # bound holds as the convergence work lowers it.
    assert 0 < sum(reads.by_module[m] for m in SOLVER_MODULES) <= 3 * iterations + 6 * solves


def test_liquid_only_step_reads_two_small_arrays_besides_the_solver(tmp_path):
    sim = Simulation(liquid_scene(tmp_path), "cpu")
    for reads, iterations, solves in counted_steps(sim, 6):
        assert solves == 1
        other = {m: n for m, n in reads.by_module.items() if m not in SOLVER_MODULES}
        # liquid only: the grid stages' box (core/active_box.py, 12 ints with the gas's) is read once per step too, and
        # the void search's count of covered EMPTY cells and their box (core/voids.py, 7 ints); on a step
        # that has some, the count of those the device sweeps did not reach (1 int), and then, only if
        # any is left, the cell types and the sweeps' marks
        assert 1 <= other.pop("core.voids") <= 4
        assert other == {"core.simulation": STEP_READS, "core.active_box": 1}
        assert reads.elements["core.simulation"] == step_elements(sim)
        assert set(reads.by_function) - {(m, f) for m, f in reads.by_function if m in SOLVER_MODULES} == {
            ("core.simulation", "_phase_solve"), ("core.simulation", "_phase_read_back"), ("core.active_box", "update"),
            ("core.voids", "find")}
        assert_solver_within_bound(reads, iterations, solves)


def test_gas_and_tension_step_reads_the_boxes_once(tmp_path):
    # Gas and surface tension keep the grid stages' box (Stage.grid_box): the box and the gas's box
    # (core/active_box.py, 12 ints) are one read per step, as for liquid only; the stages read nothing.
    scene = Scene(domain=Domain(size=(0.1, 0.1), cell_size=0.1 / 24),
                  materials={"water": Material("water", surface_tension=0.072), "air": Material("air", kind="gas")},
                  shapes=[Box("water", (0.0, 0.0), (0.1, 0.06)), Sphere("air", center=(0.05, 0.025), radius=0.01)],
                  solver=SolverSettings(particles_per_cell=4), output=Output(path=str(tmp_path / "g.usdc")))
    sim = Simulation(scene, "cpu")
    assert set(sim.effects) == {"gas", "surface_tension"} and sim.region.enabled
    for reads, iterations, solves in counted_steps(sim, 6):
        other = {m: n for m, n in reads.by_module.items() if m not in SOLVER_MODULES}
        assert 1 <= other.pop("core.voids") <= 4
        if sim.stats.steps == 1:  # the gas's start pressure, read once before any step's read-back exists
            assert other.pop("physics.gas") == 1
        assert other == {"core.simulation": STEP_READS, "core.active_box": 1}
        # the grid box and the gas's (6 ints each) from each of the CPU's particle ranges (a cache
        # line each), in one read
        assert reads.elements["core.active_box"] == CACHE_LINE_FLOATS * sim.parallel.threads
        assert_solver_within_bound(reads, iterations, solves)


def test_full_effects_step_reads_nothing_per_stage_but_conversions_candidates(tmp_path):
    sim = Simulation(full_scene(tmp_path), "cpu")
    assert set(sim.effects) == {"gas", "colliders", "viscosity", "surface_tension", "emitters", "foam",
                                "subgrid_bubbles", "entrainment"}
    convert_steps = 0
    for reads, iterations, solves in counted_steps(sim, 16):
        modules = dict(reads.by_module)
        # Viscosity (explicit here): its stiffness rate, one float, by which the host picks the substeps.
        assert modules.pop("physics.viscous_solve") == 1
        # The void pass: its count, then on a step with covered EMPTY cells the count the device sweeps
        # left, and only if some are left the cell types, the sweeps' marks and the phases it labels on
        # the host (core/voids.py).
        voids = modules.pop("core.voids")
        assert 1 <= voids <= 6
        # A void the pass labels on the host (it read the cell types and the sweeps' marks): whether
        # a bubble's gas touches it reads the particles' phase and activity (ParticleState.numpy).
        state = modules.pop("core.state", 0)
        if state:
            print(f"step {sim.stats.steps}: the void pass labels on the host: {voids} reads, {state} of particle fields")
        assert state == 0 or (state == 2 and voids >= 3), (voids, state)
        if sim.stats.steps == 1:  # the gas's start pressure, read once before any step's read-back exists
            assert modules.pop("physics.gas") == 1
        # The stream's layers: the fill of their cells, one read on a step that lays any (effects/emitters.py).
        assert modules.pop("effects.emitters", 0) <= 1
        # Entrainment, colliders, foam, gas, tension: no read at all (the gas's step measures
        # ride on the step's read-back).
        assert set(modules) <= {"core.simulation", "effects.subgrid", *SOLVER_MODULES}, modules
        assert modules["core.simulation"] == STEP_READS and reads.elements["core.simulation"] == step_elements(sim)
        assert_solver_within_bound(reads, iterations, solves)
        if sim.stats.steps % 2:
            assert "effects.subgrid" not in modules
            continue
        # A conversion step: the candidates' count (with entrainment's), then their rows only.
        convert_steps += 1
        n = sim.num_particles
        phase, active = sim.particles.numpy("phase"), sim.particles.numpy("active") == 1
        candidates = int((((phase == PHASE_GAS) | (phase == PHASE_SUBGRID)) & active).sum())
        assert modules["effects.subgrid"] == 2
        rows = (reads.elements["effects.subgrid"] - 2) / CANDIDATE_COLUMNS
        assert rows == int(rows) and 0.5 * candidates <= rows <= 2 * candidates < 0.5 * n, (rows, candidates, n)
    assert convert_steps == 8
    assert sim.stage("viscosity").counts["implicit_steps"] == 0  # the one read above is the explicit path's
    assert sim.stage("entrainment").seeded > 0  # it had work, with no read of its own
    assert sim.launches["trapped_air"] == sim.stats.steps


def test_entrained_seeds_settle_exactly_and_overflow_joins_at_the_read_back(tmp_path):
    sims = [Simulation(splash_scene(tmp_path), "cpu") for _ in range(2)]
    roomy, tight = sims
    tight.stage("entrainment").state.capacity = 1  # one slot: the first step seeding two overflows
    new = 0
    while new < 2:  # in lock step: identical until that step
        n0, seeded0 = roomy.num_particles, roomy.stage("entrainment").seeded
        for sim in sims:
            sim.advance_to(sim.time + sim.stable_dt() * 0.9999)
        new = roomy.stage("entrainment").seeded - seeded0
        assert tight.stage("entrainment").seeded == roomy.stage("entrainment").seeded
    assert tight.stage("entrainment").overflows == 1 and roomy.stage("entrainment").overflows == 0
    assert tight.stage("entrainment").state.capacity == 2 * new
    for sim in sims:
        p = sim.particles
        assert sim.num_particles == n0 + new and sim.ledger.next_id == n0 + new
        assert np.array_equal(p.numpy("ids")[n0:], np.arange(n0, n0 + new))
        assert (p.numpy("phase")[n0:] == PHASE_SUBGRID).all() and (p.numpy("active")[n0:] == 1).all()
        # Beyond the count the arrays stay zero: the provisional slots were never written.
        assert not p.active.numpy()[sim.num_particles:].any() and not p.x.numpy()[sim.num_particles:].any()
    # The seed within the capacity moved in its step; the excess joined after the move.
    x_tight, x_roomy = tight.particles.numpy("x"), roomy.particles.numpy("x")
    assert np.array_equal(x_tight[: n0 + 1], x_roomy[: n0 + 1])
    assert not np.array_equal(x_tight[n0 + 1:], x_roomy[n0 + 1:])


def test_resuming_fewer_particles_leaves_zero_beyond_the_count(tmp_path):
    # Entrainment's provisional slots (and every append) rely on zero, inactive slots beyond the
    # count: a checkpoint with fewer particles than the fresh simulation must not leave old ones there.
    a = Simulation(splash_scene(tmp_path), "cpu")
    a.particles.compact(np.arange(0, a.num_particles, 2))
    save_checkpoint(a, tmp_path / "c.npz")
    b = Simulation(splash_scene(tmp_path), "cpu")
    load_checkpoint(b, tmp_path / "c.npz")
    assert b.num_particles == a.num_particles < b.particles.capacity
    for name in ("active", "x", "phase"):
        assert not getattr(b.particles, name).numpy()[b.num_particles:].any(), name


def test_host_read_counter_attributes_reads_and_patches_nothing_outside(tmp_path):
    numpy, sync = wp.array.numpy, wp.synchronize
    a = wp.zeros(7, dtype=float, device="cpu")
    with HostReads() as reads:
        a.numpy()
        a.list()  # one read, not two (list reads through numpy)
        wp.synchronize()
    assert reads.by_function == {(__name__, "test_host_read_counter_attributes_reads_and_patches_nothing_outside"): 3}
    assert reads.elements[__name__] == 14 and reads.total == 3
    assert wp.array.numpy is numpy and wp.synchronize is sync  # zero cost when not counting


def test_step_graph_is_the_step_on_the_cpu(tmp_path):
    # Capture needs CUDA: on the CPU step_graph is step, bit for bit (the GPU path is untested here).
    a, b = (Simulation(liquid_scene(tmp_path), "cpu") for _ in range(2))
    for _ in range(3):
        dt = a.stable_dt()
        a.step(dt)
        b.step_graph(dt)
    assert not b._graphs
    for name in ("x", "v", "C", "J"):
        assert np.array_equal(a.particles.numpy(name), b.particles.numpy(name)), name


CUDA = wp.is_cuda_available()


@pytest.mark.skipif(not CUDA, reason="CUDA graphs need a GPU (none here: this test has not run yet)")
def test_step_graph_replays_the_step_on_a_gpu(tmp_path):
    # A fixed dt, so the captured stretches (step_plan(graph=True)) replay while the grid box holds.
    # GPU atomics sum in any order: the same state to float32 round-off, the same launches.
    a, b = (Simulation(liquid_scene(tmp_path), "cuda:0") for _ in range(2))
    for _ in range(10):
        a.step(5.0e-4)
        b.step_graph(5.0e-4)
    assert b._graphs and a.launches == b.launches
    np.testing.assert_allclose(b.particles.numpy("x"), a.particles.numpy("x"), rtol=0, atol=1e-6)
    np.testing.assert_allclose(b.particles.numpy("v"), a.particles.numpy("v"), rtol=0, atol=1e-4)
