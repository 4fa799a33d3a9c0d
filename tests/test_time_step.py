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
