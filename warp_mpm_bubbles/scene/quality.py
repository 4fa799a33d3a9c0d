"""Quality presets: named solver settings that trade accuracy for time.

A preset fills the [solver] settings it governs when the scene leaves them unset; a value the
scene sets itself wins. `--quality` on the command line replaces the scene's own values (the
user's latest word). The values come from the measured accuracy-vs-time frontier
(`benchmarks/validation/accuracy_vs_time.py`, benchmarks/results/accuracy_vs_time/cpu.md). Resolution is the one lever that
lowered every error there, so `reference` also refines the grid: `refine` grid cells per
[domain].cell_size along each axis (the scene's geometry and cell_size stay as written).
"""

from __future__ import annotations

DEFAULT_QUALITY = "production"

# particles_per_cell is given per dimension: (2D, 3D). Measured (benchmarks/results/accuracy_vs_time/cpu_presets.md): cg_tolerance moved
# no error between 1e-3 and 1e-7; cfl 1.0 halves the steps of free-surface runs at about twice
# the volume drift, 0.25 lowers it; more than 2 particles per cell and axis lowered no error beyond
# the seed noise and raised the dam break's volume loss (2D and 3D), so every preset keeps 4 / 8.
PRESETS: dict[str, dict] = {
    "preview": {"particles_per_cell": (4, 8), "cfl": 1.0, "cg_tolerance": 1e-3, "refine": 1},
    "production": {"particles_per_cell": (4, 8), "cfl": 0.5, "cg_tolerance": 1e-5, "refine": 1},
    "reference": {"particles_per_cell": (4, 8), "cfl": 0.25, "cg_tolerance": 1e-6, "refine": 2},
}
GOVERNED = ("particles_per_cell", "cfl", "cg_tolerance", "refine")


def preset_value(quality: str, name: str, dim: int):
    value = PRESETS[quality][name]
    return value[dim - 2] if isinstance(value, tuple) else value
