"""Physics and invariants of the liquid core on Warp's CPU device (docs/design.md#validation reference cases)."""

import math
import pathlib

import numpy as np
import pytest
import warp as wp

from scenes import dam_break_2d, tank_2d
from warp_mpm_bubbles.core.simulation import Simulation

wp.config.quiet = True
G = 9.81
REFDATA = pathlib.Path(__file__).resolve().parent / "data"  # the reference data of docs/design.md#validation
MARTIN_MOYCE = REFDATA / "martin_moyce_1952_n2_2_a2.25in.csv"


# ------------------------------------------------------------------------------- tank at rest
@pytest.fixture(scope="module")
def tank(tmp_path_factory):
    sim = Simulation(tank_2d(depth=0.5, cells=32, out=tmp_path_factory.mktemp("tank") / "t.usdc"), "cpu")
    speeds = []
    for _ in range(15):  # 0.5 s, about 1.1 gravity-wave crossings of the tank
        sim.advance_frame()
        speeds.append(np.linalg.norm(sim.particles_numpy()["velocities"], axis=1).max())
    return sim, np.array(speeds)


def test_tank_at_rest_stays_at_rest(tank):
    # Bound: 5% of sqrt(g H). The only source of motion is the surface position read from jittered
    # particles (about +-0.1 dx); measured here: max 3.1%, rms 0.1%, not growing.
    _, speeds = tank
    scale = math.sqrt(G * 0.5)
    assert speeds.max() < 0.05 * scale
    assert speeds[-5:].max() <= 1.5 * speeds[:5].max() + 1e-3 * scale  # not growing


def test_tank_pressure_is_hydrostatic(tmp_path):
    # p = rho g depth with the surface imposed where the particles end (ghost fluid). Tolerance:
    # a quarter cell of head, rho g dx / 4 (measured: 0.02); placing p = 0 at the empty cell's
    # centre instead (no ghost fluid) is off by rho g dx / 2 everywhere and fails this test.
    # The volume correction is off here: it relaxes the seeding noise once by expanding the
    # water 0.36%, which lifts the surface by about 0.1 dx and would blur what this checks.
    sim = Simulation(tank_2d(depth=0.5, cells=32, out=tmp_path / "t.usdc", volume_relaxation_time=0.0), "cpu")
    for _ in range(6):
        sim.advance_frame()
    dx = sim.grid.dx
    p = sim.pressure_numpy()[2:-2, :, 0]  # columns away from the corners
    depth_rows = int(round(0.5 / dx))
    y = (np.arange(depth_rows) + 0.5) * dx
    expected = 1000.0 * G * (0.5 - y)
    error = np.abs(p[:, :depth_rows] - expected[None, :])
    assert error.max() < 0.25 * 1000.0 * G * dx, error.max()
    assert np.all(p[:, depth_rows + 1:] == 0.0)  # air above the water is at gauge zero


# ------------------------------------------------------------------------ dam break (2D, coarse)
@pytest.fixture(scope="module")
def dam_break(tmp_path_factory):
    """Martin & Moyce's column (width a, height 2a) at 16 cells per a, run to T = 3.33."""
    a = 0.1
    sim = Simulation(dam_break_2d(a=a, cells_per_a=16, out=tmp_path_factory.mktemp("dam") / "d.usdc"), "cpu")
    ref = np.loadtxt(MARTIN_MOYCE, delimiter=",", comments="#", skiprows=4)[1:]  # skip T = 0
    start = sim.particles_numpy()
    volume0, density0 = sim.liquid_volume(), sim.liquid_density()
    time_unit = math.sqrt(a / (2 * G))  # T = t sqrt(2 g / a)
    front, finite, inside = [], True, True
    for T, _ in ref:
        sim.advance_to(T * time_unit)
        p = sim.particles_numpy()
        finite &= bool(np.isfinite(p["positions"]).all() and np.isfinite(p["velocities"]).all())
        inside &= bool(((p["positions"] >= 0) & (p["positions"] <= np.array(sim.grid.domain_size))).all())
        front.append(p["positions"][:, 0].max() / a)
    return dict(sim=sim, ref=ref, front=np.array(front), start=start, end=sim.particles_numpy(),
                volume_drift=sim.liquid_volume() / volume0 - 1.0,
                compression=sim.liquid_density() / density0 - 1.0, finite=finite, inside=inside)


def test_dam_break_front_speed_matches_martin_moyce(dam_break):
    # The surge front's speed dZ/dT over T in [1.4, 3.4] (least-squares slope) within 10% of the
    # experiment's: at 16 cells per a the front is resolved to 1/16 a, so Z carries +-0.06 over a
    # span of 2.4 in Z, i.e. +-5% in slope, doubled for the tip's sheet breaking off in one cell.
    # Measured: +1.5% with Jacobi-PCG, +6.3% with multigrid-PCG, +4.5% with the two-sided volume
    # correction (the tip is one particle: solver and correction settings move it).
    ref, front = dam_break["ref"], dam_break["front"]
    late = ref[:, 0] >= 1.4
    slope_sim = np.polyfit(ref[late, 0], front[late], 1)[0]
    slope_ref = np.polyfit(ref[late, 0], ref[late, 1], 1)[0]
    assert abs(slope_sim / slope_ref - 1.0) < 0.10, (slope_sim, slope_ref)


def test_dam_break_front_leads_by_the_gate_delay(dam_break):
    # Inviscid simulations lead Martin & Moyce's front by a near-constant time: the experiment's
    # gate took time to lift (Martin & Moyce 1952; most SPH/VOF reproductions shift T by 0.2-0.4).
    # Fit that shift; it must be a delay of the experiment (0 <= dT <= 0.5), and after it the
    # simulated front must follow the measured one to within 0.1 a (1.6 cells) RMS.
    ref, front = dam_break["ref"], dam_break["front"]
    shifts = np.linspace(-0.5, 1.0, 151)
    rms = [_shifted_rms(ref, front, s) for s in shifts]
    best = shifts[int(np.nanargmin(rms))]
    assert 0.0 <= best <= 0.5, best
    assert np.nanmin(rms) < 0.1, np.nanmin(rms)


def _shifted_rms(ref, front, shift):
    """RMS of Z_ref(T + shift) - Z_sim(T) over the times where the shifted reference exists."""
    T = ref[:, 0] + shift
    ok = (T >= ref[0, 0]) & (T <= ref[-1, 0])
    if ok.sum() < 8:
        return np.nan
    return float(np.sqrt(np.mean((np.interp(T[ok], ref[:, 0], ref[:, 1]) - front[ok]) ** 2)))


def test_dam_break_conserves_particles_and_stays_in_domain(dam_break):
    start, end = dam_break["start"], dam_break["end"]
    assert dam_break["finite"] and dam_break["inside"]
    np.testing.assert_array_equal(start["ids"], end["ids"])
    np.testing.assert_array_equal(start["material"], end["material"])


def test_dam_break_liquid_volume_drift_is_bounded(dam_break):
    # Occupied volume sum(min(phi, 1)) dx^3 against its start. Without the volume correction this
    # run loses 2.8% (particles cluster where the flow turns). Measured +0.23% with the correction
    # moving positions (the default), -0.93% moving velocities. Bound 1%: a third of the
    # uncorrected loss. This measure also reads the particles' sampling scatter as loss (a shuffle
    # by half a spacing that keeps every volume reads -0.83%): moving positions, each enclosed
    # cell's whole excess is answered, so the scatter in the water's inside stays at the
    # seeding's (7.0% -> 6.9% of a cell's fill, against 10.1% moving velocities) and the measure
    # reads a little more than at the start; the next test reads the compression alone.
    assert abs(dam_break["volume_drift"]) < 0.01, dam_break["volume_drift"]


def test_dam_break_liquid_is_not_compressed(dam_break):
    # The liquid's mean rest-volume fraction inside it (Simulation.liquid_density) against its
    # start: clustering particles compress the water and its surface sinks, and the scatter's mean
    # is 0, so this reads compression only. Measured: +0.10% moving positions (the default), +0.38%
    # moving velocities; +2.0% without the volume correction (the same run in one advance: +0.41%
    # and +2.0%). Bound 1%, both signs: half the uncorrected compression; moving velocities a noise
    # band of 0.2 instead of 0.1 reads +1.7%.
    print(f"dam break: compression {dam_break['compression']:+.4f}, occupied volume {dam_break['volume_drift']:+.4f}")
    assert abs(dam_break["compression"]) < 0.01, dam_break["compression"]


def test_time_steps_land_on_frames_and_respect_cfl(tmp_path):
    scene = dam_break_2d(cells_per_a=8, out=tmp_path / "d.usdc")
    sim = Simulation(scene, "cpu")
    for _ in range(3):
        sim.advance_frame()
        assert sim.time == pytest.approx(sim.frame / scene.output.fps, abs=1e-12)
    dx, cfl = sim.grid.dx, scene.solver.cfl
    assert max(sim.stats.dt_history) <= cfl * dx / math.sqrt(G * dx) * (1 + 1e-9)


# ------------------------------------------------------------------------------ determinism
def _run_positions(tmp_path, seed, steps=6):
    sim = Simulation(dam_break_2d(cells_per_a=8, out=tmp_path / "d.usdc", seed=seed), "cpu")
    for _ in range(steps):
        sim.step(sim.stable_dt())
    return sim.particles_numpy()["positions"]


def test_same_scene_and_seed_give_identical_positions(tmp_path):
    np.testing.assert_array_equal(_run_positions(tmp_path, 0), _run_positions(tmp_path, 0))


def test_another_seed_gives_other_positions(tmp_path):
    assert not np.array_equal(_run_positions(tmp_path, 0, steps=1), _run_positions(tmp_path, 1, steps=1))
