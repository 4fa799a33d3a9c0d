"""Small scenes built with the Python API, shared by tests (and handy in a REPL)."""

# The scenes the benchmarks use too live in benchmarks/cases.py, the one home of shared cases.
from benchmarks.cases import WATER, dam_break_2d, tank_2d  # noqa: F401  (re-exported for the tests)

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
