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

# A particle's `active` flag: 1 while simulated, 0 once retired. LEAVING marks, for the rest of the
# kernel that moved it, a particle that crossed an open wall: the one serial pass that books its mass
# as outflow (Simulation.book_outflow) retires it, so the ledger's sum has one order on the CPU.
# AIRBORNE: liquid that crossed an open top (the wall against gravity) flies above the domain on its
# own, in free fall (no grid reaches it), and rejoins the simulation when it falls back in.
RETIRED = 0
ACTIVE = 1
LEAVING = 2
AIRBORNE = 3

# Gas-liquid interface methods ([solver].interface): ghost-fluid gas-liquid faces, or the published
# "any gas particle makes a gas cell"; the kernels take the index.
INTERFACES = ("sharp", "baseline")
INTERFACE_SHARP, INTERFACE_BASELINE = range(2)
# Pressure preconditioners ([solver].preconditioner); the solver's kernels take the index.
PRECONDITIONERS = ("none", "jacobi", "multigrid")

# Wall-type indices as in scene.WALL_TYPES.
WALL_NO_SLIP = 0
WALL_FREE_SLIP = 1
WALL_OPEN = 2


def sphere_radius(volume):
    """Radius of the sphere of this volume: a bubble's, in 2D runs too (sub-grid bubbles are real)."""
    return np.cbrt(0.75 * np.asarray(volume, np.float64) / np.pi)


def connected_labels(cells: np.ndarray, dim: int, faces_only: bool = False) -> np.ndarray:
    """Labels of the connected groups of the cells in `cells`, an (m, dim) integer array, one row
    per occupied cell; labels are the smallest row of the group. Cells touching by faces, edges or
    corners connect (sub-grid bubbles gather), or by faces only (faces_only: diagnostics' bubbles)."""
    m = len(cells)
    label = np.arange(m)
    if m < 2:
        return label
    span = cells.max(axis=0) + 3  # room for a neighbour on either side
    key = np.ravel_multi_index((cells + 1).T, span)  # +1: a neighbour of row 0 stays >= 0
    order = np.argsort(key)
    ii, jj = [], []
    for off in np.ndindex(*(3,) * dim):
        off = np.array(off) - 1
        if tuple(off) <= (0,) * dim or (faces_only and np.abs(off).sum() != 1):  # each pair once
            continue
        nb = np.ravel_multi_index((cells + 1 + off).T, span)
        pos = np.searchsorted(key, nb, sorter=order).clip(0, m - 1)
        hit = key[order[pos]] == nb
        ii.append(np.flatnonzero(hit))
        jj.append(order[pos[hit]])
    ii, jj = np.concatenate(ii), np.concatenate(jj)
    while True:  # min-label propagation with pointer jumping
        new = label.copy()
        np.minimum.at(new, ii, label[jj])
        np.minimum.at(new, jj, label[ii])
        new = new[new]
        if np.array_equal(new, label):
            return label
        label = new


def open_air_seeds(cells: np.ndarray, shape, ghost, up) -> np.ndarray:
    """Which of these EMPTY cells (an (m, 3) index array into a cell-type array of `shape`) are open
    air by position alone: ghost cells (an open wall) and cells of the domain's top layer (against
    gravity, `up` = (axis, sign)); without gravity (axis -1), of its outer layer on every simulated
    axis (those with a ghost layer: not z in 2D)."""
    shape, ghost = np.asarray(shape), np.asarray(ghost)
    seeds = ((cells < ghost) | (cells >= shape - ghost)).any(axis=1)
    axis, sign = up
    if axis < 0:
        simulated = ghost > 0
        layer = (cells == ghost) | (cells == shape - ghost - 1)
        return seeds | (layer & simulated).any(axis=1)
    return seeds | (cells[:, axis] == (shape[axis] - ghost[axis] - 1 if sign > 0 else ghost[axis]))


def closed_empty_cells(types: np.ndarray, ghost, up) -> tuple[np.ndarray, np.ndarray]:
    """The voids of a cell-type array, by definition: the EMPTY cells whose face-connected EMPTY region
    reaches no open-air seed (open_air_seeds). Returns (cells, labels): an (m, 3) index array in
    row-major order and each cell's region label. core/voids.py finds the same cells faster."""
    empty = np.argwhere(types == EMPTY)
    if len(empty) == 0:
        return empty, np.zeros(0, int)
    labels = connected_labels(empty, 3, faces_only=True)
    seeds = open_air_seeds(empty, types.shape, ghost, up)
    closed = ~np.isin(labels, np.unique(labels[seeds]))
    return empty[closed], labels[closed]


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
