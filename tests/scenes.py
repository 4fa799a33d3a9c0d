"""Small scenes built with the Python API, shared by tests (and handy in a REPL)."""

from warp_mpm_bubbles import Box, Domain, Material, Output, Scene, SolverSettings

WATER = {"water": Material("water", density=1000.0)}


def tank_2d(width=1.0, height=1.0, depth=0.5, cells=32, ppc=4, out="tank.usdc", **solver):
    """Water at rest, `depth` deep, in a closed free-slip tank."""
    return Scene(
        domain=Domain(size=(width, height), cell_size=width / cells),
        materials=dict(WATER),
        shapes=[Box("water", min=(0.0, 0.0), max=(width, depth))],
        solver=SolverSettings(particles_per_cell=ppc, **solver),
        output=Output(path=str(out), frames=4),
        name="tank_2d",
    )


def dam_break_2d(a=0.1, cells_per_a=16, length=6.0, ppc=4, out="dam.usdc", **solver):
    """Martin & Moyce's column: width a, height 2a, against the left wall of a tank `length` a long."""
    dx = a / cells_per_a
    return Scene(
        domain=Domain(size=(length * a, 2.5 * a), cell_size=dx),
        materials=dict(WATER),
        shapes=[Box("water", min=(0.0, 0.0), max=(a, 2 * a))],
        solver=SolverSettings(particles_per_cell=ppc, **solver),
        output=Output(path=str(out), frames=4),
        name="dam_break_2d",
    )
