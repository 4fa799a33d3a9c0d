"""A two-way foam head ([effects.foam] head = true, effects/foam_head.py): foam stacks on the water
and loads it with its weight, trades momentum with it exactly, gives its liquid back exactly, and
collapses by drainage to the height the drainage equation predicts. Warp's CPU device, 2D tanks of a
few hundred foam particles."""

import numpy as np
import pytest
import warp as wp

from warp_mpm_bubbles import Box, Domain, Material, Output, Scene, SolverSettings
from warp_mpm_bubbles.core.grid import PHASE_FOAM, PHASE_LIQUID, SOLID_FREE_SLIP
from warp_mpm_bubbles.core.simulation import Simulation
from warp_mpm_bubbles.effects import foam_drainage as fd
from warp_mpm_bubbles.io.checkpoint import load_checkpoint, save_checkpoint
from warp_mpm_bubbles.scene.effects import Collider, Foam
from warp_mpm_bubbles.scene.model import SceneError

wp.config.quiet = True
HEAD_KERNELS = {"burst_head", "splat_head", "head_columns", "settle_foam", "load_water", "take_water"}
W, G = 0.1, 9.81  # tank width (m), gravity


def tank(tmp_path, columns=32, gas=0.0125, **foam):
    """Water 3 cm deep (to the nearest cell) under a gas layer `gas` thick one cell above it: the gas
    is in open air at once and becomes foam in the first step, none of it trapped in the water."""
    dx = W / columns
    depth = round(0.03 / dx) * dx
    return Scene(
        domain=Domain(size=(W, round(0.075 / dx) * dx), cell_size=dx),
        materials={"water": Material("water"), "air": Material("air", kind="gas")},
        shapes=[Box("water", min=(0.0, 0.0), max=(W, depth)),
                Box("air", min=(0.0, depth + dx), max=(W, depth + dx + gas))],
        solver=SolverSettings(particles_per_cell=4),
        output=Output(path=str(tmp_path / "head.usdc"), frames=2, fps=30.0),
        effects={"foam": Foam(head=True, **foam)},
    )


def step(sim):
    sim.advance_to(sim.time + sim.stable_dt() * 0.9999)


def foam_mask(sim):
    n = sim.num_particles
    return (sim.particles.phase.numpy()[:n] == PHASE_FOAM) & (sim.particles.active.numpy()[:n] == 1)


def foam_masses(sim, mask):
    """kg of each foam particle: its gas and its films' liquid (the stage's weight)."""
    n = sim.num_particles
    return (sim.particles.mass.numpy()[:n][mask].astype(np.float64)
            + 1000.0 * sim.particles.foam_liquid.numpy()[:n][mask].astype(np.float64))


# ------------------------------------------------------------- the head's weight reaches the floor
def floor_rise(tmp_path, columns):
    """(rise, load), Pa: the floor's pressure over the water's own rho g (depth - dx/2) (the bottom
    row's centres; depth from the water particles' volume, after the films took theirs), and the
    head's m g / A, both averaged over 0.4-0.8 s, when the water has settled."""
    sim = Simulation(tank(tmp_path, columns=columns, drainage=False, lifetime=1e6), "cpu")
    dx, sums = sim.grid.dx, np.zeros(3)
    while sim.time < 0.8:
        dt = sim.stable_dt() * 0.9999
        step(sim)
        if sim.time > 0.4:
            n = sim.num_particles
            water = (sim.particles.phase.numpy()[:n] == PHASE_LIQUID) & (sim.particles.active.numpy()[:n] == 1)
            depth = sim.particles.vol0.numpy()[:n][water].astype(np.float64).sum() / (W * dx)  # the slab is dx deep
            load = foam_masses(sim, foam_mask(sim)).sum() * G / (W * dx)
            floor = sim.pressure_numpy()[:, 0, 0].astype(np.float64).mean()
            sums += dt * np.array([floor - 1000.0 * G * (depth - 0.5 * dx), load, 1.0])
    return sums[0] / sums[2], sums[1] / sums[2]


def test_a_resting_head_raises_the_floor_pressure_by_its_weight(tmp_path):
    # A closed tank at rest with a head of mass m on it: the floor's pressure rises by m g / A.
    # Measured at 16 / 32 / 64 columns: +11.0 / +3.6 / +1.7% (the same tank without the head reads
    # the water's own to 0.01 Pa at 32). Moving velocities the correction's part of the pressure
    # read +21.6 / +0.16 / +3.6%: the 0.16% at 32 was a crossing, not convergence. Bounds: at 32
    # between 0 and 4.5%, and under 0.4 of the error at 16.
    errors = []
    for columns in (16, 32):
        rise, load = floor_rise(tmp_path, columns)
        errors.append(rise / load - 1.0)
        print(f"{columns} columns: floor pressure over the water's {rise:.2f} Pa; m g / A = {load:.2f} Pa "
              f"({errors[-1]:+.2%})")
        assert load > 25.0  # a head of ~1.5 cm at ~200 kg/m^3
    assert 0.0 < errors[1] < 0.045
    assert errors[1] < 0.4 * errors[0]


def test_in_3d_the_floor_carries_the_heads_weight(tmp_path):
    # A 3D tank (12 x 16 x 12 cells, water 6 deep, a head of ~1.9 cm): the floor's mean pressure
    # with the head's load against the same scene with the load switched off, averaged over
    # 1.1-1.6 s. Measured: 37.09 Pa against m g / A = 36.96 Pa (+0.35%). Bound 2%. (Against the water
    # particles' own weight the unloaded floor reads 13 Pa high: the particles the new films took
    # leave the top cells less full, which the pressure solve counts as full water; docs/foam.md.)
    # The films' weight 5% heavy in the stage gives +5.2%.
    dx, width = 0.005, 0.06

    def run(loaded):
        scene = Scene(domain=Domain(size=(width, 16 * dx, width), cell_size=dx),
                      materials={"water": Material("water"), "air": Material("air", kind="gas")},
                      shapes=[Box("water", (0, 0, 0), (width, 6 * dx, width)),
                              Box("air", (0, 7 * dx, 0), (width, 10 * dx, width))],
                      solver=SolverSettings(particles_per_cell=8),
                      output=Output(path=str(tmp_path / "h3.usdc"), frames=2, fps=30.0),
                      effects={"foam": Foam(head=True, drainage=False, lifetime=1e6)})
        sim = Simulation(scene, "cpu")
        if not loaded:
            sim.stage("foam").head.load = lambda ctx: None
        sums = np.zeros(3)
        while sim.time < 1.6:
            dt = sim.stable_dt() * 0.9999
            step(sim)
            if sim.time > 1.1:
                load = foam_masses(sim, foam_mask(sim)).sum() * G / width ** 2
                sums += dt * np.array([sim.pressure_numpy()[:, 0, :].astype(np.float64).mean(), load, 1.0])
        return sums[0] / sums[2], sums[1] / sums[2]

    (p_on, load), (p_off, _) = run(True), run(False)
    print(f"3D: floor {p_on:.2f} Pa loaded, {p_off:.2f} unloaded; m g / A = {load:.2f} Pa")
    assert load > 30.0
    assert (p_on - p_off) / load == pytest.approx(1.0, abs=0.02)


def test_the_head_stacks_to_its_volume_over_the_area(tmp_path):
    # The foam rests on the water packed: each column's highest bubble stands about the column's
    # foam volume over its area above the water (its height). Measured after 0.3 s: the height
    # 15.6 mm (4 cells of gas at 0.2 liquid: 5 cells, 15.6 mm); |top bubble - (surface + height)|
    # 0.56 cells on average, median 0.3 (a bubble settles toward its place at up to rise_speed, and
    # the place moves as its neighbours do), 3.4 at most. Bounds: the height 12-17 mm, the median
    # half a cell, the mean 0.75. Stacked without the foam below (`stack` left out of the place),
    # the gaps become 2.2 cells.
    sim = Simulation(tank(tmp_path, drainage=False, lifetime=1e6), "cpu")
    while sim.time < 0.3:
        step(sim)
    head, dx = sim.stage("foam").head, sim.grid.dx
    surface, top = head.cells.surface.numpy()[1:-1, 0, 0], head.cells.top.numpy()[1:-1, 0, 0]
    mask = foam_mask(sim)
    x = sim.particles.x.numpy()[:sim.num_particles][mask]
    column = np.floor((x[:, 0] - sim.ctx.geometry.origin[0]) / dx).astype(int) - 1
    highest = np.array([x[column == c, 1].max() for c in range(len(top))])
    gap = np.abs(highest - top) / dx
    assert sim.stage("foam").summary_lines(sim.ctx) == [
        f"  foam: a two-way head, bubbles burst at drawn lifetimes (mean 1e+06 s); it stands "
        f"{head.height() * 1e3:.3g} mm tall on average"]
    print(f"height {np.mean(top - surface) * 1e3:.2f} mm; top bubble off by {gap.mean():.2f} cells "
          f"(median {np.median(gap):.2f}, max {gap.max():.2f})")
    assert 0.012 < np.mean(top - surface) < 0.017
    assert np.median(gap) < 0.5 and gap.mean() < 0.75


# ------------------------------------------------------ momentum: what the foam loses, the water gains
def test_foam_and_water_trade_momentum_exactly(tmp_path):
    # Step by step: the impulse the water's support gives the foam (its momentum change less its
    # weight's impulse, from the particles before and after they move) equals, reversed, the
    # impulse put on the water's faces before the next pressure solve (rho_face dx^3 du over the
    # faces, the momentum the pressure solve itself counts: it is what gravity and the pressure
    # change), nothing left booked. Measured over 30 steps, along gravity: largest relative
    # mismatch 9e-8 (float32 velocities). Bound 1e-5. A 1% error in the faces' share (push_face)
    # gives 1e-2.
    sim = Simulation(tank(tmp_path, drainage=False, lifetime=1e6), "cpu")
    stage = sim.stage("foam")
    head, f, g = stage.head, sim.fields, np.array([0.0, -G, 0.0])
    given, received = [], []
    advance, load = head.advance, head.load

    def measured_advance(ctx, dt, book, vented):
        mask = foam_mask(sim)
        ids = sim.particles.ids.numpy()[:sim.num_particles][mask].copy()
        v0, m = sim.particles.v.numpy()[:sim.num_particles][mask].astype(np.float64), foam_masses(sim, mask)
        advance(ctx, dt, book, vented)
        after = sim.particles.v.numpy()[:sim.num_particles][mask].astype(np.float64)
        assert (sim.particles.ids.numpy()[:sim.num_particles][mask] == ids).all()  # none burst or moved
        given.append((m[:, None] * (after - v0 - dt * g)).sum(axis=0))

    def measured_load(ctx):
        k = 1.0 / sim.grid.dx ** 3
        before = [f.vel[a].numpy().astype(np.float64).copy() for a in range(2)]
        load(ctx)
        got = []
        for a in range(2):
            inv_rho = f.inv_rho[a].numpy().astype(np.float64)
            du = f.vel[a].numpy().astype(np.float64) - before[a]
            got.append((du[inv_rho > 0] / inv_rho[inv_rho > 0]).sum() / k)
        received.append(np.array(got + [0.0]))
        # all of it taken, but the float64 remainders of its float32 shares
        assert np.abs(head.cells.impulse.numpy()).max() <= 1e-12

    head.advance, head.load = measured_advance, measured_load
    while sim.stats.steps < 40:
        step(sim)
    worst = 0.0
    for k in range(10, 39):  # after the layer has become foam; the water takes step k's at step k + 1
        # Along gravity: the side walls also stop foam pushed across (wall_stopped, after the
        # support is booked), so across gravity the foam's change is the water's and the walls'.
        worst = max(worst, abs(received[k + 1][1] + given[k][1]) / abs(given[k][1]))
    print(f"largest mismatch {worst:.1e}; support impulse per step {given[20]} N s")
    assert worst < 1e-5
    assert given[20][1] > 0.0  # the water holds the foam up


# --------------------------------------------------------------- liquid: water + films + owed is constant
def test_liquid_moves_between_water_and_films_exactly(tmp_path):
    # New films take their liquid from the water under them; what drains out of the head's bottom and
    # what burst films held is owed back and becomes water particles. Water (the liquid particles'
    # rest volume) + films + owed is constant: measured 0 at every step (float64 sums of the float32
    # volumes each side books). Bound 1e-12 of the water. The core's liquid budget (added - held -
    # left) stays closed too: measured 0. A water particle made 0.1% bigger than booked gives 4e-5.
    sim = Simulation(tank(tmp_path, gas=0.025, collapse="drainage", burst_fraction=0.05, viscosity=1e-5,
                          bubble_radius=2.5e-4), "cpu")
    stage = sim.stage("foam")

    def liquid():
        n = sim.num_particles
        water = (sim.particles.phase.numpy()[:n] == PHASE_LIQUID) & (sim.particles.active.numpy()[:n] == 1)
        films = sim.particles.foam_liquid.numpy()[:n][foam_mask(sim)].astype(np.float64).sum()
        return sim.particles.vol0.numpy()[:n][water].astype(np.float64).sum() + films + stage.head.owed()

    start, worst = liquid(), 0.0
    while sim.time < 0.6:
        step(sim)
        worst = max(worst, abs(liquid() - start) / start)
    budget, core = stage.liquid_budget(sim.ctx), sim.mass_budget()["liquid"]
    print(f"largest imbalance {worst:.1e}; made {budget['water_made']:.2e} m^3, burst {budget['burst']:.2e}, "
          f"core budget error {core['error']:.1e} kg")
    assert worst < 1e-12
    assert budget["water_made"] > 1e-7 and budget["burst"] > 1e-8  # water was made back; films burst
    assert abs(core["error"]) < 1e-6 * core["held"]


# ---------------------------------------------- collapse by drainage: the height the equation predicts
@pytest.mark.parametrize("columns", [16, 32])
def test_a_head_drains_down_to_the_height_where_its_films_burst(tmp_path, columns):
    # collapse = "drainage": films burst when drainage has thinned them to burst_fraction f. A head on
    # its pool drains toward the steady profile alpha(h) = (0.36^-1/2 + K1 h / (2 K2))^-2, so it
    # stands, once drained, where alpha = f: h_eq = (2 K2 / K1)(f^-1/2 - 0.36^-1/2) = 19.0 mm here
    # (0.25 mm bubbles, f = 0.05; viscosity 1e-5 Pa s so it drains in a second). From 2.3 cm it
    # decays and stops. Measured at 2 s: 19.17 mm (+0.7%) at 16 columns, 18.58 mm (-2.5%) at 32,
    # 19.73 mm (+3.6%) at 64 (by hand: 25 s of CPU); bound 5%. K1 3% high in
    # the stage (h_eq 3% lower) gives 16.90 mm (-11%) and 18.08 mm (-5.1%).
    sim = Simulation(tank(tmp_path, columns, gas=0.025, collapse="drainage", burst_fraction=0.05,
                          viscosity=1e-5, bubble_radius=2.5e-4), "cpu")
    k1, k2 = fd.drainage_coefficients(2.5e-4, 1000.0, G, 1e-5, 0.072, 50.0)
    h_eq = 2 * k2 / k1 * (0.05 ** -0.5 - 0.36 ** -0.5)
    head = sim.stage("foam").head
    heights = []
    while sim.time < 2.0:
        step(sim)
        heights.append(np.mean(head.cells.top.numpy()[1:-1, 0, 0] - head.cells.surface.numpy()[1:-1, 0, 0]))
    print(f"{columns} columns: head {max(heights) * 1e3:.1f} mm -> {heights[-1] * 1e3:.2f} mm, "
          f"h_eq {h_eq * 1e3:.2f} mm")
    assert max(heights) > 1.1 * h_eq  # it stood taller
    assert heights[-1] == pytest.approx(h_eq, rel=0.05)


# ------------------------------------------------- collapse by lifetimes: Bikerman's decay of the height
def test_a_heads_height_decays_at_the_set_time_constant(tmp_path):
    # collapse = "lifetime" (the default) on a head: the bubbles burst at the end of their drawn
    # lifetimes (stratified), so the head's height (its volume over the area) falls as
    # exp(-t / lifetime). The fitted time constant of the mean height over 0.05-0.6 s against the set
    # 0.2 s: measured +1.32%, +0.62%, -0.002% at 32, 64, 128 columns (383, 1536, 6144 bubbles; 0.8,
    # 2.4, 10 s of CPU): order 1.1, then to the sampling's floor. Bound 2% each (the issue asks 5%),
    # falling with resolution. Lifetimes 3% long give +4.6%, +3.6%, +2.9%.
    errors = []
    for columns in (32, 64, 128):
        sim = Simulation(tank(tmp_path, columns, drainage=False, lifetime=0.2, lifetimes="stratified"), "cpu")
        head, times, heights = sim.stage("foam").head, [], []
        while sim.time < 0.6:
            step(sim)
            if sim.time > 0.05:
                times.append(sim.time)
                heights.append(np.mean(head.cells.top.numpy()[1:-1, 0, 0] - head.cells.surface.numpy()[1:-1, 0, 0]))
        tau = -1.0 / np.polyfit(times, np.log(heights), 1)[0]
        errors.append(tau / 0.2 - 1.0)
    print("time constant errors", errors)
    assert all(abs(e) < 0.02 for e in errors)
    assert abs(errors[2]) < abs(errors[0])


def test_a_resumed_head_runs_on_as_if_never_stopped(tmp_path):
    # The head's booked impulses, the liquid owed per column and the count of water made back are
    # checkpointed: a run saved after 2 frames and resumed matches the straight run bit for bit
    # after 4, and its liquid ledger too. Without the owed liquid in the checkpoint the ledgers differ.
    kw = dict(gas=0.025, collapse="drainage", burst_fraction=0.05, viscosity=1e-5, bubble_radius=2.5e-4)
    straight = Simulation(tank(tmp_path, 16, **kw), "cpu")
    for _ in range(4):
        straight.advance_frame()
    first = Simulation(tank(tmp_path, 16, **kw), "cpu")
    for _ in range(2):
        first.advance_frame()
    save_checkpoint(first, tmp_path / "ck.npz")
    resumed = Simulation(tank(tmp_path, 16, **kw), "cpu")
    load_checkpoint(resumed, tmp_path / "ck.npz")
    for _ in range(2):
        resumed.advance_frame()
    a, b = straight.particles_numpy(True), resumed.particles_numpy(True)
    for key in ("positions", "velocities", "material", "mass"):
        np.testing.assert_array_equal(a[key], b[key])
    assert straight.stage("foam").head.state.water_made > 0
    assert straight.stage("foam").liquid_budget(straight.ctx) == resumed.stage("foam").liquid_budget(resumed.ctx)


# --------------------------------------------------------------------------- opt-in, and bad settings
def test_without_head_no_head_kernel_runs(tmp_path):
    scene = tank(tmp_path, lifetime=1e6)
    scene.effects["foam"].head = False
    sim = Simulation(scene, "cpu")
    for _ in range(3):
        step(sim)
    assert not HEAD_KERNELS & set(sim.launches) and "gas_to_foam" in sim.launches
    assert "force" not in sim.stage("foam").hooks()


@pytest.mark.parametrize("keys, key, words", [
    ({"burst_fraction": -0.01}, "[effects.foam].burst_fraction", "> 0"),
    ({"burst_fraction": 0.3}, "[effects.foam].burst_fraction", "liquid_fraction"),
    ({"collapse": "sometimes"}, "[effects.foam].collapse", "lifetime"),
    ({"collapse": "drainage", "head": False}, "[effects.foam].collapse", "head = true"),
    ({"collapse": "drainage", "drainage": False}, "[effects.foam].collapse", "drainage = true"),
    ({"head": "yes"}, "[effects.foam].head", "true or false"),
])
def test_bad_head_settings_are_refused_by_name(tmp_path, keys, key, words):
    scene = tank(tmp_path)
    for k, v in keys.items():
        setattr(scene.effects["foam"], k, v)
    with pytest.raises(SceneError) as err:
        scene.validate()
    print(err.value)
    assert key in str(err.value) and words in str(err.value)


def test_a_head_without_gravity_is_refused(tmp_path):
    scene = tank(tmp_path)
    scene.domain.gravity = (0.0, 0.0)
    with pytest.raises(SceneError) as err:
        scene.validate()
    assert "[effects.foam].head" in str(err.value) and "gravity" in str(err.value)


# ------------------------------------------------------------------------------ a head in a glass
def test_a_head_in_a_glass_stays_on_its_liquid(tmp_path):
    # A 2D glass (one cell of wall, its inner faces part-way into the wall's cells, as a round glass's
    # are) holding water under a layer of gas that becomes the head. The grid sees the wall as whole
    # solid cells, the collider puts particles on its true face: foam there lies in a solid cell, in a
    # column with no water. Measured over 0.4 s, from each bubble's second step on (a bubble is made
    # where its gas was, which may be such a cell): no foam in a solid cell, none more than a cell
    # under its column's water, none outside the glass's cavity. Before the head kept foam out of
    # solid cells, up to 16 bubbles at a time lay in the wall's cells and 14 had left the cavity,
    # falling through the wall and the glass's floor to the domain's floor; without the move out of
    # a solid cell alone, 7 in solid cells; without the stop at one alone, 1.
    dx = 0.0025
    inner = (0.022, 0.0585)  # the cavity: the walls' cells are [0.02, 0.0225] and [0.0575, 0.06]
    scene = Scene(domain=Domain(size=(0.08, 0.08), cell_size=dx),
                  materials={"water": Material("water"), "air": Material("air", kind="gas")},
                  shapes=[Box("water", min=(0.02, 0.0), max=(0.06, 0.02)),
                          Box("air", min=(0.02, 0.0225), max=(0.06, 0.0325))],
                  colliders=[Collider("glass", center=(0.04, 0.0), radius=0.0205, height=0.05, wall_thickness=dx)],
                  solver=SolverSettings(particles_per_cell=4),
                  output=Output(path=str(tmp_path / "glass.usdc"), frames=2, fps=30.0),
                  effects={"foam": Foam(head=True, drainage=False, lifetime=1e6)})
    sim = Simulation(scene, "cpu")
    origin = np.array(sim.ctx.geometry.origin)[:2]
    in_solid = below = outside = 0
    was_foam = np.zeros(0, bool)
    while sim.time < 0.4:
        step(sim)
        mask = foam_mask(sim)
        old = mask & np.pad(was_foam, (0, len(mask) - len(was_foam)))[:len(mask)]
        was_foam = mask
        x = sim.particles.x.numpy()[:sim.num_particles][old][:, :2].astype(np.float64)
        solid = sim.fields.types.numpy()[:, :, 0] >= SOLID_FREE_SLIP
        fill = np.where(solid, 0.0, np.minimum(sim.fields.liq_volume.numpy()[:, :, 0] / dx ** 2 / dx, 1.0))
        cells = np.floor((x - origin) / dx).astype(int)
        in_solid = max(in_solid, int(solid[cells[:, 0], cells[:, 1]].sum()))
        cavity = (x[:, 0] > inner[0]) & (x[:, 0] < inner[1]) & (x[:, 1] > dx)
        outside = max(outside, int((~cavity).sum()))
        n_below = 0
        for (i, _), y in zip(cells[cavity], x[cavity, 1]):
            wet = np.nonzero(fill[i] >= 0.5)[0]  # the column's water: its highest cell at least half full
            n_below += bool(len(wet)) and y < origin[1] + (wet[-1] + fill[i, wet[-1]]) * dx - dx
        below = max(below, n_below)
    print(f"{was_foam.sum()} foam; at most {in_solid} in a solid cell, {below} under the water, {outside} outside")
    assert was_foam.sum() > 150
    assert in_solid == 0 and below == 0 and outside == 0


# ------------------------------------------------------------- a bubble under the head
def test_a_bubble_under_the_head_is_not_given_the_heads_load(tmp_path):
    # The load goes on the water's faces LOAD_DEPTH cells under the surface. Where a bubble sits
    # there, those faces are the gas's: the same impulse over the gas's density moved them about a
    # thousand times faster than the water (a beer with a head blew up: 162 m/s on one face in one
    # step). Here a bubble 4 cells across, its centre 5 cells under a 3 cm deep water's surface,
    # with a head on top, over 12 steps. Measured, fastest gas particle: 0.55 m/s (without a head
    # 0.43 m/s: the bubble rising and bursting); with the load put on gas faces, 8.9 m/s at the
    # fourth step. Bound 1 m/s.
    from warp_mpm_bubbles import Sphere
    scene = tank(tmp_path, columns=32, gas=0.0125, lifetime=50.0)
    dx = W / 32
    depth = round(0.03 / dx) * dx
    scene.shapes.append(Sphere("air", center=(0.5 * W, depth - 5.0 * dx), radius=2.0 * dx))
    sim = Simulation(scene, "cpu")
    fastest = 0.0
    for _ in range(12):
        step(sim)
        p = sim.particles_numpy()
        gas = (p["phase"] == 1)
        if gas.any():
            fastest = max(fastest, float(np.linalg.norm(p["velocities"][gas], axis=1).max()))
    assert fastest < 1.0, f"the bubble under the head moved at {fastest:.3g} m/s"
