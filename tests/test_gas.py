"""Compressible gas in the two-phase pressure system (docs/design.md: #pressure-system, #validation), on Warp's CPU device."""

import math

import numpy as np
import pytest
import warp as wp

from benchmarks.cases import first_minimum, radius_history
from warp_mpm_bubbles import Box, Cylinder, Domain, Material, Output, Scene, SolverSettings, Sphere
from warp_mpm_bubbles.core.gas_law import cell_compressibility
from warp_mpm_bubbles.core.grid import FLUID, INTERFACE_SHARP
from warp_mpm_bubbles.core.kernel_args import face_field
from warp_mpm_bubbles.core.transfer_kernels import gas_volume_rate
from warp_mpm_bubbles.core.simulation import Simulation

wp.config.quiet = True
P_ATM = 101325.0
AIR_AND_WATER = lambda: {"water": Material("water"), "air": Material("air", kind="gas")}  # noqa: E731


# ------------------------------------------------- Minnaert: a 2D bubble breathing in a liquid disc
R0, R_INF = 0.01, 0.05
OMEGA_2D = math.sqrt(2 * P_ATM / (1000.0 * R0**2 * math.log(R_INF / R0)))  # docs/design.md#validation, sigma = 0
STEPS_PER_PERIOD = 40


def upward_crossings(t, V):
    """Times where V rises through its mean (linear interpolation between samples)."""
    x = V - V.mean()
    return [t[i] - x[i] * (t[i + 1] - t[i]) / (x[i + 1] - x[i]) for i in range(len(x) - 1) if x[i] < 0 <= x[i + 1]]


def breathe(scene, period):
    """Run 3.2 periods, sampling the gas volume STEPS_PER_PERIOD times a period."""
    sim = Simulation(scene, "cpu")
    budget0 = sim.gas_budget()
    times, volumes = [], []
    while sim.time < 3.2 * period:
        sim.advance_to(sim.time + period / STEPS_PER_PERIOD)
        times.append(sim.time)
        volumes.append(sim.gas_budget()["volume"])
    return dict(sim=sim, t=np.array(times), V=np.array(volumes), budget0=budget0)


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
    return dict(breathe(scene, period), period=period)


def test_bubble_breathes_at_the_2d_minnaert_frequency(breathing):
    # Reference: omega0^2 = 2 p0 / (rho R0^2 ln(Rinf/R0)) (isothermal, sigma = 0) = 178.6 Hz.
    # Measured -1.5% at 8 cells per radius (2026-12-05; -1.52% just before a gas cell's compressibility
    # took the gas's share of the cell, -0.9% before the volume correction became a rate; seed spread
    # about 1%, benchmarks/results/accuracy_vs_time/cpu.md); it was
    # -7.6% before the gas took its cells' volume change (update_gas_J), which the old 10% bound
    # allowed. 3% bounds the measurement with the seed noise.
    up = upward_crossings(breathing["t"], breathing["V"])
    assert len(up) >= 3, up
    f_sim = 1.0 / np.diff(up).mean()
    f_ref = OMEGA_2D / (2 * math.pi)
    assert abs(f_sim / f_ref - 1.0) < 0.03, (f_sim, f_ref)


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
    # Speed bound (issue #17 tightened it from the free-fall speed over the depth, 1.66 m/s): the
    # fastest particle at 0.1 s, the jet under the rising bubble, measured 0.416 and 0.464 m/s
    # (sharp, seeds 0 and 1), 0.383 and 0.410 (baseline; 2026-12-05, earlier up to 0.473); bound
    # 0.7 m/s, 1.5 times the largest.
    end, sim = rising["end"], rising["sim"]
    assert np.isfinite(end["positions"]).all() and np.isfinite(end["velocities"]).all()
    assert (end["positions"] >= 0).all() and (end["positions"] <= np.array(sim.grid.domain_size)).all()
    top = np.linalg.norm(end["velocities"], axis=1).max()
    print(f"rising bubble ({sim.scene.solver.interface}): fastest particle {top:.3f} m/s")
    assert top < 0.7


def test_rising_bubble_rises(rising):
    is_gas = lambda p: p["material"] == 1  # noqa: E731
    y0 = rising["start"]["positions"][is_gas(rising["start"]), 1].mean()
    active = rising["sim"].particles_numpy()
    y1 = active["positions"][is_gas(active), 1].mean()
    # Measured 15.9 and 17.5 mm in 0.1 s (sharp, seeds 0 and 1), 16.0 and 16.8 (baseline; 2026-12-05,
    # earlier 17.6 and 17.2); bound
    # 12-22 mm, the seed spread with 25% either side (was: more than 5 mm).
    print(f"rising bubble: gas centroid rose {1000 * (y1 - y0):.1f} mm in 0.1 s")
    assert 0.012 < y1 - y0 < 0.022


def test_rising_bubble_gas_mass_is_exactly_accounted_for(rising):
    budget = rising["sim"].gas_budget()
    assert budget["total"] == pytest.approx(rising["budget0"]["total"], rel=1e-12)
    np.testing.assert_array_equal(rising["end"]["ids"], rising["start"]["ids"])


@pytest.mark.slow
def test_a_bubble_rising_five_diameters_stays_a_bubble_without_water_inside(tmp_path):
    # Issue #3's bar: the default (sharp interface, the liquid reading its own velocity field) keeps
    # the liquid found at least one cell deep inside the gas under 1% of the gas volume until the
    # bubble has risen five diameters. 2D, 6 cells per radius (CI size; benchmarks/validation/rising_bubble_leak.py
    # runs 8 and 3D): measured 0.00% in every frame at both, where one shared velocity field peaked
    # at 1.13% (6 cells) and 2.31% (8 cells), and the published baseline broke the bubble up.
    # And it stays a bubble: with gas films retracting (the default) the largest bubble holds 77.1%
    # of the gas at the end and 0.66% lies dispersed in the water (re-measured 2026-12-05 at c0f4e15;
    # earlier 86.6% and 0.22%, at 8 cells 86.8% and 0.25%; 66.7% and 0.66%, 72% and 0.9% while the
    # bubble's own gas in the cells the interface crosses retracted too); with gas_films = "passive"
    # 40.4% and 28.7% (earlier 31% and 36%; 8 cells: 57% and 19.7%). Bounds 50% and 5% lie between.
    from warp_mpm_bubbles.diagnostics import bubble_volumes, gas_centroid_and_diameter, phase_leak

    R = 0.01
    scene = Scene(
        domain=Domain(size=(0.08, 0.22), cell_size=R / 6, walls="free_slip"),
        materials={"water": Material("water", surface_tension=0.072), "air": Material("air", kind="gas")},
        shapes=[Box("water", min=(0.0, 0.0), max=(0.08, 0.20)), Sphere("air", center=(0.04, 0.025), radius=R)],
        output=Output(path=str(tmp_path / "r.usdc"), fps=60),
    )
    sim = Simulation(scene, "cpu")
    assert sim.scene.solver.liquid_velocity == "own"

    def measure():
        p = sim.particles_numpy()
        gas = p["material"] == 1
        height = gas_centroid_and_diameter(p["positions"], gas, p["volume"] / sim.grid.dx, 2)[0][1]
        return height, phase_leak(p["positions"], gas, p["volume"], sim.grid.dx, sim.grid.interior, 2)

    y0, _ = measure()
    worst = 0.0
    while sim.time < 0.9:
        sim.advance_frame()
        height, leak = measure()
        worst = max(worst, leak["liquid_in_gas"])
        if height - y0 >= 5 * 2 * R:
            break
    assert height - y0 >= 5 * 2 * R, "the bubble did not rise five diameters in 0.9 s"
    assert sim.gas_budget()["vented"] == 0.0  # still under water: the leak is measured on the whole bubble
    assert worst < 0.01, worst
    assert leak["gas_in_liquid"] < 0.05, leak
    p = sim.particles_numpy()
    gas = p["material"] == 1
    largest = bubble_volumes(p["positions"], gas, p["volume"], sim.grid.dx, sim.grid.interior, 2)[0]
    assert largest / p["volume"][gas].sum() > 0.5


@pytest.mark.slow
def test_a_3d_cap_bubble_rises_at_the_davies_taylor_speed(tmp_path):
    # docs/design.md#validation: a large bubble (d_e = 2 cm, Eotvos 54) rises at 0.711 sqrt(g d_e) = 0.315 m/s in
    # open water; in this 6 cm square tank (d/D = 0.33) the wall factor 1.13 exp(-d/D) (Wallis
    # 1969; Clift, Grace & Weber ch. 9) gives 0.255 m/s. Started as Davies & Taylor's 50 degree
    # cap of the same volume (a sphere at rest is pierced by its wake first), 4 cells per radius
    # (CI size), speed of the gas centroid from 0.1 s (past the start-up) to 0.2 s.
    # Measured -0.4% here (2026-12-05; -2% before a gas cell's compressibility took the gas's share
    # of the cell), and by benchmarks/validation/rising_bubble_leak.py --dim 3 --shape cap over five diameters
    # -8% at 5 cells per radius and +5% at 7: the bound, 15%, covers that spread with the wall
    # factor's own scatter. It stays one bubble meanwhile (largest 69% at 0.2 s; 66% before) with no
    # water inside (0.00%).
    from warp_mpm_bubbles.diagnostics import bubble_volumes, gas_centroid_and_diameter, phase_leak

    R, width, depth = 0.01, 0.06, 0.18
    c = math.cos(math.radians(50.0))
    r_cap = R * (4.0 / ((1.0 - c) ** 2 * (2.0 + c))) ** (1.0 / 3.0)  # the ball the cap is cut from
    centre = (width / 2, 1.02 * r_cap, width / 2)
    scene = Scene(
        domain=Domain(size=(width, depth + 0.02, width), cell_size=R / 4, walls="free_slip"),
        materials={"water": Material("water", surface_tension=0.072), "air": Material("air", kind="gas")},
        shapes=[Box("water", min=(0.0, 0.0, 0.0), max=(width, depth, width)), Sphere("air", centre, r_cap),
                Box("water", min=(0.0, 0.0, 0.0), max=(width, centre[1] + r_cap * c, width))],
        output=Output(path=str(tmp_path / "cap.usdc"), fps=60),
    )
    sim = Simulation(scene, "cpu")
    budget0 = sim.gas_budget()
    d_e = (6.0 * budget0["volume"] / math.pi) ** (1.0 / 3.0)
    assert d_e == pytest.approx(2 * R, rel=0.02)  # the cap holds the sphere's volume
    times, heights = [], []
    while sim.time < 0.2 - 1e-9:
        sim.advance_frame()
        if sim.time >= 0.1 - 1e-9:
            p = sim.particles_numpy()
            gas = p["material"] == 1
            times.append(sim.time)
            heights.append(gas_centroid_and_diameter(p["positions"], gas, p["volume"], 3)[0][1])
    speed = np.polyfit(times, heights, 1)[0]
    davies_taylor = 0.711 * math.sqrt(9.81 * d_e) * 1.13 * math.exp(-d_e / width)
    assert speed == pytest.approx(davies_taylor, rel=0.15)
    leak = phase_leak(p["positions"], gas, p["volume"], sim.grid.dx, sim.grid.interior, 3)
    assert leak["liquid_in_gas"] < 0.01, leak
    largest = bubble_volumes(p["positions"], gas, p["volume"], sim.grid.dx, sim.grid.interior, 3)[0]
    assert largest / p["volume"][gas].sum() > 0.5


def test_liquid_only_scene_runs_no_gas_stage(tmp_path):
    scene = Scene(domain=Domain(size=(0.1, 0.1), cell_size=0.01), materials={"water": Material("water")},
                  shapes=[Box("water", min=(0.0, 0.0), max=(0.1, 0.05))], output=Output(path=str(tmp_path / "w.usdc")))
    sim = Simulation(scene, "cpu")
    sim.step(sim.stable_dt())
    assert not sim.has_gas and "vent" not in sim.timer.phases_run
    assert sim.fields.gas_volume.shape == (1, 1, 1)  # gas arrays are placeholders, never read


# ------------------------------------- isothermal collapse to the first radius minimum (docs/design.md#rayleigh-plesset)
# Rows of tests/data/rayleigh_plesset_isothermal_collapse_reference.csv (p_g0/p_inf = 0.2, inviscid,
# sigma = 0; units R0, rho, p_inf): t, R_3D, R_2D with a free outer surface at Rout0 = 10 R0; and the
# first minima in its header. They check the integrator that gives the reference for the smaller
# annulus simulated below.
RP_TABLE = [(0.50, 0.893942, 0.956038), (1.00, 0.433708, 0.816791), (1.50, 0.753384, 0.548315),
            (1.80, 0.922190, 0.267607), (1.90, 0.954892, 0.126627), (1.94, 0.965315, 0.083752),
            (1.95, 0.967695, 0.085424), (2.00, 0.978272, 0.149284), (2.10, 0.993036, 0.285838),
            (2.50, 0.970742, 0.625590), (3.00, 0.723018, 0.858281), (4.00, None, 0.997704),
            (6.00, None, 0.303422), (8.00, None, 0.990800)]
RP_FIRST_MINIMUM = {3: (1.11585, 0.19108), 2: (1.94252, 0.08353)}
P_G0 = 0.2  # initial gas pressure over the ambient one
R_OUT0 = 3.0  # outer radius of the liquid annulus, in R0 (the table's 10 R0 would need 9x the cells)


def test_rayleigh_plesset_integrator_reproduces_the_reference_table():
    # RK4 with steps of 1e-3: measured, the table to 5e-7 (its 6 decimals), the header minima to
    # 2e-5 (its 5 decimals); bounds 1e-5 and 1e-4, far below the simulation's errors.
    for dim, column, r_out0 in ((3, 1, None), (2, 2, 10.0)):
        t, R = radius_history(P_G0, dim, r_out0, t_end=8.0 if dim == 2 else 3.0)
        rows = np.array([(row[0], row[column]) for row in RP_TABLE if row[column] is not None])
        assert np.abs(np.interp(rows[:, 0], t, R) - rows[:, 1]).max() < 1e-5, dim
        t_min, R_min = first_minimum(t, R)
        assert (t_min, R_min) == pytest.approx(RP_FIRST_MINIMUM[dim], abs=1e-4), dim


def collapse_run(cells_per_radius, out_dir):
    """A bubble of radius R0 seeded at 0.2 p_inf in a free liquid annulus of outer radius 3 R0, no
    gravity, sampled every step until it has passed its first minimum. Returns t / t_unit, R / R0."""
    dx = R0 / cells_per_radius
    L = 2 * (R_OUT0 + 0.5) * R0
    u_p = math.sqrt(P_ATM / 1000.0)  # the speed scale of the pressure-driven flow, sqrt(p_inf/rho)
    scene = Scene(
        domain=Domain(size=(L, L), cell_size=dx, gravity=(0.0, 0.0), walls="open", ambient_pressure=P_ATM),
        materials=AIR_AND_WATER(),
        shapes=[Cylinder("water", center=(L / 2, L / 2), radius=R_OUT0 * R0),
                Cylinder("air", center=(L / 2, L / 2), radius=R0, pressure=(P_G0 - 1.0) * P_ATM)],  # gauge
        # The flow starts from rest, where the CFL limit says nothing: cap the step at the CFL step
        # of the speed scale (0.5 dx / u_p, 0.03 t_unit at 16 cells); near the minimum the CFL
        # limit of the real speed (up to 3 u_p) takes over.
        solver=SolverSettings(max_dt=0.5 * dx / u_p),
        output=Output(path=str(out_dir / "c.usdc")),
    )
    sim = Simulation(scene, "cpu")
    t_unit = R0 * math.sqrt(1000.0 / P_ATM)
    # The 2D run is a slab one cell (dx) thick: the gas volume is its area times dx.
    radius = lambda: math.sqrt(sim.gas_budget()["volume"] / (math.pi * dx)) / R0  # noqa: E731
    t, R = [0.0], [radius()]
    budget0 = sim.gas_budget()
    while (min(R) > 0.3 or R[-1] < 0.3) and sim.time < 3.0 * t_unit:  # until past the minimum
        sim.advance_to(sim.time + sim.stable_dt())
        t.append(sim.time / t_unit)
        R.append(radius())
    return dict(sim=sim, t=np.array(t), R=np.array(R), budget0=budget0)


# Measured (seed 0), errors of the first minimum against RK4 of the 2D equation at Rout0 = 3 R0
# (t = 1.4178 t_unit, R = 0.08353 R0; R_min does not depend on Rout0), steps capped at 0.5 dx/u_p:
#   cells/R0    8       12      16       24       32
#   t_min     +4.25%  +1.99%  +0.70%   +0.02%   -0.19%
#   R_min     +76%    +54%    +40%     +28%     +21%
# All minima are shallow; R_min (1.3 cells at 16 per radius) converges at about order 1 and
# depends on the step about as much as on the grid (caps 0.5/0.25/0.125 dx/u_p moved it by up to
# 15 points before the change below). Each bound lies between the measured error and that of
# the next coarser resolution. History: before the gas took its cells' volume change
# (update_gas_J; the interpolated divergence had booked most of the compression on liquid
# particles), t_min was +2.75% / +0.77% and R_min +31% / +13% at 16 / 32 cells: the change
# made the timing four times more accurate (and the Minnaert frequency eight times) and the
# depth of this under-resolved minimum worse.
# Issue #12 (volume correction as a rate, the gas_expansion step limit): t_min +1.48% / +1.39%,
# R_min +25% / +20% at 16 / 32 cells (with volume_relaxation_time = 1 ms: +1.05% / +1.16%, +20% /
# +17%; without the limit's 10% volume change per step, +3.0% and +43% at 16). The old share per
# step was, at these 16-32 microsecond steps, a relaxation time of 0.05-0.1 ms, 100x the default:
# the timing's -0.19% at 32 cells leaned on it. The t_min bound at 32 is widened to 2% accordingly.
# Re-measured 2026-12-05 (a gas cell's compressibility the gas's share of the cell): +1.43% / +1.39%,
# +25% / +19% at 16 / 32 cells.
COLLAPSE_TOLERANCE = {16: (0.02, 0.50), 32: (0.02, 0.25)}  # cells/R0: (t_min, R_min), relative


@pytest.fixture(scope="module", params=[16, pytest.param(32, marks=pytest.mark.slow)])
def collapse(request, tmp_path_factory):
    run = collapse_run(request.param, tmp_path_factory.mktemp("collapse"))
    t_ref, R_ref = first_minimum(*radius_history(P_G0, 2, R_OUT0, t_end=3.0))
    return dict(run, cells=request.param, t_ref=t_ref, R_ref=R_ref)


def test_collapse_starts_from_the_seeded_bubble(collapse):
    # R = sqrt(V / (pi dx)) of the seeded gas is R0 up to the seeding noise (measured 0.9992-1.0012
    # at 16 cells for seeds 0-3): checks the slab-volume reading that the collapse test relies on.
    assert collapse["R"][0] == pytest.approx(1.0, abs=5e-3)
    budget = collapse["sim"].gas_budget()
    assert budget["total"] == pytest.approx(collapse["budget0"]["total"], rel=1e-12)
    assert budget["vented"] == 0.0


def test_first_collapse_minimum_matches_rayleigh_plesset(collapse):
    t, R = collapse["t"], collapse["R"]
    start = int(np.argmax(R < 0.5))  # the collapse proper: seeding noise makes tiny early wiggles
    t_min, R_min = first_minimum(t[start - 1:], R[start - 1:])
    tol_t, tol_R = COLLAPSE_TOLERANCE[collapse["cells"]]
    assert t_min / collapse["t_ref"] - 1.0 == pytest.approx(0.0, abs=tol_t), (t_min, collapse["t_ref"])
    assert R_min / collapse["R_ref"] - 1.0 == pytest.approx(0.0, abs=tol_R), (R_min, collapse["R_ref"])


# ------------------------------------------ Minnaert in 3D: a bubble breathing in a liquid shell
R_SHELL = 3 * R0  # free outer surface of the liquid shell
OMEGA_3D = math.sqrt(3 * P_ATM / (1000.0 * R0**2) / (1 - R0 / R_SHELL))  # docs/design.md#validation, sigma = 0: 339.8 Hz


@pytest.fixture(scope="module")
def breathing_3d(tmp_path_factory):
    """A bubble seeded 2% above ambient at the centre of a free liquid sphere, no gravity, 3 periods."""
    L = 2 * (R_SHELL + 0.5 * R0)
    period = 2 * math.pi / OMEGA_3D
    scene = Scene(
        domain=Domain(size=(L, L, L), cell_size=R0 / 6, gravity=(0.0, 0.0, 0.0), walls="open"),
        materials=AIR_AND_WATER(),
        shapes=[Sphere("water", center=(L / 2,) * 3, radius=R_SHELL),
                Sphere("air", center=(L / 2,) * 3, radius=R0, pressure=0.02 * P_ATM)],
        solver=SolverSettings(max_dt=period / STEPS_PER_PERIOD),
        output=Output(path=str(tmp_path_factory.mktemp("minnaert3d") / "m.usdc")),
    )
    return breathe(scene, period)


@pytest.mark.slow
def test_bubble_breathes_at_the_3d_minnaert_frequency(breathing_3d):
    # Reference: omega0^2 = 3 p0 / (rho R0^2) / (1 - R0/Rinf) (isothermal, sigma = 0), Rinf = 3 R0.
    # Measured -1.33% at 6 cells per radius (this test, 2026-12-05; -1.5% before a gas cell's
    # compressibility took the gas's share of the cell). Before the gas took its cells' volume
    # change (update_gas_J) it was -15.5% at 4, -10.8% at 6 and -8.7% at 8 cells. 5% bounds the
    # measurement with a margin for the seeding noise (about 1% in 2D).
    up = upward_crossings(breathing_3d["t"], breathing_3d["V"])
    assert len(up) >= 3, up
    f_sim = 1.0 / np.diff(up).mean()
    f_ref = OMEGA_3D / (2 * math.pi)
    assert abs(f_sim / f_ref - 1.0) < 0.05, (f_sim, f_ref)


@pytest.mark.slow
def test_3d_bubble_volume_follows_pv_constant_and_keeps_its_gas(breathing_3d):
    # As in 2D: the mean volume is 1.02 times the seeded one (measured 1.0199 at 6 cells, 1.0204 before
    # the gas's share of the cell; 1.0209
    # at 4); bound 0.2%. The seeded volume gives back R0 (measured 0.9996 R0).
    b0 = breathing_3d["budget0"]
    assert (3 * b0["volume"] / (4 * math.pi)) ** (1 / 3) == pytest.approx(R0, rel=5e-3)
    assert breathing_3d["V"].mean() / b0["volume"] == pytest.approx(1.02, rel=2e-3)
    budget = breathing_3d["sim"].gas_budget()
    assert budget["total"] == pytest.approx(b0["total"], rel=1e-12)
    assert budget["vented"] == 0.0


@wp.kernel(enable_backward=False)
def _cell_kappa(kv: wp.array(dtype=float), vg: wp.array(dtype=float), cell_volume: float,
                out: wp.array(dtype=float)):
    i = wp.tid()
    out[i] = cell_compressibility(kv[i], vg[i], INTERFACE_SHARP, cell_volume)


def test_a_gas_cells_compressibility_matches_the_volume_change_its_gas_takes():
    """The solve lets a gas cell change volume as div dt = -kappa_cell dp; update_gas_J hands the gas
    the whole cell's change (gas_volume_rate: r = div dx^3 / V_g), so its pressure moves by
    dp = -r dt / kappa_gas. The two agree only with kappa_cell = kappa_gas V_g / dx^3, in a cell the
    particles under- or over-fill too: with V_g / (V_g + V_l) a lone sliver of gas among empty cells
    had its J moved 1/alpha times more than the solve assumed and ran away (the pour: 241 m/s)."""
    dx, kappa_gas, div = 0.01, 1.0 / 101325.0, 3.0  # 1/Pa; 1/s
    fractions = np.array([0.05, 0.17, 0.5, 1.0, 1.3])  # V_g / dx^3: slivers, a full cell, an over-full one
    n = len(fractions)
    types = wp.array(np.full((n, 1, 1), FLUID, np.int32), device="cpu")
    u = np.zeros((n + 1, 1, 1), np.float32)
    u[1:, 0, 0] = div * dx * np.arange(1, n + 1)  # each cell's div: (u[i+1] - u[i]) / dx = div
    zeros_v, zeros_w = wp.zeros((n, 2, 1), dtype=float, device="cpu"), wp.zeros((n, 1, 2), dtype=float, device="cpu")
    vg = (fractions * dx**3).astype(np.float32)
    rate = wp.zeros((n, 1, 1), dtype=float, device="cpu")
    vel = face_field([wp.array(u, device="cpu"), zeros_v, zeros_w])
    wp.launch(gas_volume_rate, (n, 1, 1), device="cpu",
              inputs=[wp.vec3i(0, 0, 0), dx, 2, types, vel, wp.array(vg.reshape(n, 1, 1), device="cpu"),
                      wp.zeros((n, 1, 1), dtype=float, device="cpu"), rate])
    kappa_cell = wp.zeros(n, dtype=float, device="cpu")
    wp.launch(_cell_kappa, n, device="cpu", inputs=[wp.array((kappa_gas * vg).astype(np.float32), device="cpu"),
                                                    wp.array(vg, device="cpu"), dx**3, kappa_cell])
    r = rate.numpy().ravel()
    assert r == pytest.approx(div / fractions, rel=1e-5)
    # the pressure change the solve expects equals the one the gas's J update makes
    assert div / kappa_cell.numpy() == pytest.approx(r / kappa_gas, rel=1e-5, abs=0.0)
