"""Small scenes built with the Python API, shared by tests (and handy in a REPL)."""

# The scenes the benchmarks use too live in benchmarks/cases.py, the one home of shared cases.
from benchmarks.cases import WATER, dam_break_2d, tank_2d  # noqa: F401  (re-exported for the tests)


def squeezed_block_after_one_step(out, dt: float, block=(0.0, 0.1), squeeze: float = 0.9, **solver):
    """Water filling a 2D box (16 cells a side, no gravity) squeezed into 90% of its side, so each
    cell is about 1.23x over-full, then one step of dt: (sim, div, phi), the faces' projected
    divergence per cell and the cells' rest-volume fractions. The volume correction's request is all
    that moves this water (the tests of its rate, tests/test_energy.py and tests/test_volume_fill.py).
    `block` (lo, hi along both axes) and `squeeze` (about the box's middle) place a smaller block in
    open air instead (tests/test_volume_shift.py's surface cells)."""
    import warp as wp

    from warp_mpm_bubbles import Box, Domain, Material, Output, Scene, SolverSettings
    from warp_mpm_bubbles.core.simulation import Simulation

    lo, hi = block
    scene = Scene(domain=Domain(size=(0.1, 0.1), cell_size=0.1 / 16, gravity=(0.0, 0.0)),
                  materials={"water": Material("water")}, shapes=[Box("water", (lo, lo), (hi, hi))],
                  solver=SolverSettings(**solver), output=Output(path=str(out)))
    sim = Simulation(scene, "cpu")
    x = sim.particles.x.numpy()
    x[:, :2] = 0.05 + squeeze * (x[:, :2] - 0.05)
    sim.particles.x = wp.array(x, dtype=wp.vec3, device=sim.device)
    sim.step(dt)
    dx = sim.grid.dx
    u, v = sim.fields.vel[0].numpy(), sim.fields.vel[1].numpy()
    div = ((u[1:] - u[:-1]) + (v[:, 1:] - v[:, :-1]))[:, :, 0] / dx
    return sim, div, sim.fields.liq_volume.numpy()[:, :, 0] / dx**3

# A small 2D tank as a scene file (fill in out and frames with str.format): the CLI tests' scene.
SMALL_2D = """
name = "small"
[domain]
size = [0.4, 0.2]
cell_size = 0.0125
[materials.water]
density = 1000.0
[[shapes]]
type = "box"
material = "water"
min = [0.0, 0.0]
max = [0.1, 0.15]
[output]
path = "{out}"
fps = 60
frames = {frames}
"""
