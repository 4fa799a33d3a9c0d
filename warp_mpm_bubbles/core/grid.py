"""The staggered (MAC) grid: sizes, origin and the cell-type codes shared by all kernels.

Pressure lives at cell centres, velocity component ``a`` on the faces normal to axis ``a``.
One layer of ghost cells surrounds the domain on every simulated axis, so a particle anywhere in
``[0, size]`` has its whole quadratic B-spline stencil inside the arrays and walls are ordinary
solid (or, for open walls, empty) cells. A 2D run is a slab one cell thick in z with no ghost
layer in z and no w component.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

# Cell types. Solid codes say how tangential velocity behaves at that wall.
EMPTY = 0
FLUID = 1
SOLID_FREE_SLIP = 2
SOLID_NO_SLIP = 3

# Phase of a fluid cell (and of a particle). Particles of the later phases are Lagrangian: the
# core transfers skip them and their effect moves them (foam rides the surface; sub-grid bubbles
# follow buoyancy and drag).
PHASE_LIQUID = 0
PHASE_GAS = 1
PHASE_FOAM = 2
PHASE_SUBGRID = 3

# Gas-liquid interface methods, as indices of scene.INTERFACES.
INTERFACE_SHARP = 0
INTERFACE_BASELINE = 1

# Wall-type indices as in scene.WALL_TYPES.
WALL_NO_SLIP = 0
WALL_FREE_SLIP = 1
WALL_OPEN = 2


def sphere_radius(volume):
    """Radius of the sphere of this volume: a bubble's, in 2D runs too (sub-grid bubbles are real)."""
    return np.cbrt(0.75 * np.asarray(volume, np.float64) / np.pi)


@dataclass(frozen=True)
class MacGrid:
    dim: int  # 2 or 3
    dx: float
    interior: tuple[int, int, int]  # cells inside the domain (nz = 1 in 2D)
    domain_size: tuple[float, float, float]  # metres; in 2D z is one cell thick

    @classmethod
    def from_domain(cls, domain) -> "MacGrid":
        nx, ny, nz = domain.cells
        dx = float(domain.dx)
        size = (nx * dx, ny * dx, nz * dx)
        return cls(dim=domain.dim, dx=dx, interior=(nx, ny, nz), domain_size=size)

    @property
    def ghost(self) -> tuple[int, int, int]:
        return (1, 1, 1 if self.dim == 3 else 0)

    @property
    def cells(self) -> tuple[int, int, int]:
        """Cell-array shape including ghost layers."""
        return tuple(n + 2 * g for n, g in zip(self.interior, self.ghost))

    @property
    def origin(self) -> tuple[float, float, float]:
        """World position of the corner of ghost cell (0, 0, 0)."""
        return tuple(-g * self.dx for g in self.ghost)

    def face_shape(self, axis: int) -> tuple[int, int, int]:
        shape = list(self.cells)
        shape[axis] += 1
        return tuple(shape)

    @property
    def axes(self) -> range:
        """Velocity components that are simulated."""
        return range(self.dim)

    def cell_centres(self) -> np.ndarray:
        """World positions of all cell centres, shape cells + (3,)."""
        idx = np.indices(self.cells).transpose(1, 2, 3, 0).astype(np.float64)
        return (idx + 0.5) * self.dx + np.asarray(self.origin)

    def interior_slice(self) -> tuple[slice, slice, slice]:
        return tuple(slice(g, g + n) for g, n in zip(self.ghost, self.interior))
