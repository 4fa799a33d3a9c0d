"""Small scenes built with the Python API, shared by tests (and handy in a REPL)."""

from warp_mpm_bubbles import Box, Domain, Material, Output, Scene, SolverSettings

WATER = {"water": Material("water", density=1000.0)}

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
