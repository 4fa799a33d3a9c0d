"""Compressible gas in the two-phase pressure system (DESIGN §2, §5), on Warp's CPU device."""

import math

import numpy as np
import pytest
import warp as wp

from warp_mpm_bubbles import Box, Cylinder, Domain, Material, Output, Scene, SolverSettings, Sphere
from warp_mpm_bubbles.simulation import Simulation

wp.config.quiet = True
P_ATM = 101325.0
AIR_AND_WATER = lambda: {"water": Material("water"), "air": Material("air", kind="gas")}  # noqa: E731


# ------------------------------------------------- Minnaert: a 2D bubble breathing in a liquid disc
R0, R_INF = 0.01, 0.05
OMEGA_2D = math.sqrt(2 * P_ATM / (1000.0 * R0**2 * math.log(R_INF / R0)))  # DESIGN §5, sigma = 0
STEPS_PER_PERIOD = 40


@pytest.fixture(scope="module")
def breathing(tmp_path_factory):
    """A bubble seeded 2% above ambient at the centre of a free liquid disc, no gravity, 3 periods."""
    L = 12 * R0
    period = 2 * math.pi / OMEGA_2D
    scene = Scene(
        domain=Domain(size=(L, L), cell_size=R0 / 8, gravity=(0.0, 0.0), walls="open"),
        materials=AIR_AND_WATER(),
        shapes=[Cylinder("water", center=(L / 2, L / 2), radius=R_INF),
                Cylinder("air", center=(L / 2, L / 2), radius=R0, pressure=0.02 * P_ATM)],
        solver=SolverSettings(max_dt=period / STEPS_PER_PERIOD),
        output=Output(path=str(tmp_path_factory.mktemp("minnaert") / "m.usdc")),
    )
    sim = Simulation(scene, "cpu")
    budget0 = sim.gas_budget()
    times, volumes = [], []
    while sim.time < 3.2 * period:
        sim.advance_to(sim.time + period / STEPS_PER_PERIOD)
        times.append(sim.time)
        volumes.append(sim.gas_budget()["volume"])
    return dict(sim=sim, t=np.array(times), V=np.array(volumes), budget0=budget0, period=period)


def test_bubble_breathes_at_the_2d_minnaert_frequency(breathing):
    # Reference: omega0^2 = 2 p0 / (rho R0^2 ln(Rinf/R0)) (isothermal, sigma = 0) = 178.6 Hz.
    # Measured -7.6% at 8 cells per radius and -6.2% at 16 (the same at 40 and 80 steps per
    # period: the error is spatial and shrinks slowly); 10% bounds the 8-cell result.
    t, V = breathing["t"], breathing["V"]
    x = V - V.mean()
    up = [t[i] - x[i] * (t[i + 1] - t[i]) / (x[i + 1] - x[i]) for i in range(len(x) - 1) if x[i] < 0 <= x[i + 1]]
    assert len(up) >= 3, up
    f_sim = 1.0 / np.diff(up).mean()
    f_ref = OMEGA_2D / (2 * math.pi)
    assert abs(f_sim / f_ref - 1.0) < 0.10, (f_sim, f_ref)


def test_bubble_volume_follows_pv_constant(breathing):
    # Seeded at 1.02 p_atm, the bubble oscillates about the volume where its pressure is the
    # ambient one: V = 1.02 V_seed (isothermal p V = const). Measured 1.0203; bound 0.2%, a tenth of
    # the 2% change that is being checked.
    mean_volume = breathing["V"].mean()
    assert mean_volume / breathing["budget0"]["volume"] == pytest.approx(1.02, rel=2e-3)


def test_gas_mass_is_conserved_while_breathing(breathing):
    budget = breathing["sim"].gas_budget()
    assert budget["total"] == pytest.approx(breathing["budget0"]["total"], rel=1e-12)
    assert budget["vented"] == 0.0  # the bubble never touched the atmosphere


# ------------------------------------------------ a bubble rising at 1000:1, both interface methods
@pytest.fixture(scope="module", params=["sharp", "baseline"])
def rising(request, tmp_path_factory):
    dx = 0.08 / 32
    scene = Scene(
        domain=Domain(size=(0.08, 0.16), cell_size=dx),
        materials=AIR_AND_WATER(),
        shapes=[Box("water", min=(0.0, 0.0), max=(0.08, 0.14)), Sphere("air", center=(0.04, 0.03), radius=0.01)],
        solver=SolverSettings(interface=request.param),
        output=Output(path=str(tmp_path_factory.mktemp("rise") / "r.usdc"), fps=60),
    )
    sim = Simulation(scene, "cpu")
    start = sim.particles_numpy()
    budget0 = sim.gas_budget()
    for _ in range(6):  # 0.1 s
        sim.advance_frame()
    return dict(sim=sim, start=start, end=sim.particles_numpy(include_retired=True), budget0=budget0)


def test_rising_bubble_stays_finite_bounded_and_inside(rising):
    # Speed bound: the free-fall speed over the water's depth, sqrt(2 g 0.14) = 1.66 m/s; a bubble
    # of 2 cm rises at about 0.2 m/s, its wake a few times that.
    end, sim = rising["end"], rising["sim"]
    assert np.isfinite(end["positions"]).all() and np.isfinite(end["velocities"]).all()
    assert (end["positions"] >= 0).all() and (end["positions"] <= np.array(sim.grid.domain_size)).all()
    assert np.linalg.norm(end["velocities"], axis=1).max() < math.sqrt(2 * 9.81 * 0.14)


def test_rising_bubble_rises(rising):
    is_gas = lambda p: p["material"] == 1  # noqa: E731
    y0 = rising["start"]["positions"][is_gas(rising["start"]), 1].mean()
    active = rising["sim"].particles_numpy()
    y1 = active["positions"][is_gas(active), 1].mean()
    assert y1 > y0 + 0.005  # more than two cells in 0.1 s


def test_rising_bubble_gas_mass_is_exactly_accounted_for(rising):
    budget = rising["sim"].gas_budget()
    assert budget["total"] == pytest.approx(rising["budget0"]["total"], rel=1e-12)
    np.testing.assert_array_equal(rising["end"]["ids"], rising["start"]["ids"])


def test_liquid_only_scene_runs_no_gas_stage(tmp_path):
    scene = Scene(domain=Domain(size=(0.1, 0.1), cell_size=0.01), materials={"water": Material("water")},
                  shapes=[Box("water", min=(0.0, 0.0), max=(0.1, 0.05))], output=Output(path=str(tmp_path / "w.usdc")))
    sim = Simulation(scene, "cpu")
    sim.step(sim.stable_dt())
    assert not sim.has_gas and "vent" not in sim.timer.stages_run
    assert sim.gas_volume.shape == (1, 1, 1)  # gas arrays are placeholders, never read
