"""No voids (issue #12): a particle-free cell inside the liquid is not a free surface (core/voids.py),
gas films retract without leaving holes (physics/tension.py), and air a splash closes over becomes a
resolved bubble. Small 2D grids; docs/design.md#voids has the before/after measurements."""

import numpy as np
import pytest
import warp as wp

from warp_mpm_bubbles import Box, Cylinder, Domain, Material, Output, Scene, SolverSettings, Sphere
from warp_mpm_bubbles.core.grid import EMPTY, FLUID, PHASE_GAS, PHASE_LIQUID
from warp_mpm_bubbles.core.simulation import Simulation
from warp_mpm_bubbles.diagnostics import void_cells

wp.config.quiet = True
L = 0.02  # tank width, m


def filled_tank(cells, out):
    """Hysing et al. (2009) case 1 scaled to a 2 x 4 cm closed tank, completely filled: Re 35, Eo 10,
    density and viscosity ratios 10, incompressible gas; no-slip top and bottom, free-slip sides.
    Defaults otherwise (sharp interface, the liquid's own field, films retract)."""
    return Scene(
        domain=Domain(size=(L, 2 * L), cell_size=L / cells,
                      walls={"x_min": "free_slip", "x_max": "free_slip", "y_min": "no_slip", "y_max": "no_slip"}),
        materials={"water": Material("water", density=1000.0, viscosity=0.0895, surface_tension=0.0981),
                   "air": Material("air", kind="gas", density=100.0, viscosity=0.00895, eos="incompressible")},
        shapes=[Box("water", min=(0.0, 0.0), max=(L, 2 * L)), Sphere("air", center=(L / 2, L / 2), radius=L / 4)],
        output=Output(path=str(out / "tank.usdc")), name="filled_tank")


def holes(sim):
    """Particle-free cells (liquid and gas particles where they are now) that are not open air."""
    p = sim.particles_numpy()
    keep = p["phase"] <= PHASE_GAS
    idx = np.floor((p["positions"][keep] - np.asarray(sim.grid.origin)) / sim.grid.dx).astype(int)
    count = np.zeros(sim.grid.cells, int)
    np.add.at(count, tuple(idx.T), 1)
    types = sim.fields.types.numpy().copy()
    types[(count == 0) & (types == FLUID)] = EMPTY
    return void_cells(types, sim.grid.ghost, sim.up)


def rise(sim, t_end, with_pass=True):
    """Step to t_end; per step the voids (diagnostics), the interior EMPTY cells, and the holes just
    before and just after the films retract."""
    if not with_pass:
        sim.voids.apply = lambda dt: None
    stage = sim.stage("surface_tension")
    retract = stage.after_g2p
    film = []

    def measured(ctx, dt):  # a hook receives the step context; the holes are read from the simulation
        before = holes(sim)
        retract(ctx, dt)
        film.append((before, holes(sim)))

    stage.after_g2p = measured
    interior = sim.grid.interior_slice()
    voids, empty = [], []
    while sim.time < t_end - 1e-12:
        dt = min(sim.stable_dt(), t_end - sim.time)
        sim.step(dt)
        sim.time += dt
        types = sim.fields.types.numpy()
        voids.append(void_cells(types, sim.grid.ghost, sim.up))
        empty.append(int((types[interior] == EMPTY).sum()))
    return np.array(voids), np.array(empty), np.array(film)


@pytest.fixture(scope="module", params=[16, 24])
def tank(request, tmp_path_factory):
    sim = Simulation(filled_tank(request.param, tmp_path_factory.mktemp("tank")), "cpu")
    y0 = sim.particles_numpy()
    return request.param, sim, y0, rise(sim, 0.1)


def test_a_filled_tank_with_a_rising_bubble_has_no_voids_and_no_empty_cells(tank):
    cells, sim, _, (voids, empty, _) = tank
    assert len(voids) > 50  # steps
    assert voids.max() == 0 and empty.max() == 0


def test_film_retraction_never_empties_a_cell(tank):
    # Holes (particle-free cells inside) counted just before and after the films retract: the
    # retraction keeps the partition of space, so it adds none. Before the fix it added up to
    # one a step at 32 cells (physics/tension.retract_gas_films); the holes g2p opens are closed by
    # the next solve (a handful at any time, measured 0-2 at 16 cells and 0-4 at 24).
    _, _, _, (_, _, film) = tank
    assert np.all(film[:, 1] <= film[:, 0])
    assert film[:, 0].max() <= 10


def test_the_bubble_rises_and_keeps_its_gas(tank):
    cells, sim, start, _ = tank
    p = sim.particles_numpy()
    gas0, gas = start["phase"] == PHASE_GAS, p["phase"] == PHASE_GAS
    # Incompressible gas keeps its J (transfer_kernels.update_gas_J): its volume is exact. It drifted
    # -2.2% at 16 cells while update_gas_J booked the solve's residual and the closed tank's removed
    # mean as gas volume change (issue #12).
    assert p["volume"][gas].sum() == pytest.approx(start["volume"][gas0].sum(), rel=1e-6)
    y0 = (start["positions"][gas0, 1]).mean()
    y = (p["positions"][gas, 1]).mean()
    # Measured 0.438 L (16 cells) and 0.440 L (24; 0.433 and 0.435 before films retracted only from
    # the liquid's side); Hysing et al.'s reference centroid passes 0.42 L about then (t = 0.1 s is
    # their t = 2.2).
    assert 0.40 * L < y - y0 < 0.47 * L, (cells, y - y0)


def test_without_the_void_pass_the_same_tank_has_voids_only_where_a_hole_is_punched(tmp_path):
    # The test above can fail. With the void pass off the tank stays free of voids: liquid and
    # incompressible gas are one medium for the correction, which closes the interface's under-filled
    # cells before they empty (grid_kernels.cell_excess; the gas's own over-fill rule before it left
    # 4 void cells), and gas films retract only from the liquid's side of the interface (with the
    # bubble's own gas retracting, the correction off too grew 10; now 0 even so). So a 4 x 4-cell hole
    # is punched into its liquid: without the pass it stays EMPTY, cells closed off inside the liquid
    # that void_cells counts (measured 11-12 a step).
    sim = Simulation(filled_tank(24, tmp_path), "cpu")
    voids, empty, _ = rise(sim, 0.1, with_pass=False)
    assert voids.max() == 0 and empty.max() == 0
    sim = Simulation(filled_tank(24, tmp_path), "cpu")
    dx = sim.grid.dx
    assert punch_hole(sim, lo=(2 * dx, 30 * dx), hi=(6 * dx, 34 * dx)) >= 40
    voids, empty, _ = rise(sim, 0.002, with_pass=False)
    assert voids.max() > 0 and empty.max() > 0


# ------------------------------------------------------------------ a hole punched into the water
def pool(out, gas=False):
    """A 10 x 10 cm closed tank, water 7.5 cm deep, 16 cells across (with gas: a small bubble in a corner
    makes it a gas scene)."""
    materials = {"water": Material("water")}
    shapes = [Box("water", min=(0.0, 0.0), max=(0.1, 0.075))]
    if gas:
        materials["air"] = Material("air", kind="gas")
        shapes.append(Sphere("air", center=(0.085, 0.06), radius=0.008))
    return Scene(domain=Domain(size=(0.1, 0.1), cell_size=0.1 / 16), materials=materials, shapes=shapes,
                 solver=SolverSettings(), output=Output(path=str(out / "pool.usdc")), name="pool")


def punch_hole(sim, lo=(0.03, 0.02), hi=(0.05, 0.04)):
    """Retire the liquid particles in a box: a particle-free hole, 3 x 3 cells, under 3.5 cm of water."""
    x = sim.particles.numpy("x")
    inside = np.all((x[:, :2] > lo) & (x[:, :2] < hi), axis=1) & (sim.particles.numpy("phase") == PHASE_LIQUID)
    sim.particles.active.numpy()[: sim.particles.count][inside] = 0
    return int(inside.sum())


def track(sim, steps):
    out = []
    for _ in range(steps):
        sim.step(sim.stable_dt())
        out.append((void_cells(sim.fields.types.numpy(), sim.grid.ghost, sim.up), holes(sim)))
    return np.array(out)


SMALL_HOLE = dict(lo=(0.03, 0.02), hi=(0.0425, 0.0325))  # 2 x 2 cells


def test_a_hole_in_liquid_only_water_is_closed_by_the_pressure(tmp_path):
    sim = Simulation(pool(tmp_path), "cpu")
    assert punch_hole(sim, **SMALL_HOLE) > 10
    after = track(sim, 20)
    assert after[:, 0].max() == 0  # never a free surface
    # Closed by the volume correction asking each hole cell for its full deficit: with the share
    # per step, 2, 2, then 0 particle-free cells; as a rate (tau = 10 ms, at most the whole deficit
    # per step) 0 after the first step. Without the pass (below) the hole stays a free surface.
    assert after[3:, 1].max() == 0
    off = Simulation(pool(tmp_path), "cpu")
    punch_hole(off, **SMALL_HOLE)
    off.voids.apply = lambda dt: None
    before = track(off, 3)
    assert before[0, 0] >= 1  # without the pass: an EMPTY cell inside the water, at p = 0


def test_air_a_splash_closes_over_becomes_a_rising_bubble(tmp_path):
    sim = Simulation(pool(tmp_path, gas=True), "cpu")
    budget0 = sim.gas_budget()
    n_gas0 = int((sim.particles_numpy()["phase"] == PHASE_GAS).sum())
    punch_hole(sim)
    sim.step(sim.stable_dt())
    # Seeded, then splatted again in the same step: its solve saw gas cells, no EMPTY cell inside the
    # water (before: 5 void cells at p = 0 for that step).
    assert void_cells(sim.fields.types.numpy(), sim.grid.ghost, sim.up) == 0
    p = sim.particles_numpy()
    trapped = (p["phase"] == PHASE_GAS) & (p["positions"][:, 0] < 0.06)
    ppc = sim.scene.solver.particles_per_cell
    # The hole's EMPTY part (its rim cells get fill from the water around) is seeded at ppc a cell.
    # (a lone void cell elsewhere stays liquid: measured 5 of the 6 void cells seeded).
    assert 4 * ppc <= trapped.sum() <= ppc * sim.voids.last_voids and trapped.sum() % ppc == 0
    assert int((p["phase"] == PHASE_GAS).sum()) - n_gas0 == trapped.sum()
    budget = sim.gas_budget()
    assert budget["trapped"] > 0
    assert budget["total"] == pytest.approx(budget0["total"], rel=1e-9)  # booked as taken from the air
    ids = p["ids"][trapped]
    y0 = p["positions"][trapped, 1].mean()
    for _ in range(15):
        sim.step(sim.stable_dt())
    q = sim.particles_numpy()
    mine = np.isin(q["ids"], ids)
    assert q["positions"][mine, 1].mean() > y0 + 0.003  # buoyant: it rises


def splash(out):
    """A 2.4 cm water disc thrown at 1.5 m/s into a 4 cm pool, 10 x 10 cm closed tank, 32 cells, with
    water's surface tension and a small air bubble (a gas scene): the pour's splash, small."""
    return Scene(domain=Domain(size=(0.1, 0.1), cell_size=0.1 / 32),
                 materials={"water": Material("water", surface_tension=0.072), "air": Material("air", kind="gas")},
                 shapes=[Box("water", min=(0.0, 0.0), max=(0.1, 0.04)),
                         Cylinder("water", center=(0.05, 0.065), radius=0.012, velocity=(0.0, -1.5)),
                         Sphere("air", center=(0.09, 0.01), radius=0.004)],
                 output=Output(path=str(out / "splash.usdc")), name="splash")


def splash_voids(sim, t_end=0.12):
    voids = []
    while sim.time < t_end - 1e-12:
        dt = min(sim.stable_dt(), t_end - sim.time)
        sim.step(dt)
        sim.time += dt
        voids.append(void_cells(sim.fields.types.numpy(), sim.grid.ghost, sim.up))
    return np.array(voids)


def test_a_splash_leaves_no_voids_and_its_trapped_air_becomes_bubbles(tmp_path):
    from warp_mpm_bubbles.io.runner import _voids_line

    sim = Simulation(splash(tmp_path), "cpu")
    budget0 = sim.gas_budget()
    voids = splash_voids(sim)
    # A large void is seeded with gas and the step splats again, so no solve sees it EMPTY (measured:
    # 2 pockets, no void at any step; when a pocket stayed EMPTY for its first step, voids in 2 of 120
    # steps, 16 void cell-steps in all).
    assert 1 <= sim.voids.pockets <= 4 and voids.max() == 0
    assert sim.gas_budget()["total"] == pytest.approx(budget0["total"], rel=1e-9)
    assert "frames had cells closed off inside the liquid" in _voids_line(sim)
    again = Simulation(splash(tmp_path), "cpu")  # the host labelling and the seeding are deterministic
    splash_voids(again)
    np.testing.assert_array_equal(again.particles_numpy()["positions"], sim.particles_numpy()["positions"])
    off = Simulation(splash(tmp_path), "cpu")
    off.voids.apply = lambda dt: None
    before = splash_voids(off)
    assert (before > 0).sum() >= 6 and before.sum() >= 3 * voids.sum()  # measured: 12 steps, 54 cell-steps


def _void_search(types, ghost, up, dim, region=None):
    """VoidSearch.find (the covered cells' box, the device sweeps in it, the host on what they left) on
    a cell-type array: the void cells and their labels."""
    from warp_mpm_bubbles.core.voids import VoidSearch

    launch = lambda kernel, d, inputs: wp.launch(kernel, dim=d, inputs=inputs, device="cpu")  # noqa: E731
    found = VoidSearch(types.shape, ghost, up, dim, "cpu", launch).find(wp.array(types, dtype=wp.int32, device="cpu"),
                                                                        region)
    return (np.zeros((0, 3), int), np.zeros(0, int)) if found is None else found[1:]


def _random_cell_types(rng, dim, sizes, empty_share, open_walls=None):
    """A random field of EMPTY and FLUID cells, (low, high) cells a side and an EMPTY share drawn from
    `empty_share`, in a layer of wall cells: SOLID_NO_SLIP, or EMPTY (open) at a share `open_walls`."""
    from warp_mpm_bubbles.core.grid import SOLID_NO_SLIP

    n = rng.integers(*sizes, 3)
    shape = (n[0] + 2, n[1] + 2, 1 if dim == 2 else n[2] + 2)
    ghost = (1, 1, 1 if dim == 3 else 0)
    types = np.where(rng.random(shape) < rng.uniform(*empty_share), EMPTY, FLUID).astype(np.int32)
    wall = np.ones(shape, bool)
    wall[tuple(slice(g, s - g) for g, s in zip(ghost, shape))] = False
    if open_walls is None:
        types[wall] = SOLID_NO_SLIP
    else:
        types[wall] = np.where(rng.random(wall.sum()) < open_walls, EMPTY, SOLID_NO_SLIP)
    return shape, ghost, types


def test_the_void_search_finds_exactly_the_voids_of_the_rule():
    """The device sweeps and the host's search of what they leave give grid.closed_empty_cells' cells
    and regions (the rule, which labels every EMPTY cell) on random cell types, 2D and 3D, with gravity
    along each axis and sign and without; and a falling block's air needs no host search at all."""
    from warp_mpm_bubbles.core.grid import SOLID_NO_SLIP, closed_empty_cells

    rng = np.random.default_rng(7)
    searched = 0
    for trial in range(80):
        dim = 2 + trial % 2
        shape, ghost, types = _random_cell_types(rng, dim, (4, 12), (0.2, 0.8), open_walls=0.1)
        up = (int(rng.integers(-1, dim)), int(rng.choice([-1, 1])))
        cells, labels = _void_search(types, ghost, up, dim)
        ref_cells, ref_labels = closed_empty_cells(types, ghost, up)
        np.testing.assert_array_equal(cells, ref_cells)
        regions = lambda c, lab: {tuple(map(tuple, c[lab == r])) for r in np.unique(lab)}  # noqa: E731
        assert regions(cells, labels) == regions(ref_cells, ref_labels)
        searched += len(cells) > 0
    assert searched > 10  # the random fields do hold voids
    # A block in mid-air: the air under it is covered, and the sweeps reach all of it on the device.
    types = np.full((18, 18, 18), SOLID_NO_SLIP, np.int32)
    types[1:-1, 1:-1, 1:-1] = EMPTY
    types[5:13, 9:15, 5:13] = FLUID
    cells, _ = _void_search(types, (1, 1, 1), (1, 1), 3)
    assert len(cells) == 0
    types[7:11, 11, 7:11] = EMPTY  # a pocket inside the block: a void
    assert len(_void_search(types, (1, 1, 1), (1, 1), 3)[0]) == 16
    # searched in the grid stages' box (the block's cells and a margin): the same, though the air
    # below the box is covered too
    cells, labels = _void_search(types, (1, 1, 1), (1, 1), 3, region=((3, 7, 3), (15, 17, 15)))
    assert len(cells) == 16 and len(set(labels)) == 1


def test_the_sweeps_in_slabs_mark_what_one_launch_marks():
    """VoidSearch's line sweeps split into slabs (one a thread on the CPU; here 1, 2 and 3 slabs of
    every box, run one after the other) mark the same open air as one launch: random cell types, 2D
    and 3D, gravity along each axis. The marks are compared before the host's search, which would
    cover for cells a wrong slab left unmarked."""
    from warp_mpm_bubbles.core.voids import VoidSearch

    rng = np.random.default_rng(11)
    launch = lambda kernel, d, inputs: wp.launch(kernel, dim=d, inputs=inputs, device="cpu")  # noqa: E731
    marked = 0
    for trial in range(24):
        dim = 2 + trial % 2
        shape, ghost, types = _random_cell_types(rng, dim, (5, 14), (0.3, 0.8))
        up = (int(rng.integers(0, dim)), int(rng.choice([-1, 1])))
        marks = []
        for threads in (1, 2, 3):
            search = VoidSearch(shape, ghost, up, dim, "cpu", launch, threads=threads)
            search.split_cells = 0  # split every box, however small
            search.find(wp.array(types, dtype=wp.int32, device="cpu"))
            marks.append(search.reached.numpy())
        np.testing.assert_array_equal(marks[1], marks[0])
        np.testing.assert_array_equal(marks[2], marks[0])
        marked += int(marks[0].sum())
    assert marked > 100  # the sweeps did mark open air


# ------------------------------------------------------------------ a gap beside an air bubble
def test_a_gap_beside_an_air_bubble_is_the_bubbles_and_closes(tmp_path):
    # Liquid retired along an air bubble's side leaves particle-free cells connected to the gas: a gap
    # in the bubble, not a void closed off in the liquid (issue #12's rule). It stays EMPTY (p = 0), so
    # the bubble's gas and the water around are drawn in: measured 2 gap cells, then 1, then none.
    # Held at the gas's pressure instead, the pour's gaps lasted about 4x longer (docs/design.md#voids).
    from warp_mpm_bubbles.io.runner import _voids_line

    scene = Scene(domain=Domain(size=(0.1, 0.1), cell_size=0.1 / 32),
                  materials={"water": Material("water"), "air": Material("air", kind="gas")},
                  shapes=[Box("water", min=(0.0, 0.0), max=(0.1, 0.075)),
                          Sphere("air", center=(0.05, 0.035), radius=0.01)],
                  output=Output(path=str(tmp_path / "gap.usdc")), name="gap")
    sim = Simulation(scene, "cpu")
    for _ in range(5):
        sim.step(sim.stable_dt())
    punch_hole(sim, lo=(0.0595, 0.03), hi=(0.066, 0.04))
    gaps = []
    for step in range(6):
        sim.step(sim.stable_dt())
        types = sim.fields.types.numpy()
        gaps.append(len(sim.voids.gap_cells))
        assert void_cells(types, sim.grid.ghost, sim.up, sim.voids.gap_mask()) == 0
        assert sim.voids.last_voids == 0
        if step == 0:  # the gap is there, EMPTY, and only the gap mask keeps it out of the voids
            assert gaps[0] >= 1 and np.all(types[tuple(sim.voids.gap_cells.T)] == EMPTY)
            assert void_cells(types, sim.grid.ghost, sim.up) == gaps[0]
    assert gaps[-1] == 0 and max(gaps[3:]) == 0, gaps
    assert "bubble gaps" in _voids_line(sim) and not sim.voids.by_frame


# ------------------------------------------------------------------ the trapped-air threshold
def test_a_void_of_pocket_cells_is_trapped_air_and_one_cell_less_is_liquid(tmp_path):
    # The threshold itself (voids.POCKET_CELLS, "a void region this large is air"): two voids are cut
    # into the water of a gas scene, far from its bubble and from each other, one of exactly
    # POCKET_CELLS cells and one of POCKET_CELLS - 1, and the pass is run on them. The first must be
    # seeded with gas (ppc particles a cell, in its cells), the second made a liquid cell, each by its
    # own rule: a threshold off by one either way (> for >=, or >= POCKET_CELLS - 1) fails.
    from warp_mpm_bubbles.core.voids import POCKET_CELLS

    sim = Simulation(pool(tmp_path, gas=True), "cpu")
    sim.step(sim.stable_dt())  # cells classified; the bubble (x 0.077-0.093 m, y 0.052-0.068 m) is gas
    g, f = sim.grid, sim.fields
    assert sim.voids.pockets == 0 and sim.voids.last_voids == 0
    row = int((0.022 - g.origin[1]) / g.dx)  # 8 cells under the water surface, 3 above the floor
    first = lambda x: int((x - g.origin[0]) / g.dx)  # noqa: E731  (the cell holding x)
    pocket = np.array([(first(0.015) + n, row, 0) for n in range(POCKET_CELLS)])
    gap = np.array([(first(0.045) + n, row, 0) for n in range(POCKET_CELLS - 1)])
    types = f.types.numpy()
    assert np.all(types[tuple(np.concatenate([pocket, gap]).T)] == FLUID)
    assert np.all(f.phase_cells.numpy()[tuple(np.concatenate([pocket, gap]).T)] == PHASE_LIQUID)
    types[tuple(np.concatenate([pocket, gap]).T)] = EMPTY
    f.types.assign(types)
    before = sim.particles_numpy()
    sim.voids.apply(sim.stats.dt_history[-1])

    assert sim.voids.last_voids == 2 * POCKET_CELLS - 1
    assert sim.voids.pockets == 1 and sim.voids.seeded
    p = sim.particles_numpy()
    new = ~np.isin(p["ids"], before["ids"])
    ppc = sim.scene.solver.particles_per_cell
    assert new.sum() == POCKET_CELLS * ppc and np.all(p["phase"][new] == PHASE_GAS)
    cells = np.floor((p["positions"][new] - np.asarray(g.origin)) / g.dx).astype(int)
    cells[:, 2] = 0
    assert {tuple(c) for c in cells} == {tuple(c) for c in pocket}
    types, phases = f.types.numpy(), f.phase_cells.numpy()
    assert np.all(types[tuple(gap.T)] == FLUID) and np.all(phases[tuple(gap.T)] == PHASE_LIQUID)
    assert np.all(types[tuple(pocket.T)] == EMPTY)  # left to the step's second splat, which sees its gas
