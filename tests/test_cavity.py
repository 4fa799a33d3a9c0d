"""A near-vacuum cavity collapses on Rayleigh's time and the water stays water (issue #12 item 7;
physics/cavity.py, docs/design.md#cavities). Reference: the cylindrical Rayleigh collapse by RK4
(benchmarks/cases.py). Numbers: benchmarks/validation/cavity_collapse.py (benchmarks/results/cavity_collapse/cpu.md)."""

import math

import numpy as np
import pytest
import warp as wp

from benchmarks.cases import P_ATM, P_G0, RHO, cavity_in_tank, collapse_time
from warp_mpm_bubbles import Box, Domain, Material, Output, Scene, Sphere
from warp_mpm_bubbles.core.simulation import Simulation

wp.config.quiet = True
CAVITY_KERNELS = ("count_cavity_gas", "mark_cavities", "release_cavity_faces", "cavity_room", "cavity_gas_J")

# Measured (seed 0; seeds 1-3 in brackets), the collapse time's error against RK4, at R = R0/2 and
# R0/4, by the gas's volume and by the liquid's flux (benchmarks/cases.py):
#   cells/R0          8                         16                        32
#   gas,  R0/2   -2.30% [-1.83 -1.69 -1.75]   -0.59% [-0.59 -0.61 -0.65]   -0.21%
#   gas,  R0/4   -0.25% [-0.11 +0.04 -0.02]   +0.12% [+0.16 +0.10 +0.16]   +0.16%
#   flux, R0/2   -0.36% [-0.04 +0.10 -0.04]   +0.08% [+0.22 +0.06 -0.02]   +0.11%
#   flux, R0/4   -0.27%                       +0.06% [+0.18 +0.05 -0.02]   +0.10%
# The gas's error converges at order 2.2 (differences 1.71, 0.38 points; extrapolated -0.1%); the
# liquid's is converged at 16. Bounds at 16 lie between the measured error and that at 8 (R0/2 by
# the gas: 1.2%), or, where 8 is as close, at about three times the seed spread; a 3% change of
# the reference (or of the water's density, 6%) fails each of them. Before (a strict xfail): the
# gas at 1 Pa reached 4e4 m/s, R = 1.2 R0 after one step, and the steps fell under 1e-9 s.
GAS_BOUNDS = {0.5: 0.012, 0.25: 0.01}  # at 16 cells per radius, relative, either side
FLUX_BOUND = 0.005
COARSE_BOUND = 0.035  # by the gas at 8 cells per radius, R0/2


@pytest.fixture(scope="module")
def collapses(tmp_path_factory):
    return {n: collapse_time(n, tmp_path_factory.mktemp(f"cavity{n}"), t_end=1.6, max_steps=400) for n in (8, 16)}


def errors(run, key):
    return {r: run[key][r] / run["t_ref"][r] - 1.0 for r in run["t_ref"]}


def test_a_near_vacuum_cavity_collapses_on_the_cylindrical_rayleigh_time(collapses):
    # 2D analogue of Rayleigh's collapse: an empty cylinder R0 (gas at 1 Pa) in a free water annulus
    # 3 R0 across reaches R0/2 at 0.969 R0 sqrt(rho/p_inf) and R0/4 at 1.113 (RK4; R -> 0 at 1.168;
    # 3D Rayleigh 0.915).
    coarse, fine = collapses[8], collapses[16]
    print({n: {"gas": errors(run, "t"), "flux": errors(run, "t_flux"), "steps": run["steps"]} for n, run in collapses.items()})
    for r, bound in GAS_BOUNDS.items():
        assert errors(fine, "t")[r] == pytest.approx(0.0, abs=bound), r
        assert errors(fine, "t_flux")[r] == pytest.approx(0.0, abs=FLUX_BOUND), r
    assert errors(coarse, "t")[0.5] == pytest.approx(0.0, abs=COARSE_BOUND)
    assert abs(errors(fine, "t")[0.5]) < abs(errors(coarse, "t")[0.5])  # it converges
    assert fine["first_dt"][0] == pytest.approx(0.5 * (0.01 / 16) / math.sqrt((P_ATM - P_G0 * P_ATM) / RHO), rel=1e-3)


def test_the_cavity_keeps_the_water_and_the_gas_ledger(collapses):
    # The water's volume (its particles' V0 J over the seeded annulus; measured 0.9979 and 0.9994
    # at 8 and 16) and the gas's mass ledger (exact); no gas vents (the cavity is inside the water).
    for run in collapses.values():
        assert run["liquid_after"]["volume_share"] == pytest.approx(1.0, abs=0.005)
        assert run["gas_after"]["total"] == pytest.approx(run["gas_before"]["total"], rel=1e-12)
        assert run["gas_after"]["vented"] == 0.0


@pytest.mark.parametrize("p_g0", [0.005, 0.015])
def test_a_cavity_of_a_few_hundredths_of_ambient_collapses_and_rebounds(tmp_path, p_g0):
    # Between a vacuum and an ordinary bubble: gas at 0.5% and 1.5% of ambient (under the 2% where
    # gas becomes a cavity's, physics/cavity.py), compressed past ambient at the end of its
    # collapse, where it leaves the cavity's model. Measured at 8 cells per radius, R0/2 by the gas:
    # -2.36% and +1.08%, by the flux -0.27% and -0.99%; at 1.6 R0 sqrt(rho/p_inf) (35 and 52 steps)
    # the fastest water 0.90 and 1.63 m/s, its particles' volume 0.993 and 0.983 of the seeded.
    # Before the cavity's memory and the pressure spread limit, the 0.5% one stopped on NaN after
    # its collapse, and the ordinary model (no cavity) reached R0/2 13% early.
    run = collapse_time(8, tmp_path, t_end=1.6, max_steps=600, p_g0=p_g0, to_end=True)
    print(p_g0, errors(run, "t"), errors(run, "t_flux"), run["steps"])
    assert errors(run, "t")[0.5] == pytest.approx(0.0, abs=COARSE_BOUND)
    assert errors(run, "t_flux")[0.5] == pytest.approx(0.0, abs=0.02)
    assert run["gas_after"]["total"] == pytest.approx(run["gas_before"]["total"], rel=1e-12)
    assert run["liquid_after"]["max_speed"] < 10.0
    assert run["liquid_after"]["volume_share"] == pytest.approx(1.0, abs=0.03)


def test_a_cavity_in_a_tank_leaves_the_water_a_body_of_water(tmp_path):
    # The case: a 1 Pa cavity 2 cm across, 3 cm deep in a 2D tank (32 cells across), to
    # 0.2 s. Before: the whole water body ended flattened on the floor (its volume from 1.74e-5 to
    # 1.2e-7 m^3). Measured: the water's volume -0.66%, its top 1% of particles at 62.4 mm (seeded
    # surface 59.5; the collapse's jet reaches 70), its centroid from 30.1 to 28.8 mm (filling the
    # cavity lowers it; at rest, 28.4), the gas left 1e-5 of its volume (1 Pa, now at about
    # ambient), the fastest water 0.66 m/s, 268 steps.
    run = cavity_in_tank(32, tmp_path, t_end=0.2)
    before, after = run["before"], run["after"]
    print(run)
    assert after["volume"] == pytest.approx(before["volume"], rel=0.015)
    assert 0.0 < after["surface"] < 1.5 * before["surface"]
    assert 0.9 * before["centroid"] < after["centroid"] < before["centroid"]
    assert run["gas"]["volume"] < 1e-4 * run["gas_before"]["volume"]
    assert run["gas"]["total"] == pytest.approx(run["gas_before"]["total"], rel=1e-12)
    assert after["max_speed"] < 2.0
    assert run["steps"] < 1000


def test_ordinary_gas_never_runs_the_cavity_kernels(tmp_path):
    # A bubble at ambient pressure: after the first step (which measures it), no cavity kernel is
    # launched (the gas stage's read-back says none can exist), and none of its cells is marked.
    scene = Scene(domain=Domain(size=(0.04, 0.06), cell_size=0.04 / 16),
                  materials={"water": Material("water"), "air": Material("air", kind="gas")},
                  shapes=[Box("water", (0.0, 0.0), (0.04, 0.05)), Sphere("air", (0.02, 0.015), 0.006)],
                  output=Output(path=str(tmp_path / "b.usdc")))
    sim = Simulation(scene, "cpu")
    sim.step(sim.stable_dt())
    first = {k: sim.launches[k] for k in CAVITY_KERNELS}
    for _ in range(3):
        sim.step(sim.stable_dt())
    assert sim.stage("gas").state.cavity == 0.0
    assert {k: sim.launches[k] for k in CAVITY_KERNELS} == first
    assert not np.any(sim.fields.cavity.numpy())
    assert not np.any(sim.particles.numpy("cavity_gas"))


def test_a_checkpoint_from_before_the_cavity_model_resumes(tmp_path):
    """An older checkpoint has no per-particle cavity_gas: it loads with the field's fresh default (0),
    as an older checkpoint's missing host values do, and the run goes on (no KeyError)."""
    from warp_mpm_bubbles.io.checkpoint import load_checkpoint, save_checkpoint

    scene = Scene(domain=Domain(size=(0.04, 0.04), cell_size=0.04 / 16),
                  materials={"water": Material("water"), "air": Material("air", kind="gas")},
                  shapes=[Box("water", (0.0, 0.0), (0.04, 0.03)), Sphere("air", (0.02, 0.012), 0.005)],
                  output=Output(path=str(tmp_path / "c.usdc")), name="old_checkpoint")
    sim = Simulation(scene, "cpu")
    for _ in range(2):
        sim.step(sim.stable_dt())
    path = tmp_path / "checkpoint.npz"
    save_checkpoint(sim, path)
    with np.load(path) as data:
        old = {k: data[k] for k in data.files if k != "particle_cavity_gas"}
    np.savez(path, **old)
    resumed = Simulation(scene, "cpu")
    load_checkpoint(resumed, path)
    assert resumed.particles.numpy("cavity_gas").max() == 0
    assert np.array_equal(resumed.particles_numpy()["positions"], sim.particles_numpy()["positions"])
    resumed.step(resumed.stable_dt())
