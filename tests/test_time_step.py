"""The time step's limits are the documented formulas exactly (issue #17): CFL with sqrt(|g| dx)
added to the speed, the capillary limit sqrt((rho_l + rho_g) dx^3 / (4 pi sigma)), and the explicit
viscous limit dx^2 / (4 dim nu) (the stress form; none when the viscosity is implicit). A limit
looser than its formula lets a run go unstable; a stricter one only costs time, so each is
checked for equality where it is the binding one."""

import math

import pytest
import warp as wp

from warp_mpm_bubbles import Box, Domain, Material, Output, Scene
from warp_mpm_bubbles.core.simulation import Simulation
from warp_mpm_bubbles.scene.effects import Viscosity

wp.config.quiet = True


def at_rest(tmp_path, effects=None, **water):
    scene = Scene(domain=Domain(size=(0.04, 0.04), cell_size=0.04 / 16),
                  materials={"water": Material("water", **water)},
                  shapes=[Box("water", (0.0, 0.0), (0.04, 0.02))], effects=effects or {},
                  output=Output(path=str(tmp_path / "s.usdc")))
    return Simulation(scene, "cpu")


def test_cfl_limit_at_rest(tmp_path):
    sim = at_rest(tmp_path)
    dx = sim.grid.dx
    assert sim.stable_dt() == pytest.approx(sim.scene.solver.cfl * dx / math.sqrt(9.81 * dx), rel=1e-9)


def test_capillary_limit(tmp_path):
    sim = at_rest(tmp_path, surface_tension=0.5)  # strong enough that it binds (dt 1.4 ms vs CFL 4 ms)
    dx = sim.grid.dx
    limit = math.sqrt(1000.0 * dx**3 / (4 * math.pi * 0.5))
    assert limit < 0.5 * dx / math.sqrt(9.81 * dx)
    assert sim.stable_dt() == pytest.approx(limit, rel=1e-9)


def test_viscous_limit(tmp_path):
    # nu = 1e-3 m^2/s: the stress form's explicit limit dx^2 / (4 dim nu) = 0.78 ms binds; the
    # default solver ("auto") goes implicit instead and the CFL limit (8 ms) is left.
    sim = at_rest(tmp_path, viscosity=1.0, effects={"viscosity": Viscosity(solver="explicit")})
    dx = sim.grid.dx
    assert sim.stable_dt() == pytest.approx(dx**2 / (4 * 2 * 1e-3), rel=1e-9)
    sim = at_rest(tmp_path, viscosity=1.0)
    assert "viscous" not in sim.dt_limits()
    assert sim.stable_dt() == pytest.approx(sim.scene.solver.cfl * dx / math.sqrt(9.81 * dx), rel=1e-9)


def test_the_run_records_which_limit_set_each_step(tmp_path):
    # The summary's "steps set by" (io/runner.py): at rest the CFL limit (5.6 ms) sets the 3 steps of a
    # 1/60 s frame; with strong tension the capillary limit (1.4 ms) does, and cfl then sets none,
    # which is what a user choosing a cfl preset needs to see.
    for tension, binding in ((0.0, "cfl"), (0.5, "capillary")):
        sim = at_rest(tmp_path, surface_tension=tension)
        sim.advance_to(1.0 / 60.0)
        counts = sim.stats.limited_by
        assert sum(counts.values()) == sim.stats.steps
        assert counts.get(binding, 0) == sim.stats.steps and sim.stats.steps >= 3, counts


def test_a_frame_shorter_than_every_limit_is_set_by_the_frame(tmp_path):
    sim = at_rest(tmp_path)
    sim.advance_to(1e-4)  # CFL allows 5.6 ms
    assert sim.stats.limited_by == {"frame": 1}


# ----------------------------------------------------------------------- the gas_expansion limit
# physics/gas.py's dt_limit, against its documented formula written out here (not read from
# scene/limits.py, which restates it): the smaller of cfl dx / sqrt(dp / rho), dp the gas's gauge
# pressure beyond the domain's hydrostatic head rho g H, and 0.1 / rate, the step in which the
# fastest-changing gas cell changes its volume by 10% at the last step's rate, floored at a tenth of
# the step at which the ambient pressure would push the liquid across cfl cells. Each is checked
# where it binds, to rel 1e-5 (float32 state), so a limit 3% looser or stricter fails.
SHARE, P_ATM, RHO, G = 0.1, 101325.0, 1000.0, 9.81


def bubble_tank(tmp_path, pressure=0.0):
    """Water 3 cm deep in a 4 cm closed tank, 16 cells across, with an air bubble of radius 2 cells
    at the gauge pressure given."""
    from warp_mpm_bubbles import Sphere

    scene = Scene(domain=Domain(size=(0.04, 0.04), cell_size=0.04 / 16),
                  materials={"water": Material("water"), "air": Material("air", kind="gas")},
                  shapes=[Box("water", (0.0, 0.0), (0.04, 0.03)),
                          Sphere("air", center=(0.02, 0.012), radius=0.005, pressure=pressure)],
                  output=Output(path=str(tmp_path / "b.usdc")))
    return Simulation(scene, "cpu")


def test_gas_expansion_limit_from_the_gas_pressure(tmp_path):
    # 2 atm of gauge pressure, far beyond the 0.04 m head (392 Pa): the pressure part binds (88 us;
    # the CFL limit at rest is 8.0 ms).
    sim = bubble_tank(tmp_path, pressure=2.0e5)
    cfl, dx = sim.scene.solver.cfl, sim.grid.dx
    expected = cfl * dx / math.sqrt((2.0e5 - RHO * G * 0.04) / RHO)
    limits = sim.dt_limits()
    assert limits["gas_expansion"] == pytest.approx(expected, rel=1e-5)
    assert min(limits, key=limits.get) == "gas_expansion"


def expanding_gas_limit(tmp_path, rate_per_axis):
    """The gas_expansion limit after one step of a bubble at ambient pressure (no pressure part),
    its velocity field then replaced by the uniform expansion u = rate_per_axis * x (so every gas
    cell's divergence is dim * rate_per_axis) and the step's report re-taken from it, as the step's
    end does (Simulation._phase_read_back)."""
    import numpy as np

    sim = bubble_tank(tmp_path)
    assert "gas_expansion" not in sim.dt_limits()
    sim.step(sim.stable_dt())  # cells classified: the bubble's cells are gas cells
    f, g = sim.fields, sim.grid
    for field in (f.vel, f.gas_vel or []):
        for a in range(g.dim):
            shape = field[a].shape
            x = np.indices(shape)[a] * g.dx  # face a's position along a, from the grid's corner
            field[a].assign((rate_per_axis * x).astype(np.float32))
    f.target_div.zero_()  # the volume correction's own divergence is not the gas's expansion
    f.max_speed.zero_()
    for write in sim.report_writers:
        write(sim)
    report = sim.read_host(f.max_speed)
    for read in sim.report_readers:
        read(sim, report)
    assert sim.stage("gas").state.expansion_rate == pytest.approx(g.dim * rate_per_axis, rel=1e-5)
    return sim, sim.dt_limits()


def test_gas_expansion_limit_from_the_gas_volume_rate(tmp_path):
    # A gas cell growing at 40 / s may take a step of 0.1 / 40 = 2.5 ms (the floor is 12 us, the
    # CFL limit 5.1 ms, so this limit binds).
    sim, limits = expanding_gas_limit(tmp_path, 20.0)
    assert limits["gas_expansion"] == pytest.approx(SHARE / 40.0, rel=1e-5)
    assert min(limits, key=limits.get) == "gas_expansion"


def test_gas_expansion_limit_floor(tmp_path):
    # At 2e4 / s the rate asks 5 us; the floor (12 us) holds the step at 0.1 cfl dx / sqrt(p_atm / rho_liquid).
    sim, limits = expanding_gas_limit(tmp_path, 1.0e4)
    cfl, dx = sim.scene.solver.cfl, sim.grid.dx
    floor = SHARE * cfl * dx / math.sqrt(P_ATM / RHO)
    assert SHARE / 2.0e4 < 0.5 * floor
    assert limits["gas_expansion"] == pytest.approx(floor, rel=1e-5)
