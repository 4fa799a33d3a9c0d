"""The gas laws and the liquid-gas face weight, with power (issue #17): the compressibility the
pressure solve applies (isothermal and adiabatic), an adiabatic bubble's breathing frequency
(Minnaert with gamma), an incompressible-gas bubble that keeps its volume beside an isothermal one
that follows the hydrostatic head, and a liquid layer under gas whose hydrostatic pressure needs the
ghost-fluid face weight theta. 2D, Warp's CPU device; every test prints what it measures."""

import math

import numpy as np
import pytest
import warp as wp

from test_gas import P_ATM, R0, R_INF, STEPS_PER_PERIOD, breathe, upward_crossings
from warp_mpm_bubbles import Box, Cylinder, Domain, Material, Output, Scene, SolverSettings, Sphere
from warp_mpm_bubbles.core.simulation import Simulation

wp.config.quiet = True
G = 9.81
GAMMA = 1.4


def gas(eos):
    return Material("air", kind="gas", eos=eos, gamma=GAMMA) if eos == "adiabatic" else Material("air", kind="gas", eos=eos)


def bubble_in_disc(tmp_path, eos, max_dt=None, seed=0):
    """A bubble of R0 seeded 2% above ambient in a free liquid disc of R_INF, no gravity (test_gas.py's)."""
    L = 12 * R0
    return Scene(domain=Domain(size=(L, L), cell_size=R0 / 8, gravity=(0.0, 0.0), walls="open"),
                 materials={"water": Material("water"), "air": gas(eos)},
                 shapes=[Cylinder("water", center=(L / 2, L / 2), radius=R_INF),
                         Cylinder("air", center=(L / 2, L / 2), radius=R0, pressure=0.02 * P_ATM)],
                 solver=SolverSettings(max_dt=max_dt, seed=seed), output=Output(path=str(tmp_path / "b.usdc")))


# ------------------------------------------------ the compressibility the solve applies, one step at a time
@pytest.mark.parametrize("eos", ["isothermal", "adiabatic"])
def test_gas_compresses_by_its_law_in_each_step(tmp_path, eos):
    # In a gas cell the system reads kappa/dt^2 (p - p^) - lap p = -div u*/dt, so one step changes
    # the gas's volume by dV/V = -kappa (p - p^), kappa = 1/p_abs (isothermal) or 1/(gamma p_abs)
    # (adiabatic), p^ the particles' pressure by the law. Here p^ is recomputed from the particles'
    # J by the law itself, p is the solved pressure averaged over the gas, dV from the gas budget.
    # Measured kappa_eff gamma p_abs over the first three steps: isothermal 1.0043, 1.0009, 0.9994
    # (seeds 1, 2: 0.998-1.004); adiabatic 1.0099, 0.9969, 1.0000 (seeds 1, 2: 0.995-1.006). Bound
    # on the mean: 1.5% (three times the seed spread), so kappa x0.97 or a gamma 3% off fails.
    gamma = GAMMA if eos == "adiabatic" else 1.0
    sim = Simulation(bubble_in_disc(tmp_path, eos), "cpu")
    measured = []
    for _ in range(3):
        n = sim.num_particles
        is_gas = sim.particles.phase.numpy()[:n] == 1
        J = sim.particles.J.numpy()[:n][is_gas].astype(np.float64)
        vol = sim.particles.vol0.numpy()[:n][is_gas] * J
        p_hat = (vol * P_ATM * (J**-gamma - 1.0)).sum() / vol.sum()  # volume-weighted, as p2g_gas splats it
        sim.step(2e-4)
        p, vg = sim.fields.pressure.numpy(), sim.fields.gas_volume.numpy()
        p_solved = (p * vg).sum() / vg.sum()
        kappa_eff = -(sim.gas_budget()["volume"] / vol.sum() - 1.0) / (p_solved - p_hat)
        measured.append(kappa_eff * gamma * (P_ATM + p_hat))
    print(f"{eos}: kappa_eff * gamma * p_abs per step = {np.round(measured, 4)}")
    assert np.mean(measured) == pytest.approx(1.0, abs=0.015), measured


# ------------------------------------------------------------------------ adiabatic Minnaert (2D)
OMEGA_ADIABATIC = math.sqrt(2 * GAMMA * P_ATM / (1000.0 * R0**2 * math.log(R_INF / R0)))


@pytest.mark.slow  # 6 s on an idle machine, over 20 s on two loaded cores
def test_adiabatic_bubble_breathes_at_the_minnaert_frequency_with_gamma(tmp_path):
    # omega0^2 = 2 gamma p0 / (rho R0^2 ln(Rinf/R0)) (DESIGN §5 with gamma): 211.3 Hz. Measured
    # -0.81% (seeds 1, 2: -1.95%, -1.38%; the isothermal test measures -0.9%), 3 periods, 8 cells
    # per radius. Bound [-3%, +1%]: the seed spread with 1% margin; gamma x1.1 (+4.9%) fails.
    # The mean volume oscillates about the rest volume J = 1, seeded at J0 = (1/1.02)^(1/gamma):
    # V = 1.02^(1/gamma) V_seed = 1.014245; measured 1.014133 (seeds: 1.014159, 1.014148); bound
    # 0.03% (a gamma 3% off in the seeding moves it by 0.04%).
    period = 2 * math.pi / OMEGA_ADIABATIC
    run = breathe(bubble_in_disc(tmp_path, "adiabatic", max_dt=period / STEPS_PER_PERIOD), period)
    up = upward_crossings(run["t"], run["V"])
    assert len(up) >= 3, up
    ratio = (1.0 / np.diff(up).mean()) / (OMEGA_ADIABATIC / (2 * math.pi))
    mean_volume = run["V"].mean() / run["budget0"]["volume"]
    print(f"adiabatic breathing: f / f_Minnaert(gamma) = {ratio:.4f}; mean volume {mean_volume:.6f} "
          f"(expected {1.02 ** (1 / GAMMA):.6f})")
    assert 0.97 < ratio < 1.01
    assert mean_volume == pytest.approx(1.02 ** (1 / GAMMA), rel=3e-4)


# ------------------------------------- a rising bubble: incompressible gas keeps its volume exactly
@pytest.mark.parametrize("eos", ["incompressible", "isothermal"])
def test_rising_bubble_volume_follows_its_gas_law(tmp_path, eos):
    # A 2 cm bubble in 0.14 m of water rises for 0.1 s (test_gas.py's scene). Incompressible gas
    # (kappa = 0, fixed density): measured |V/V0 - 1| at most 2.3e-4 over six frames (seeds 0, 1).
    # Isothermal: V/V0 = p_atm / (p_atm + rho g depth), depth of the gas centroid at the end. The
    # bubble breathes (+-0.2% from step to step, its Minnaert period near the step), so one sample
    # is a draw from that: the mean over the last frame's steps is the volume the law sets,
    # measured +0.027%, +0.047%, +0.056% of it (seeds 0, 1, 2; the last step alone +0.10%, -0.03%,
    # -0.00%). Bounds 0.1% of the volume: a tenth of the compression the isothermal bubble shows
    # (the 1% head), which an incompressible gas must not.
    dx = 0.08 / 32
    scene = Scene(domain=Domain(size=(0.08, 0.16), cell_size=dx),
                  materials={"water": Material("water"), "air": gas(eos)},
                  shapes=[Box("water", min=(0.0, 0.0), max=(0.08, 0.14)), Sphere("air", center=(0.04, 0.03), radius=0.01)],
                  output=Output(path=str(tmp_path / "r.usdc"), fps=60))
    sim = Simulation(scene, "cpu")
    v0 = sim.gas_budget()["volume"]
    ratios, last_frame = [], []
    for frame in range(6):
        sim.advance_frame((lambda dt, rest: last_frame.append(sim.gas_budget()["volume"] / v0)) if frame == 5 else None)
        ratios.append(sim.gas_budget()["volume"] / v0)
    p = sim.particles_numpy()
    centroid = p["positions"][p["material"] == 1, 1].mean()
    expected = 1.0 if eos == "incompressible" else P_ATM / (P_ATM + 1000.0 * G * (0.14 - centroid))
    print(f"{eos} rising bubble: V/V0 per frame {np.round(ratios, 5)}, over the last frame's steps "
          f"{np.mean(last_frame):.5f}, expected at the end {expected:.5f}, risen {1000 * (centroid - 0.03):.1f} mm")
    assert centroid > 0.03 + 0.01  # it rose (measured 16-18 mm)
    if eos == "incompressible":
        assert np.abs(np.array(ratios) - 1.0).max() < 1e-3
    else:
        assert np.mean(last_frame) == pytest.approx(expected, abs=1e-3)


# ------------------------------------------------ ghost-fluid face weight: water under a gas layer
@pytest.mark.parametrize("eos", ["isothermal", "incompressible"])
def test_layered_column_pressure_needs_the_face_weight_theta(tmp_path, eos):
    # Water 8.25 cells deep under gas filling a closed tank, at rest. The first gas row's cell is a
    # quarter liquid, so the face between it and the top liquid row is theta ~ 0.75 liquid and the
    # pressure step across it is (theta rho_l + (1 - theta) rho_g) g dx. Analytic: p(bottom row) -
    # p(first gas row) = rho_l g (h - dx/2) + rho_g g (dx/4). Measured after 4 steps (seeds 0-2):
    # isothermal 1.0012, 0.9977, 1.0006; incompressible 1.0011, 0.9983, 1.0007 of it; the gas
    # column's own head 0.998-1.002 of rho_g g height. theta fixed at 1/2 puts a quarter cell of
    # water's head wrong: -3%. Bound 1%: rho_l or g 3% off fails too.
    dx, h = 0.01, 0.0825
    scene = Scene(domain=Domain(size=(0.08, 0.16), cell_size=dx),
                  materials={"water": Material("water"), "air": gas(eos)},
                  shapes=[Box("water", (0.0, 0.0), (0.08, h)), Box("air", (0.0, h), (0.08, 0.16))],
                  output=Output(path=str(tmp_path / "layer.usdc")))
    sim = Simulation(scene, "cpu")
    for _ in range(4):
        sim.step(sim.stable_dt())
    p = sim.pressure_numpy()[:, :, 0]
    j_gas = int(h / dx)
    y = (np.arange(p.shape[1]) + 0.5) * dx
    expected = 1000.0 * G * (h - y[0]) + 1.2 * G * (y[j_gas] - h)
    ratio = (p[:, 0] - p[:, j_gas]).mean() / expected
    gas_head = (p[:, j_gas] - p[:, -1]).mean() / (1.2 * G * (y[-1] - y[j_gas]))
    print(f"layered column ({eos}): liquid head / analytic = {ratio:.5f}; gas head / analytic = {gas_head:.4f}")
    assert ratio == pytest.approx(1.0, abs=0.01)
    assert gas_head == pytest.approx(1.0, abs=0.02)  # 0.8 Pa over the gas: near the CG tolerance
