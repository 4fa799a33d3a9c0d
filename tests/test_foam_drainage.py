"""Foam drainage and collapse by law: the films' liquid drains by the foam-drainage equation
(Verbist, Weaire & Kraynik 1996) down each grid column and is booked back to the water exactly; a
head's volume decays by Bikerman's exponential law at the set time constant. On Warp's CPU device."""

import numpy as np
import pytest
import warp as wp

from warp_mpm_bubbles import Box, Domain, Material, Output, Scene, SolverSettings
from warp_mpm_bubbles.core.grid import EMPTY, FLUID, PHASE_FOAM, SOLID_FREE_SLIP
from warp_mpm_bubbles.core.simulation import Simulation
from warp_mpm_bubbles.effects import foam_drainage as fd
from warp_mpm_bubbles.scene.effects import Foam
from warp_mpm_bubbles.scene.model import SceneError

wp.config.quiet = True
DRAIN_KERNELS = {"splat_foam", "drain_columns", "gather_foam"}
# Defaults of [effects.foam]: 0.5 mm bubbles of water. The coefficients written out here (docs/foam.md),
# apart from the code's: Plateau borders of length L = (pi / (6 sqrt 2))^(1/3) R (a Kelvin cell of the
# bubble's volume), delta_a = 0.171, C0 = sqrt(3) - pi/2, drag C = 50. K1 = 0.148 m/s, K2 = 2.51e-4
# m^2/s: the capillary length K2/K1 is 1.7 mm.
L_EDGE = (np.pi / (6 * np.sqrt(2))) ** (1 / 3) * 5e-4
K1 = 1000.0 * 9.81 * L_EDGE ** 2 / (0.171 * 50.0 * 1e-3)
K2 = np.sqrt(np.sqrt(3) - np.pi / 2) * 0.072 * L_EDGE / (2 * 50.0 * 1e-3 * np.sqrt(0.171))
CODE_K1, CODE_K2 = fd.drainage_coefficients(5e-4, 1000.0, 9.81, 1e-3, 0.072, 50.0)


# ------------------------------------------------------------ one column of foam, the kernel alone
class Column:
    """n foam cells (cells 1..n) of liquid fraction a0 on `below` (cell 0), up = +y, dx = height / n."""

    def __init__(self, n, height, a0, below="pool"):
        self.n, self.dx = n, height / n
        shape = (1, n + 2, 1)
        types = np.full(shape, FLUID, np.int32)
        types[0, n + 1, 0] = EMPTY
        liq = np.zeros(shape, np.float32)
        if below == "pool":
            liq[0, 0, 0] = self.dx ** 3
        else:
            types[0, 0, 0] = SOLID_FREE_SLIP if below == "solid" else EMPTY
        self.gas = np.zeros(shape)
        self.gas[0, 1:n + 1, 0] = (1.0 - a0) * self.dx ** 3
        liquid = np.zeros(shape)
        liquid[0, 1:n + 1, 0] = a0 * self.dx ** 3
        self.initial = liquid.sum()
        dev = "cpu"
        self.types, self.liq = wp.array(types, device=dev), wp.array(liq, device=dev)
        self.gas_w = wp.array(self.gas, dtype=wp.float64, device=dev)
        self.liquid = wp.array(liquid, dtype=wp.float64, device=dev)
        self.ledger = wp.zeros(4, dtype=wp.float64, device=dev)

    def run(self, t_end, dt=0.02, k1=CODE_K1, k2=CODE_K2, head=0):
        for _ in range(int(round(t_end / dt))):
            wp.launch(fd.drain_columns, (1, 1, 1), [dt, k1, k2, self.dx, 1, 1, self.types, self.liq, self.gas_w,
                                                    self.liquid, self.ledger, head], device="cpu")
        return self

    def alpha(self):
        liquid = self.liquid.numpy()[0, 1:self.n + 1, 0]
        return liquid / (liquid + self.gas[0, 1:self.n + 1, 0])

    def imbalance(self):
        """(liquid now + liquid out through the bottom - liquid at first) / liquid at first."""
        return (self.liquid.numpy().sum() + self.ledger.numpy()[fd.THROUGH_BOTTOM] - self.initial) / self.initial


@pytest.mark.parametrize("below", ["pool", "solid", "air"])
def test_the_column_solve_conserves_liquid_exactly(below):
    # Each face's flux leaves one cell and enters the next as the same float64 number, and what
    # crosses the bottom is booked: the liquid balances to float64 round-off over ~1e5 sub-steps.
    # Measured |imbalance| <= 2e-12; bound 1e-10 (a flux 1e-4 off between neighbours gives ~1e-3).
    col = Column(20, 0.01, 0.1, below).run(4.0)
    out = col.ledger.numpy()[fd.THROUGH_BOTTOM]
    print(f"{below}: out {out / col.initial:+.4f} of the liquid, imbalance {col.imbalance():.2e}")
    assert abs(col.imbalance()) < 1e-10
    if below == "solid":
        assert out == 0.0 and col.liquid.numpy().sum() == pytest.approx(col.initial, rel=1e-12)
    elif below == "air":
        assert out > 0.3 * col.initial  # free drainage: most of it has left in 4 s
    a = col.alpha()
    assert (a >= 0).all() and a[-1] < 0.1 and a[-1] < a[0]  # the liquid has run down: the top dried


def steady_error(n):
    """Largest relative error of a 1 cm column's steady profile on a pool against the analytic
    alpha(h) = (WET_LIMIT^-1/2 + K1 h / (2 K2))^-2, h the height above the pool (zero flux)."""
    col = Column(n, 0.01, 0.1).run(20.0)
    h = (np.arange(n) + 0.5) * col.dx
    exact = (0.36 ** -0.5 + K1 * h / (2.0 * K2)) ** -2.0
    return np.abs(col.alpha() / exact - 1.0).max()


def test_a_column_on_its_pool_reaches_the_analytic_steady_profile():
    # Zero flux, K1 alpha^2 = K2 alpha^(1/2) d(alpha)/dz, with alpha = 0.36 at the pool: the profile
    # falls from 0.36 to 0.048 over the 1 cm (six capillary lengths). Measured errors at 10, 20, 40
    # cells: 0.87%, 0.23%, 0.059% (the run to 20 s is steady to 1e-8): order 1.92 then 1.96, the
    # scheme's second order. Bound: 1.5% at each resolution and order > 1.8. K1 3% off moves the
    # profile's dry end by 3.8%.
    errors = [steady_error(n) for n in (10, 20, 40)]
    orders = np.log2(np.array(errors[:-1]) / np.array(errors[1:]))
    print("steady profile errors", errors, "orders", orders)
    assert max(errors) < 0.015
    assert (orders > 1.8).all()


def test_a_heads_packed_column_reaches_the_steady_profile_at_its_packed_heights():
    # A two-way head's column (head = 1): foam that fills half of each cell, with an empty cell
    # between two of them (a gap between stacked particles), is one packed run: cells' centres as far
    # apart as their foam is tall (its gas and liquid over the cell's area, at least half a cell), the
    # gap bridged. Its steady profile is the analytic one at the foam's packed heights (the wet cells
    # near the pool swell to 0.7 of a cell). Measured: largest relative error 0.071% (20 foam cells,
    # 5.3 mm of foam); bound 0.5%. Against heights of half a cell each (the swelling left out)
    # the error is 10%; solved unpacked (head = 0), the gap opens the upper run to the air and it
    # drains away: errors of order 1.
    n, gap = 21, 11
    col = Column(n, 0.01, 0.1)
    gas, liquid = col.gas.copy(), col.liquid.numpy().copy()
    gas[0, 1:n + 1, 0] *= 0.5
    liquid[0, 1:n + 1, 0] *= 0.5
    gas[0, gap, 0] = liquid[0, gap, 0] = 0.0
    col.gas, col.gas_w = gas, wp.array(gas, dtype=wp.float64, device="cpu")
    col.liquid = wp.array(liquid, dtype=wp.float64, device="cpu")
    col.run(20.0, head=1)
    foam = np.arange(1, n + 1) != gap
    stored = col.liquid.numpy()[0, 1:n + 1, 0][foam]
    alpha = stored / (stored + gas[0, 1:n + 1, 0][foam])
    size = np.clip((stored + gas[0, 1:n + 1, 0][foam]) / col.dx ** 2, 0.5 * col.dx, col.dx)  # as the solve's
    h = np.cumsum(size) - 0.5 * size
    exact = (0.36 ** -0.5 + K1 * h / (2.0 * K2)) ** -2.0
    error = np.abs(alpha / exact - 1.0).max()
    print(f"packed column: largest relative error {error:.2e}; foam {h[-1] + 0.5 * size[-1]:.4f} m tall")
    assert error < 0.005


A_WET = 0.02  # the travelling wave's fraction behind its front


def travelling_wave(depth, front):
    """The exact travelling wave of forced drainage into dry foam (Verbist et al.): behind the front,
    alpha = A_WET tanh^2(k (front - depth)), k = K1 sqrt(A_WET) / (2 K2); it moves down at K1 A_WET."""
    k = K1 * np.sqrt(A_WET) / (2.0 * K2)
    return np.where(depth < front, A_WET * np.tanh(k * (front - np.minimum(depth, front))) ** 2, 0.0)


def wave_errors(n, height=0.15, start=0.08, duration=10.0, dt=0.01):
    """A column of n cells starting as the exact wave (front 8 cm down), fed at the top by a cell
    held at A_WET (a reservoir 1e4 cells' worth of foam, so the step does not drain it): after 10 s,
    the front's speed error (where alpha crosses A_WET / 2) and the profile's largest error, both
    relative, against the wave 2.96 cm further down."""
    col = Column(n, height, 0.0, below="solid")
    depth = height - (np.arange(n) + 0.5) * col.dx
    gas = np.zeros_like(col.gas)
    gas[0, 1:n + 1, 0] = (1.0 - A_WET) * col.dx ** 3  # the wet foam fills its cells
    gas[0, n, 0] *= 1e4
    col.gas_w = wp.array(gas, dtype=wp.float64, device="cpu")
    a0 = travelling_wave(depth, start)
    a0[-1] = A_WET
    liquid = np.zeros_like(gas)
    liquid[0, 1:n + 1, 0] = a0 / (1.0 - a0) * gas[0, 1:n + 1, 0]
    for _ in range(int(round(duration / dt))):
        liquid[0, n, 0] = A_WET / (1.0 - A_WET) * gas[0, n, 0]  # the reservoir, topped up
        col.liquid = wp.array(liquid, dtype=wp.float64, device="cpu")
        wp.launch(fd.drain_columns, (1, 1, 1), [dt, CODE_K1, CODE_K2, col.dx, 1, 1, col.types, col.liq,
                                                col.gas_w, col.liquid, col.ledger, 0], device="cpu")
        liquid = col.liquid.numpy()
    alpha = liquid[0, 1:n, 0] / (liquid[0, 1:n, 0] + gas[0, 1:n, 0])  # below the reservoir
    i = np.flatnonzero(alpha >= A_WET / 2).min()  # the deepest cell past half (index 0 is the bottom)
    crossing = np.interp(A_WET / 2, [alpha[i - 1], alpha[i]], [depth[i - 1], depth[i]])
    k = K1 * np.sqrt(A_WET) / (2.0 * K2)
    front = crossing + np.arctanh(np.sqrt(0.5)) / k  # where the wave's alpha reaches 0
    expected = start + K1 * A_WET * duration
    profile = np.abs(alpha - travelling_wave(depth[:-1], expected)).max() / A_WET
    return (front - start) / (expected - start) - 1.0, profile


def test_a_drainage_front_travels_as_the_analytic_wave():
    # Forced drainage: liquid fed at the top runs into dry foam as a front of constant shape moving
    # at K1 A_WET (2.96 mm/s; width 2 K2 / (K1 sqrt(A_WET)) = 2.4 cm). Started on the exact wave:
    # measured speed errors at 30, 60, 120 cells (5, 2.5, 1.25 mm): -0.70%, -0.05%, +0.11%;
    # profile errors 1.0%, 0.51%, 0.54% of A_WET. They fall to a floor that grows with the wave's
    # fraction (profile 0.32%, 0.57%, 1.57% at 0.01, 0.02, 0.04, 240 cells): the solve keeps each
    # cell's gas and lets the foam swell with its liquid, which the drainage equation (alpha << 1)
    # neglects; the speed's error falls with order 3.8 from 30 to 60 cells, the profile's with order
    # 1.0, then the floor. Bounds: speed 1%, profile 1.5%, at each resolution. K1 3% high: +2.0%
    # and 2.0% at 30 cells.
    for n in (30, 60, 120):
        speed, profile = wave_errors(n)
        print(f"{n} cells: front speed {speed:+.3%}, profile {profile:.3%}")
        assert abs(speed) < 0.01 and profile < 0.015


# ------------------------------------------------------------------ the stage: the liquid ledger
W, H, DX = 0.2, 0.03, 0.2 / 64
AIR_AND_WATER = lambda: {"water": Material("water"), "air": Material("air", kind="gas")}  # noqa: E731


def layer(tmp_path, foam, height=0.05, water=H, layer_height=4 * DX, dx=DX):
    """Water `water` deep with a gas layer on it, which becomes foam at once."""
    return Scene(domain=Domain(size=(W, height), cell_size=dx), materials=AIR_AND_WATER(),
                 shapes=[Box("water", min=(0.0, 0.0), max=(W, water)),
                         Box("air", min=(0.0, water), max=(W, water + layer_height))],
                 solver=SolverSettings(particles_per_cell=4),
                 output=Output(path=str(tmp_path / "layer.usdc"), frames=1, fps=30.0), effects={"foam": foam})


def test_the_films_liquid_balances_exactly(tmp_path):
    # Lent by the water to new films = held + drained back + burst (rained back) + left (none here),
    # in float64 sums
    # of the float32 each particle holds: measured exactly 0 at every step; bound 1e-12 of the lent.
    # The column solve's own count of what crossed the foam's bottom agrees to the particles'
    # float32 rounding (measured 1e-6 of the lent; bound 1e-4).
    sim = Simulation(layer(tmp_path, Foam(lifetime=0.1)), "cpu")
    stage = sim.stage("foam")
    drained = []
    for _ in range(40):
        sim.advance_to(sim.time + sim.stable_dt() * 0.9999)
        b = stage.liquid_budget(sim.ctx)
        assert abs(b["lent"] - b["held"] - b["drained"] - b["burst"] - b["left"]) <= 1e-12 * b["lent"], b
        assert abs(b["drained"] - b["through_bottom"]) <= 1e-4 * b["lent"], b
        drained.append(b["drained"])
    assert b["lent"] > 0 and b["burst"] > 0 and max(np.abs(drained)) > 0.01 * b["lent"]
    n = sim.particles.count
    foam = (sim.particles.numpy("phase")[:n] == PHASE_FOAM) & (sim.particles.numpy("active")[:n] != 0)
    liquid = sim.particles.numpy("foam_liquid")[:n][foam]
    alpha = liquid / (liquid + (sim.particles.numpy("vol0") * sim.particles.numpy("J"))[:n][foam])
    assert (alpha > 0).all() and (alpha <= 0.36 + 1e-6).all()  # drained toward the pool's wet limit
    assert DRAIN_KERNELS <= set(sim.launches)
    # A resumed run takes the ledger back (its device sums are checkpointed with the stage's values).
    again = Simulation(layer(tmp_path, Foam(lifetime=0.1)), "cpu")
    again.load_state(sim.state_arrays())
    assert again.stage("foam").liquid_budget(again.ctx)["burst"] == b["burst"] > 0


@pytest.mark.parametrize("head", [False, True])
def test_films_blown_out_through_an_open_wall_are_booked(tmp_path, head):
    # Foam falling through an open floor takes its films' liquid out of the box: booked as "left",
    # so lent = held + drained + burst + left still closes exactly (without it, the ledger was short
    # by what left: measured 4.7e-7 m^3 with a head, of 7.5e-7 lent). A drop falling out of an air
    # layer: the foam made around it has nothing to rest on and falls out after it.
    dx = 0.005
    scene = Scene(domain=Domain(size=(0.045, 0.05), cell_size=dx, walls={"y_min": "open"}),
                  materials=AIR_AND_WATER(),
                  shapes=[Box("water", min=(0.025, 0.02), max=(0.045, 0.035), velocity=(0.0, -0.9)),
                          Box("air", min=(0.0, 0.035), max=(0.045, 0.05))],
                  solver=SolverSettings(particles_per_cell=4),
                  output=Output(path=str(tmp_path / "out.usdc"), frames=1, fps=30.0),
                  effects={"foam": Foam(head=head)})
    sim = Simulation(scene, "cpu")
    stage = sim.stage("foam")
    for _ in range(4):
        sim.advance_frame()
        b = stage.liquid_budget(sim.ctx)
        assert abs(b["lent"] - b["held"] - b["drained"] - b["burst"] - b["left"]) <= 1e-12 * b["lent"], b
    print(f"head {head}: lent {b['lent']:.3g} m^3, left {b['left']:.3g}, held {b['held']:.3g}")
    assert b["left"] > 0.1 * b["lent"] > 0


# ------------------------------------------------------------------------ Bikerman's decay of a head
TAU = 0.1  # s


def fitted_decay_time(tmp_path, n):
    """Bikerman's time constant of a head of foam 2.5 cm thick (made from a gas layer on 2.5 cm of
    water, 2D, n cells across 0.2 m): the least-squares slope of ln(volume) over the foam formed by
    0.05 s, from then to 3 TAU (later foam, from gas that surfaced late, would add to the head)."""
    dx = W / n
    scene = layer(tmp_path, Foam(lifetime=TAU, drainage=False, lifetimes="stratified"), height=0.075,
                  water=0.025, layer_height=0.025, dx=dx)
    sim = Simulation(scene, "cpu")
    cohort, t, volume = None, [], []
    while sim.time < 3 * TAU:
        sim.advance_to(sim.time + sim.stable_dt() * 0.9999)
        p, m = sim.particles, sim.particles.count
        foam = (p.numpy("phase")[:m] == PHASE_FOAM) & (p.numpy("active")[:m] != 0)
        if cohort is None:
            if sim.time > 0.05:
                cohort = p.numpy("ids")[:m][foam]
            continue
        foam &= np.isin(p.numpy("ids")[:m], cohort)
        t.append(sim.time)
        volume.append((p.numpy("vol0")[:m] * p.numpy("J")[:m])[foam].astype(np.float64).sum())
    return -1.0 / np.polyfit(np.array(t), np.log(volume), 1)[0], len(cohort)


def test_a_head_decays_at_the_set_time_constant(tmp_path):
    # Each film bursts at the end of its exponential lifetime (mean TAU), so a head's volume decays as
    # exp(-t / TAU). Stratified lifetimes remove the sampling noise of the exponential draw. Measured
    # at 32, 64, 128 cells (cohorts of 395, 1509, 3911 foam particles): -0.86%, +0.37%, +0.07% of
    # TAU; the error falls with order 1.2 then 2.4 (1.8 overall): burst times are whole steps and
    # the cohort samples the sequence unevenly, both shrinking with the cell. With the volume
    # correction moving positions (the default) the cohorts are 392, 1564, 4242 and the errors
    # -0.40%, +0.44%, -0.13%: which gas becomes foam follows the flow, and between 32 and 64 cells the
    # cohort's sampling is the larger part. Bound: 2% (the issue asks 5%) at each resolution, the
    # finest the closest. A 3% error in the burst rate fails it.
    errors = []
    for n in (32, 64, 128):
        tau, size = fitted_decay_time(tmp_path, n)
        errors.append(tau / TAU - 1.0)
        print(f"{n} cells: {size} foam particles, decay time {tau:.5f} s ({errors[-1]:+.2%})")
    assert max(np.abs(errors)) < 0.02
    assert abs(errors[2]) < min(abs(errors[0]), abs(errors[1]))


def test_drainage_off_launches_no_drainage_kernel(tmp_path):
    sim = Simulation(layer(tmp_path, Foam(lifetime=0.1, drainage=False)), "cpu")
    for _ in range(3):
        sim.advance_to(sim.time + sim.stable_dt() * 0.9999)
    assert not DRAIN_KERNELS & set(sim.launches) and "gas_to_foam" in sim.launches


@pytest.mark.parametrize("key, value, words", [
    ("liquid_fraction", 0.5, "random close packing"), ("bubble_radius", 0.0, "in metres"), ("viscosity", -1.0, "> 0"),
    ("surface_tension", "high", "expected a finite number"), ("permeability_constant", 0, "> 0"),
    ("lifetimes", "sometimes", "'stratified'"), ("drainage", 1, "true or false")])
def test_bad_foam_settings_are_refused_by_name(tmp_path, key, value, words):
    with pytest.raises(SceneError) as err:
        layer(tmp_path, Foam(**{key: value})).validate()
    assert f"[effects.foam].{key}" in str(err.value) and words in str(err.value), str(err.value)
