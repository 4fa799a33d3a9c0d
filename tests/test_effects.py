"""The effects model (issue #4): a scene runs the stages of the effects it asks for and no others.

The proof is the kernel launch counter (`Simulation.launches`, every launch goes through it) and
the stage timer's list of stages that ran, which the run summary prints.
"""

import io

import warp as wp

from scenes import tank_2d
from warp_mpm_bubbles import Material, Sphere
from warp_mpm_bubbles.scene.effects import Collider, LiquidInflow
from warp_mpm_bubbles.core.simulation import Simulation

wp.config.quiet = True

# What every liquid scene launches: the transfers (2D: these scenes' dimension), the grid phases,
# the pressure system.
CORE_KERNELS = {"p2g_2d", "momentum_to_velocity", "classify_cells", "zero_solid_faces", "face_inverse_density",
                "pressure_diagonal_and_rhs", "subtract_pressure_gradient", "extrapolate_velocity",
                "enforce_walls", "g2p_advect_2d", "split_pairs",
                "covered_top", "count_covered_empty", "clear_holes"}  # core/voids.py: holes in the liquid
CORE_STAGES = ["p2g", "grid", "pressure", "extend", "g2p"]
# core/voids.py's search, launched only on steps where some EMPTY cell has fluid or solid above it
VOID_SEARCH = {"mark_open_air", "sweep_open_air", "count_unreached_empty"}


def run_steps(scene, n=3):
    sim = Simulation(scene, "cpu")
    for _ in range(n):
        sim.step(sim.stable_dt())
    return sim


def test_liquid_only_scene_launches_only_core_kernels(tmp_path):
    sim = run_steps(tank_2d(cells=16, out=tmp_path / "t.usdc"))
    assert sim.effects == []
    threaded = {"fastest_of_parts"} if sim.parallel.threads > 1 else set()  # g2p's parts' speeds (core/threads.py)
    assert set(sim.launches) == CORE_KERNELS | threaded  # no gas, tension, viscosity, collider, foam or bubble kernel
    assert sim.timer.phases_run == CORE_STAGES


def test_each_effect_adds_only_its_own_stages(tmp_path):
    base = tank_2d(cells=16, out=tmp_path / "t.usdc")
    scene = tank_2d(cells=16, out=tmp_path / "t.usdc")
    scene.materials["water"] = Material("water", surface_tension=0.072)
    scene.colliders = [Collider("sphere", center=(0.5, 0.25), radius=0.1)]
    scene.emitters = [LiquidInflow("water", center=(0.5, 0.9), direction=(0.0, -1.0), radius=0.05, speed=1.0)]
    sim = run_steps(scene)
    assert sim.effects == ["colliders", "surface_tension", "emitters"]
    extra = set(sim.launches) - set(run_steps(base).launches) - VOID_SEARCH  # the stream covers the air below it
    assert extra == {"inside_any_collider", "mark_collider_cells", "push_out_of_colliders",  # static: no faces
                     # solids inside the domain may seal fluid off: its regions are counted (core/sealed_regions.py)
                     "start_labels", "sweep_labels", "check_and_mark", "count_regions", "report_squeezed",
                     "fill_box",  # the stream's nozzle: how full its cells are (effects/emitters.py)
                     "liquid_level_set", "smooth_level_set", "height_fraction", "column_heights", "surface_curvature",
                     "average_curvature", "apply_surface_tension"}
    assert sim.timer.phases_run == ["emitters", *CORE_STAGES[:2], "tension", *CORE_STAGES[2:], "colliders"]


def test_gas_is_an_effect_of_the_materials_used(tmp_path):
    scene = tank_2d(cells=16, out=tmp_path / "t.usdc")
    scene.materials["air"] = Material("air", kind="gas")  # defined but unused: no gas stage
    assert scene.validate().effect_names == []
    scene.shapes.append(Sphere("air", center=(0.5, 0.2), radius=0.1))
    assert scene.validate().effect_names == ["gas"]
    sim = run_steps(scene, 1)
    assert {"p2g_gas", "classify_phases", "vent_exposed_gas"} <= set(sim.launches)


def test_summary_lists_the_stages_that_ran(tmp_path):
    from warp_mpm_bubbles.io.runner import run_scene

    scene = tank_2d(cells=16, out=tmp_path / "t.usdc").replace_output(frames=1)
    scene.colliders = [Collider("box", center=(0.5, 0.2), size=(0.2, 0.1))]
    log = io.StringIO()
    run_scene(scene.validate(), device="cpu", log=log)
    text = log.getvalue()
    assert "phases timed: output, p2g, grid, pressure, extend, g2p, colliders" in text  # frame 0 is written first
    assert "effects: colliders" in text


def test_retired_particles_are_compacted_without_changing_the_results(tmp_path, monkeypatch):
    # A bubble under the surface bursts (its gas vents): once a quarter of the particles are
    # retired the arrays shrink. Survivors keep their order, so the run matches one that never
    # compacts bit for bit, and every particle keeps its id.
    import numpy as np

    import warp_mpm_bubbles.core.simulation as simulation

    def run(compact):
        monkeypatch.setattr(simulation, "COMPACT_RETIRED", 0.1 if compact else 2.0)  # 15% of it vents
        scene = tank_2d(cells=16, depth=0.3, out=tmp_path / "t.usdc")
        scene.materials["air"] = Material("air", kind="gas")
        scene.shapes.append(Sphere("air", center=(0.5, 0.24), radius=0.12))
        sim = Simulation(scene.validate(), "cpu")
        ids0 = sim.particles_numpy()["ids"]
        for _ in range(8):
            sim.advance_frame()
        return sim, ids0

    compacted, ids0 = run(True)
    kept, _ = run(False)
    assert compacted.num_particles < kept.num_particles  # it did compact
    a, b = compacted.particles_numpy(), kept.particles_numpy()
    for key in ("ids", "positions", "velocities", "J", "material"):
        np.testing.assert_array_equal(a[key], b[key])
    assert set(a["ids"]) <= set(ids0) and len(set(a["ids"])) == len(a["ids"])
    assert compacted.gas_budget()["total"] == kept.gas_budget()["total"]
