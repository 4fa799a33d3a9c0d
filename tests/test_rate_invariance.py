"""The state at a time does not depend on the frame rate or the step (issue #12): the volume
correction is a rate ([solver].volume_relaxation_time, or the cell over
[solver].volume_correction_speed, whose drift converges with the grid), bounded, and the step knows the gas
("gas_expansion"). Numbers: benchmarks/validation/rate_invariance.py (before/after in docs/design.md §3.3, §7)."""

import math

import numpy as np
import pytest
import warp as wp

from scenes import dam_break_2d, tank_2d
from warp_mpm_bubbles import Box, Domain, Material, Output, Scene, SolverSettings, Sphere
from warp_mpm_bubbles.core.simulation import Simulation
from warp_mpm_bubbles.scene.limits import MIN_VOLUME_RELAXATION, STEP_FIXES, step_limits

wp.config.quiet = True
P_ATM = 101325.0


def liquid_state(sim):
    p = sim.particles_numpy()
    liquid = p["phase"] == 0
    speed = np.linalg.norm(p["velocities"][liquid], axis=1)
    return p["positions"][liquid, :2].mean(0), speed.mean(), speed.max()


def occupied_cells(sim):
    """Cells holding at least one liquid particle: particles collapsing to points empty most of them."""
    p = sim.particles_numpy()
    return len(np.unique(np.floor(p["positions"][p["phase"] == 0, :2] / sim.grid.dx).astype(int), axis=0))


def dam(tmp_path, fps, max_dt=None, t_end=0.25, voids=True, **solver):
    """A 2D dam break (8 cells across the column), run frame by frame: steps land on frame times.
    voids=False switches the void pass off (core/voids.py), isolating the correction. Returns the
    simulation, its occupied volume's drift (Simulation.liquid_volume) and its compression
    (Simulation.liquid_density), each against the start."""
    scene = dam_break_2d(cells_per_a=8, out=tmp_path / "d.usdc", max_dt=max_dt, **solver)
    scene.output.fps = fps
    sim = Simulation(scene, "cpu")
    if not voids:
        sim.voids.apply = lambda dt: None
    v0, d0 = sim.liquid_volume(), sim.liquid_density()
    while sim.time < t_end - 1e-9:
        sim.advance_frame()
    return sim, sim.liquid_volume() / v0 - 1.0, sim.liquid_density() / d0 - 1.0


@pytest.mark.parametrize("moves,voids", [("velocities", False), ("positions", False), ("positions", True)],
                         ids=["velocities", "positions", "positions_with_void_pass"])
def test_the_same_dam_break_at_24_and_240_fps_and_two_max_dt(tmp_path, moves, voids):
    # At 0.25 s (the front near 1.8 column widths): fps 24, fps 240 and fps 24 with max_dt = 1 ms
    # (80, 105 and 252 steps). Measured with the void pass off (the correction alone), the
    # correction moving velocities: centroids within 1.3 mm = 0.10 dx of each other (the time
    # integration's own spread, with the correction off, is 1.8 mm), mean speeds within 0.6%, fastest
    # particles within 1.2%, occupied volume drift -0.18%, -0.13%, -0.11% (spread 0.07%). With the
    # old share per step (0.3) the drifts were -0.10%, -0.08%, +0.06%: a spread of 0.16%, outside
    # the bound of 0.1%.
    # Moving positions (the default) the occupied volume grows instead, +0.44%, +0.55%, +0.58%
    # (+0.43 / +0.54 / +0.57% with the void pass): the shift answers each enclosed cell's whole
    # excess, so it evens out the seeding's scatter, which min(phi, 1) counted as lost, and more
    # steps even out a little more. The compression, which the scatter does not bias, is +0.78%,
    # +0.76%, +0.82% (spread 0.06%; moving velocities +1.76 / +1.67 / +1.46%, spread 0.30%).
    # Bounds moving positions: the compression's spread under 0.1% and under 1%; the occupied
    # volume's drift between 0 and 1%, its spread under 0.2%.
    runs = [dam(tmp_path, 24, voids=voids, volume_correction_moves=moves),
            dam(tmp_path, 240, voids=voids, volume_correction_moves=moves),
            dam(tmp_path, 24, max_dt=1e-3, voids=voids, volume_correction_moves=moves)]
    states = [liquid_state(sim) for sim, _, _ in runs]
    drifts = np.array([d for _, d, _ in runs])
    compressions = np.array([c for _, _, c in runs])
    dx = runs[0][0].grid.dx
    centroids = np.array([s[0] for s in states])
    print(f"dam break, moving {moves}: steps {[sim.stats.steps for sim, _, _ in runs]}, centroids "
          f"{np.round(centroids, 5).tolist()}, mean speeds {[round(float(s[1]), 4) for s in states]}, max "
          f"{[round(float(s[2]), 4) for s in states]}, volume drift {np.round(100 * drifts, 3).tolist()} %, "
          f"compression {np.round(100 * compressions, 3).tolist()} %")
    assert [sim.stats.steps for sim, _, _ in runs][2] > 2 * runs[0][0].stats.steps  # max_dt did bind
    assert np.ptp(centroids, axis=0).max() < 0.15 * dx
    means, fastest = np.array([s[1] for s in states]), np.array([s[2] for s in states])
    assert np.ptp(means) < 0.02 * means.mean()
    assert np.ptp(fastest) < 0.03 * fastest.mean()
    if moves == "velocities":
        assert np.ptp(drifts) < 1e-3
        assert np.abs(drifts).max() < 5e-3
    else:
        assert np.ptp(compressions) < 1e-3 and np.abs(compressions).max() < 1e-2
        assert np.ptp(drifts) < 2e-3 and 0.0 < drifts.min() and drifts.max() < 1e-2


@pytest.mark.parametrize("tau", [None, MIN_VOLUME_RELAXATION], ids=["default", "strongest"])
def test_resting_water_stays_at_rest_under_tiny_steps(tmp_path, tau):
    # 20 steps of 1 microsecond: the correction per second is the same as at any step. Measured
    # fastest particle 0.090 m/s (default 0.01 s) and 0.90 m/s at the strongest setting, 1 ms (about
    # 0.1 dx / tau, dx = 3.1 cm: the seeding noise undone at the rate asked); the old share per step
    # reached 122 m/s. Bound: 0.2 dx / tau. Nothing collapses: every cell keeps particles.
    solver = {} if tau is None else {"volume_relaxation_time": tau}
    sim = Simulation(tank_2d(depth=0.5, cells=32, out=tmp_path / "t.usdc", max_dt=1e-6, **solver), "cpu")
    cells0 = occupied_cells(sim)
    for _ in range(20):
        sim.step(sim.stable_dt())
    _, mean, fastest = liquid_state(sim)
    tau = tau or sim.scene.solver.volume_relaxation(sim.grid.dx)
    print(f"rest, tau {tau} s, 20 steps of 1e-6 s: mean {mean:.4f} m/s, fastest {fastest:.4f} m/s")
    assert fastest < 0.2 * sim.grid.dx / tau
    assert occupied_cells(sim) == cells0


@pytest.mark.parametrize("moves", ["velocities", "positions"])
def test_the_strongest_correction_does_not_collapse_a_dam_break(tmp_path, moves):
    # tau = 1 ms (the bound), with CFL steps of about 3 ms: the whole excess per step (the cap).
    # Measured moving velocities: occupied volume drift -0.04% (default tau -0.21%), 135 occupied
    # cells (138), fastest 2.20 m/s. Moving positions: drift +1.09% (+0.43%), compression +0.51%
    # (+0.78%), 137 cells (138), fastest 2.23 m/s: the shift evens out the seeding's
    # scatter (tests above), faster the stronger it is. Bounds: the volume within 1% (moving
    # positions its compression; its occupied volume grows, by less than the 2.7% the scatter took
    # at the start), 95% of the default's cells, 1.5x its fastest particle.
    sim, drift, compression = dam(tmp_path, 24, volume_relaxation_time=MIN_VOLUME_RELAXATION, volume_correction_moves=moves)
    ref, ref_drift, ref_compression = dam(tmp_path, 24, volume_correction_moves=moves)
    cells, ref_cells = occupied_cells(sim), occupied_cells(ref)
    print(f"strongest correction, moving {moves}: drift {100 * drift:.3f}% (default {100 * ref_drift:.3f}%), "
          f"compression {100 * compression:.3f}% ({100 * ref_compression:.3f}%), occupied cells {cells} (default "
          f"{ref_cells}), fastest {liquid_state(sim)[2]:.3f} m/s")
    if moves == "velocities":
        assert abs(drift) < 0.01
    else:
        assert abs(compression) < 0.01 and 0.0 < drift < 0.027
    assert cells >= 0.95 * ref_cells
    assert liquid_state(sim)[2] < 1.5 * liquid_state(ref)[2]


def test_the_dam_breaks_volume_drift_converges_with_a_correction_speed(tmp_path):
    # [solver].volume_correction_speed = 1 m/s makes the relaxation time the cell over 1 m/s, so it
    # halves with the cell and the drift converges. Martin & Moyce's column (a = 0.1 m) to 0.2 s,
    # seed 0: 12 cells per a (tau 8.3 ms) -0.834%, 24: -0.506%, 48 (2.1 ms) -0.261% (seeds 1, 2:
    # -0.65 / -0.56 / -0.39% and -0.78 / -0.47 / -0.34%, order 0.6-1). The fixed default, 10 ms,
    # gives -0.94 / -0.86 / -0.94%: it fails both bounds at 48. Bounds: at 48 at most half of 12's
    # drift and below 0.45%; at 12 between 0.5% and 1.1% (seeds 0-2: 0.65-0.83%).
    drifts = []
    for cells in (12, 48):
        sim = Simulation(dam_break_2d(cells_per_a=cells, out=tmp_path / "d.usdc", volume_correction_speed=1.0,
                                      volume_correction_moves="velocities"), "cpu")
        assert sim.scene.solver.volume_relaxation(sim.grid.dx) == pytest.approx(sim.grid.dx / 1.0, rel=1e-12)
        v0 = sim.liquid_volume()
        sim.advance_to(0.2)
        drifts.append(sim.liquid_volume() / v0 - 1.0)
    print(f"dam break volume drift at 12 / 48 cells per a: {100 * drifts[0]:.3f} / {100 * drifts[1]:.3f}%")
    assert 0.005 < abs(drifts[0]) < 0.011
    assert abs(drifts[1]) < 0.5 * abs(drifts[0])
    assert abs(drifts[1]) < 0.0045

def expansion(tmp_path, max_dt=None, t_end=0.0015):
    """tests/test_hard_cases.py's gas at 10 atm (gauge 9 atm) in a 2D tank, to t_end."""
    scene = Scene(domain=Domain(size=(0.1, 0.2), cell_size=0.0025),
                  materials={"water": Material("water"), "air": Material("air", kind="gas")},
                  shapes=[Box("water", (0.0, 0.0), (0.1, 0.1)), Sphere("air", (0.05, 0.03), 0.004, pressure=9 * P_ATM)],
                  solver=SolverSettings(max_dt=max_dt), output=Output(path=str(tmp_path / "e.usdc"), fps=60))
    sim = Simulation(scene, "cpu")
    limits = sim.dt_limits()
    sim.advance_to(t_end)
    return sim, limits, scene


def test_a_violent_expansion_starts_with_resolved_steps(tmp_path):
    # The expansion time is R0 sqrt(rho / dp) = 1.3e-4 s. Before the gas_expansion limit the first
    # step was 8 ms and at 1.5 ms the liquid moved at 0.24 m/s mean, 0.99 m/s at most; resolved
    # steps (max_dt 2e-5 s) give 3.06 and 7.82 m/s. Measured now: first step 4.05e-5 s (35 steps),
    # 2.95 and 7.59 m/s (-3.5%, -2.9%). Bounds: 15% of the resolved run (the old run is 90% off).
    # The limit's value equals scene/limits.py's estimate before the run (a 3% change of either fails).
    sim, limits, scene = expansion(tmp_path)
    ref, _, _ = expansion(tmp_path, max_dt=2e-5)
    assert min(limits, key=limits.get) == "gas_expansion" and "gas_expansion" in STEP_FIXES
    assert limits["gas_expansion"] == pytest.approx(step_limits(scene.validate())["gas_expansion"], rel=1e-6)
    t_exp = 0.004 * math.sqrt(1000.0 / (9 * P_ATM))
    assert sim.stats.dt_history[0] < 0.5 * t_exp
    (_, mean, fastest), (_, ref_mean, ref_fastest) = liquid_state(sim), liquid_state(ref)
    print(f"expansion: first step {sim.stats.dt_history[0]:.3g} s, {sim.stats.steps} steps; liquid mean "
          f"{mean:.3f} m/s (resolved {ref_mean:.3f}), fastest {fastest:.3f} (resolved {ref_fastest:.3f})")
    assert mean == pytest.approx(ref_mean, rel=0.15)
    assert fastest == pytest.approx(ref_fastest, rel=0.15)


def test_a_bubble_at_its_hydrostatic_pressure_gets_no_pressure_limit(tmp_path):
    # The pressure part of gas_expansion counts only what exceeds the domain's hydrostatic head:
    # an ordinary bubble's first step is the CFL one.
    scene = tank_2d(cells=16, depth=0.6, out=tmp_path / "h.usdc")
    scene.materials["air"] = Material("air", kind="gas")
    scene.shapes.append(Sphere("air", center=(0.5, 0.3), radius=0.1, pressure=1000.0 * 9.81 * 0.3))
    sim = Simulation(scene.validate(), "cpu")
    assert "gas_expansion" not in sim.dt_limits() and "gas_expansion" not in step_limits(scene)


# The near-vacuum cavity against Rayleigh's time (issue #12 item 7, a strict xfail here before):
# tests/test_cavity.py.
