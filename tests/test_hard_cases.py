"""Hard cases stay stable (issue #5): small, fast versions of the scenes that break simulators.

Each asserts: no NaN or Inf, no particle outside the domain, gas mass accounted for exactly, and a
physical bound on speed or energy stated next to it.
"""

import math

import numpy as np
import pytest
import warp as wp

from warp_mpm_bubbles import Box, Domain, Material, Output, Scene, SolverSettings, Sphere
from warp_mpm_bubbles.diagnostics import bubble_volumes
from warp_mpm_bubbles.scene.effects import SubgridBubbles
from warp_mpm_bubbles.core.simulation import Simulation

wp.config.quiet = True
G = 9.81
P_ATM = 101325.0
RHO_WATER = 1000.0


def make(tmp_path, size, dx, shapes, materials=None, walls="free_slip", gravity=None, **solver):
    return Scene(
        domain=Domain(size=size, cell_size=dx, walls=walls, gravity=gravity),
        materials=materials or {"water": Material("water")},
        shapes=shapes,
        solver=SolverSettings(**solver),
        output=Output(path=str(tmp_path / "hard.usdc"), fps=60),
    )


def assert_sane(sim, budget0=None):
    p = sim.particles_numpy(include_retired=True)
    assert np.isfinite(p["positions"]).all() and np.isfinite(p["velocities"]).all()
    assert (p["positions"] >= 0).all() and (p["positions"] <= np.array(sim.grid.domain_size)).all()
    assert sim.stats.cg_unconverged == 0
    if budget0 is not None:
        assert sim.gas_budget()["total"] == pytest.approx(budget0["total"], rel=1e-12)


def energy(sim):
    """Kinetic plus potential energy of the active particles (J; per metre of slab in 2D)."""
    p = sim.particles_numpy()
    g = np.array(sim.scene.domain.gravity + (0.0,) * (3 - sim.grid.dim))
    kinetic = 0.5 * (p["mass"] * (p["velocities"] ** 2).sum(1)).sum()
    return kinetic - (p["mass"] * (p["positions"] @ g)).sum()


def air_and_water(sigma=0.0):
    return {"water": Material("water", surface_tension=sigma), "air": Material("air", kind="gas")}


def is_gas(sim, p):
    return np.array([m.is_gas for m in sim.scene.materials.values()])[p["material"]]


def bubbles(sim):
    """Gas volume of each connected bubble (diagnostics.bubble_volumes), largest first."""
    p = sim.particles_numpy()
    return bubble_volumes(p["positions"], is_gas(sim, p), p["volume"], sim.grid.dx, sim.grid.cells, sim.grid.dim)


def run(sim, t_end, probe):
    """Advance to t_end in CFL-limited steps (the last one shortened to land on t_end), probing after each."""
    while sim.time < t_end:
        sim.advance_to(min(t_end, sim.time + sim.stable_dt()))
        probe(sim)


def test_closed_tank_without_free_surface(tmp_path):
    # Full of water, all walls closed: the pressure system is singular (pure Neumann). The
    # solver must project out the constant and the water must stay still.
    sim = Simulation(make(tmp_path, (0.2, 0.2), 0.0125, [Box("water", (0.0, 0.0), (0.2, 0.2))]), "cpu")
    for _ in range(20):
        sim.step(sim.stable_dt())
    assert_sane(sim)
    assert np.abs(sim.particles_numpy()["velocities"]).max() < 0.01 * math.sqrt(G * 0.2)


def test_water_striking_a_wall_at_10_m_per_s(tmp_path):
    # Energy bound: an impact only dissipates, so kinetic + potential energy may not grow (1%
    # allowance for the transfer's rounding). Speed: the impact's pressure impulse throws jets
    # faster than the impact itself (measured 10.7 m/s), so the bound is the energetic one: no
    # particle can carry more than the whole system's energy, v < sqrt(2 E / m_particle).
    scene = make(tmp_path, (0.4, 0.2), 0.01, [Box("water", (0.25, 0.0), (0.35, 0.1), velocity=(10.0, 0.0))])
    sim = Simulation(scene, "cpu")
    e0 = energy(sim)
    sim.advance_to(0.05)
    assert_sane(sim)
    assert energy(sim) <= 1.01 * e0
    p = sim.particles_numpy()
    assert np.linalg.norm(p["velocities"], axis=1).max() < math.sqrt(2 * e0 / p["mass"].max())


def test_requested_step_100_times_the_stable_one_is_clamped(tmp_path):
    scene = make(tmp_path, (0.3, 0.2), 0.01, [Box("water", (0.0, 0.0), (0.1, 0.15))], max_dt=10.0)
    sim = Simulation(scene, "cpu")
    stable = sim.stable_dt()
    assert scene.solver.max_dt > 100 * stable
    sim.advance_to(0.1)
    assert_sane(sim)
    assert max(sim.stats.dt_history) <= 0.5 * 0.01 / math.sqrt(G * 0.01) * (1 + 1e-9)  # the CFL cap


def test_particles_starting_exactly_on_walls(tmp_path):
    sim = Simulation(make(tmp_path, (0.2, 0.2), 0.01, [Box("water", (0.0, 0.0), (0.2, 0.1))]), "cpu")
    x = sim.particles.x.numpy()
    x[:50, 0], x[50:100, 0], x[100:150, 1] = 0.0, 0.2, 0.0  # on the left, right and bottom walls
    sim.particles.x = wp.array(x, dtype=wp.vec3, device=sim.device)
    sim.advance_to(0.1)
    assert_sane(sim)


@pytest.mark.parametrize("gas_density", [1.0, 0.1], ids=["1000:1", "10000:1"])
def test_density_ratio(tmp_path, gas_density):
    # A bubble near the bottom at 1000:1 and 10000:1 for 0.05 s; speed bound sqrt(2 g H).
    scene = make(tmp_path, (0.1, 0.1), 0.0025,
                 [Box("water", (0.0, 0.0), (0.1, 0.08)), Sphere("air", (0.05, 0.025), 0.012)],
                 materials={"water": Material("water"), "air": Material("air", kind="gas", density=gas_density)})
    sim = Simulation(scene, "cpu")
    budget0 = sim.gas_budget()
    sim.advance_to(0.05)
    assert_sane(sim, budget0)
    assert np.linalg.norm(sim.particles_numpy()["velocities"], axis=1).max() < math.sqrt(2 * G * 0.08)


def test_bubble_touching_a_wall_and_the_free_surface(tmp_path):
    # The bubble straddles the surface in a corner: its exposed gas vents, none is lost.
    scene = make(tmp_path, (0.1, 0.1), 0.0025,
                 [Box("water", (0.0, 0.0), (0.1, 0.06)), Sphere("air", (0.012, 0.055), 0.012)],
                 materials={"water": Material("water"), "air": Material("air", kind="gas")})
    sim = Simulation(scene, "cpu")
    budget0 = sim.gas_budget()
    sim.advance_to(0.05)
    assert_sane(sim, budget0)
    assert sim.gas_budget()["vented"] > 0.0


def test_gas_only_closed_box(tmp_path):
    # Air alone in a closed box: pressure pinned by the gas term, nothing moves more than the
    # weight of 1.2 kg/m^3 of air can make it (hydrostatic air: speeds far below 1 cm/s).
    scene = make(tmp_path, (0.1, 0.1), 0.005, [Box("air", (0.0, 0.0), (0.1, 0.1))],
                 materials={"air": Material("air", kind="gas")})
    sim = Simulation(scene, "cpu")
    budget0 = sim.gas_budget()
    sim.advance_to(0.05)
    assert_sane(sim, budget0)
    assert np.abs(sim.particles_numpy()["velocities"]).max() < 0.01


@pytest.mark.parametrize("field, bad", [("v", np.nan), ("x", np.inf), ("v", -np.inf)])
def test_nan_in_the_state_stops_with_a_named_error(tmp_path, field, bad):
    # p2g's test for finite values (boundary.finite) on each kind: a NaN, and an infinity either way.
    from warp_mpm_bubbles.core.simulation import SimulationError

    sim = Simulation(make(tmp_path, (0.2, 0.2), 0.01, [Box("water", (0.0, 0.0), (0.2, 0.1))]), "cpu")
    values = getattr(sim.particles, field).numpy()
    values[7, 1] = bad
    setattr(sim.particles, field, wp.array(values, dtype=wp.vec3, device=sim.device))
    with pytest.raises(SimulationError, match=r"step 1 .*1 particles entered p2g with a non-finite"):
        sim.step(sim.stable_dt())


# ----------------------------------------------------------------------------- two bubbles merging
@pytest.mark.parametrize("sigma", [
    0.072,
    pytest.param(0.0, marks=pytest.mark.xfail(strict=True, reason=(
        "measured (2026-12-04, 0148f62): without surface tension the bubbles touch at t ~ 0.03 s and "
        "particles then reach 2.17 m/s > sqrt(2 g H) = 1.17 m/s; the energy no longer rises (at most "
        "-5.7e-7 J from its start; it rose 9.6e-6 J before the void pass) and one bubble holds 0.86 of "
        "the gas at 0.08 s"))),
], ids=["tension", "no_tension"])
def test_two_bubbles_rise_touch_and_merge(tmp_path, sigma):
    # Two discs of 4.8 cells radius, one above the other with a two-cell film of water
    # between them; the lower one rises in the upper one's wake and catches it (t ~ 0.06 s with
    # water's tension: the film drains first).
    dx, radius, depth = 0.00125, 0.006, 0.07
    lower, upper = (0.025, 0.02), (0.025, 0.02 + 2 * radius + 2 * dx)
    scene = make(tmp_path, (0.05, 0.08), dx,
                 [Box("water", (0.0, 0.0), (0.05, depth)), Sphere("air", lower, radius), Sphere("air", upper, radius)],
                 materials=air_and_water(sigma))
    sim = Simulation(scene, "cpu")
    budget0 = sim.gas_budget()
    assert len(bubbles(sim)) == 2
    # Energy: kinetic + potential may only grow by what the surfaces give up. Merging frees at most
    # all of both bubbles' surface energy, sigma * perimeter * slab thickness; the gas starts at
    # ambient pressure (J = 1), so its compression energy starts at zero and can only be returned.
    e0 = energy(sim)
    surface_energy = sigma * 2 * (2 * math.pi * radius) * dx
    # Speed: gravity gives no parcel more than free fall over the water's depth, sqrt(2 g H); the
    # fastest capillary flow is a film retracting (Taylor-Culick, sqrt(2 sigma / (rho h))), for the
    # thinnest film the grid holds, h = one cell.
    speed_bound = math.sqrt(2 * G * depth) + math.sqrt(2 * sigma / (RHO_WATER * dx))
    worst = {"energy": -math.inf, "speed": 0.0}

    def probe(sim):
        worst["energy"] = max(worst["energy"], energy(sim) - e0)
        worst["speed"] = max(worst["speed"], np.linalg.norm(sim.particles_numpy()["velocities"], axis=1).max())

    run(sim, 0.08, probe)
    assert_sane(sim, budget0)
    assert worst["energy"] <= surface_energy, worst
    assert worst["speed"] < speed_bound, worst
    # One bubble at the end: each started with under half the gas volume (measured 0.47 and 0.45:
    # gas in liquid-dominated interface cells belongs to no bubble), so a bubble holding 3/4 of it
    # is the two merged.
    assert bubbles(sim)[0] > 0.75 * sim.gas_budget()["volume"]


# ------------------------------------------------------------------ a bubble bursting at the surface
@pytest.mark.xfail(strict=False, reason=(
    "issue #12: chaotic in the volume correction's tau. With best-centred height columns it passes at the "
    "default 10 ms (energy 1.8e-6 J against the bound 3.4e-6 J, 0.81 m/s against 1.23) and at 3 ms, but at "
    "5 and 20 ms the rupture throws particles at 23 and 42 m/s (uncentred columns failed at 10 ms on the "
    "energy, 7.2e-6 J); docs/design.md#limitations"))
def test_bubble_bursting_at_the_free_surface(tmp_path):
    # A disc of 4.8 cells radius under 1.6 cells of water: it rises, the film ruptures and the gas
    # vents to the atmosphere (booked, so inside + vented stays the seeded mass).
    dx, radius, depth, sigma = 0.00125, 0.006, 0.04, 0.072
    scene = make(tmp_path, (0.06, 0.06), dx,
                 [Box("water", (0.0, 0.0), (0.06, depth)), Sphere("air", (0.03, depth - radius - 0.002), radius)],
                 materials=air_and_water(sigma))
    sim = Simulation(scene, "cpu")
    budget0 = sim.gas_budget()
    # The same bounds as two bubbles merging (above): energy may grow by at most the bubble's
    # surface energy; speeds stay under free fall over the depth plus a one-cell film's retraction.
    e0 = energy(sim)
    surface_energy = sigma * 2 * math.pi * radius * dx
    speed_bound = math.sqrt(2 * G * depth) + math.sqrt(2 * sigma / (RHO_WATER * dx))
    worst = {"energy": -math.inf, "speed": 0.0}

    def probe(sim):
        worst["energy"] = max(worst["energy"], energy(sim) - e0)
        worst["speed"] = max(worst["speed"], np.linalg.norm(sim.particles_numpy()["velocities"], axis=1).max())

    run(sim, 0.1, probe)
    assert_sane(sim, budget0)
    assert sim.gas_budget()["vented"] > 0.5 * budget0["total"]  # it burst: most of the gas left
    assert worst["energy"] <= surface_energy, worst
    assert worst["speed"] < speed_bound, worst


# ------------------------------------------------------- a bubble compressed tenfold and released
@pytest.mark.parametrize("max_dt,t_end", [
    (None, 0.05),
    # Steps that resolve the expansion (2e-5 s, a sixth of R0 sqrt(rho / dp) = 1.3e-4 s): measured
    # 0.89 W0 gained and the liquid's RMS speed at 0.94 of its bound. (Before the gas took its
    # cells' volume change, update_gas_J, this gained 1.23 W0 and failed: the compression was
    # booked on liquid particles and the gas's J lagged.) CFL steps: 0.04 W0, 0.19 of the bound.
    (2e-5, 0.0015),
], ids=["cfl_steps", "resolved_steps"])
def test_bubble_compressed_tenfold_and_released(tmp_path, max_dt, t_end):
    # Gas seeded at 10 atm (gauge 9 atm: J0 = 0.1) in a tank with a free surface: it expands
    # violently to ten times its seeded volume. The default steps follow the CFL limit only (the gas
    # is implicit), so the first step, 8 ms, is 60 times the expansion time.
    dx, radius = 0.0025, 0.004
    scene = make(tmp_path, (0.1, 0.2), dx,
                 [Box("water", (0.0, 0.0), (0.1, 0.1)), Sphere("air", (0.05, 0.03), radius, pressure=9 * P_ATM)],
                 materials=air_and_water(), max_dt=max_dt)
    sim = Simulation(scene, "cpu")
    budget0 = sim.gas_budget()
    p = sim.particles_numpy()
    gas = is_gas(sim, p)
    assert p["J"][gas] == pytest.approx(0.1, rel=1e-6)
    # Energy: isothermal gas (p V = p0 V0) expanding from V0 to its rest volume 10 V0 against the
    # atmosphere does work W0 = p0 V0 ln 10 - P_atm (10 V0 - V0) = P_atm V0 (10 ln 10 - 9) on the
    # liquid (incompressible: the free surface moves out by what the bubble gains); past 10 V0 the
    # gas takes energy back. So kinetic + potential energy can never exceed E0 + W0, and the
    # liquid's RMS speed is bounded by that energy all being its kinetic energy.
    V0 = p["volume"][gas].sum()
    W0 = P_ATM * V0 * (10 * math.log(10) - 9)
    e0 = energy(sim)
    liquid_mass = p["mass"][~gas].sum()
    worst = {"energy": -math.inf, "rms_over_bound": 0.0}

    def probe(sim):
        p = sim.particles_numpy()
        liquid = ~is_gas(sim, p)
        e = energy(sim)
        kinetic_liquid = 0.5 * (p["mass"][liquid] * (p["velocities"][liquid] ** 2).sum(1)).sum()
        rms = math.sqrt(2 * kinetic_liquid / liquid_mass)
        bound = math.sqrt(2 * (e0 + W0 - (e - kinetic_liquid)) / liquid_mass)
        worst["energy"] = max(worst["energy"], (e - e0) / W0)
        worst["rms_over_bound"] = max(worst["rms_over_bound"], rms / bound)

    run(sim, t_end, probe)
    assert_sane(sim, budget0)
    assert worst["energy"] <= 1.0, worst
    assert worst["rms_over_bound"] <= 1.0, worst


# ------------------------------------------------------------------------------- sloshing tank
@pytest.mark.parametrize("steps", [1_000, pytest.param(10_000, marks=pytest.mark.slow)])
def test_sloshing_tank_long_run(tmp_path, steps):
    # A 2D tank of 16 x 8 cells, water 4 cells deep on average, its surface tilted (slope 0.15,
    # 2.8 to 5.2 cells deep) and released: it sloshes, and over thousands of steps must neither
    # gain energy nor lose volume. The tilt is a staircase of boxes half a cell wide (the particle
    # spacing at 4 per cell; the scene refuses narrower ones, which would seed nothing).
    cells, width, slope = (16, 8), 0.4, 0.15
    dx = width / cells[0]
    mean_depth = cells[1] * dx / 2
    n = 2 * cells[0]
    steps_of_water = [Box("water", (i * width / n, 0.0), ((i + 1) * width / n,
                                                           mean_depth + slope * ((i + 0.5) * width / n - width / 2)))
                      for i in range(n)]
    sim = Simulation(make(tmp_path, (width, cells[1] * dx), dx, steps_of_water), "cpu")
    # The tilt's energy above the flat surface: rho g dz / 2 * integral (h - h_mean)^2 dx.
    tilt_energy = RHO_WATER * G * dx * slope**2 * width**3 / 24
    e0, v0 = energy(sim), sim.liquid_volume()
    # Speed: no parcel falls further than from the highest surface point to the floor.
    speed_bound = math.sqrt(2 * G * (mean_depth + slope * width / 2))
    worst = {"energy": -math.inf, "volume": 0.0, "speed": 0.0}
    for step in range(1, steps + 1):
        sim.step(sim.stable_dt())
        # Energy: inviscid water between free-slip walls has no source, so E(t) <= E0; the
        # allowance, 1% of the tilt's energy, is far above the rounding of the float32 sums
        # (about 1e-7 J) and far below any real growth.
        worst["energy"] = max(worst["energy"], (energy(sim) - e0) / tilt_energy)
        worst["speed"] = max(worst["speed"], np.linalg.norm(sim.particles_numpy()["velocities"], axis=1).max())
        if step % 100 == 0:
            worst["volume"] = max(worst["volume"], abs(sim.liquid_volume() / v0 - 1))
    assert_sane(sim)
    assert worst["energy"] <= 0.01, worst
    # Volume: the drift may move the mean level by less than a tenth of a cell (2.5% here).
    assert worst["volume"] < 0.1 * dx / mean_depth, worst
    assert worst["speed"] < speed_bound, worst


# --------------------------------------------------------------------- bubbles smaller than a cell
@pytest.mark.parametrize("interface,subgrid", [("sharp", False), ("baseline", False), ("sharp", True)],
                         ids=["sharp", "baseline", "subgrid_effect"])
def test_bubbles_smaller_than_a_cell(tmp_path, interface, subgrid):
    # Seven gas discs of radius 0.4 dx (1 to 4 particles each) at assorted offsets inside their
    # cells, 2.4 cm under the surface. Neither interface treatment resolves them (measured: the
    # sharp one leaves them in place, the baseline one lifts them at a few cm/s); with
    # [effects.subgrid_bubbles] they become Lagrangian bubbles with buoyancy and drag. Each way they
    # must stay finite and keep their gas.
    dx = 0.0025
    centres = [(0.02 + 0.01 * i + (0.13 * i % 1) * dx, 0.02 + (0.37 * i % 1) * dx) for i in range(7)]
    scene = make(tmp_path, (0.1, 0.1), dx,
                 [Box("water", (0.0, 0.0), (0.1, 0.08))] + [Sphere("air", c, 0.4 * dx) for c in centres],
                 materials=air_and_water(), interface=interface)
    if subgrid:
        scene.effects = {"subgrid_bubbles": SubgridBubbles()}
    sim = Simulation(scene, "cpu")
    budget0 = sim.gas_budget()
    sim.advance_to(0.1)
    assert_sane(sim, budget0)
    # Speed bound: free fall over the water's depth, sqrt(2 g H) = 1.25 m/s (the sub-grid bubbles,
    # 2.4 mm across, rise at up to 0.27 m/s; the others move at under 0.06 m/s).
    assert np.linalg.norm(sim.particles_numpy()["velocities"], axis=1).max() < math.sqrt(2 * G * 0.08)
