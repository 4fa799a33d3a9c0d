"""Measurements on particle snapshots (host-side numpy): how well the phases stay apart, and where
the bubbles are. Used by tests, benchmarks and examples; nothing here runs inside a step.
"""

from __future__ import annotations

import numpy as np

from .core.grid import connected_labels


def _dominance(positions, is_gas, volumes, dx, shape, dim):
    """Per cell (nearest-cell binning): +1 gas-dominated, -1 liquid-dominated, 0 no particle."""
    idx = np.clip(np.floor(positions[:, :dim] / dx).astype(int), 0, np.array(shape[:dim]) - 1)
    flat = np.ravel_multi_index(idx.T, shape[:dim])
    gas = np.bincount(flat, weights=np.where(is_gas, volumes, 0.0), minlength=np.prod(shape[:dim]))
    liq = np.bincount(flat, weights=np.where(is_gas, 0.0, volumes), minlength=np.prod(shape[:dim]))
    dom = np.sign(gas - liq).reshape(shape[:dim])
    return dom, flat


def _interior(mask):
    """Cells whose whole 3^d neighbourhood is in mask (one-cell erosion; outside the grid is not)."""
    padded = np.pad(mask, 1, constant_values=False)
    out = np.ones_like(mask)
    for offset in np.ndindex(*(3,) * mask.ndim):
        out &= padded[tuple(slice(o, o + n) for o, n in zip(offset, mask.shape))]
    return out


def phase_leak(positions, is_gas, volumes, dx: float, cells, dim: int) -> dict[str, float]:
    """The leak metric of issue #3, relative to the total gas volume:

    liquid_in_gas   volume of liquid particles at least one cell deep inside the gas region
                    (every cell of their 3^d neighbourhood gas-dominated): water leaked into bubbles
    gas_in_liquid   volume of gas particles at least one cell deep inside the liquid: gas left
                    behind by, or torn from, a bubble

    Particles in the interface cells themselves are not counted: binning smears any interface
    over a cell, so counting them would measure the resolution, not the leak.
    """
    positions = np.asarray(positions, dtype=np.float64)
    is_gas = np.asarray(is_gas, dtype=bool)
    volumes = np.asarray(volumes, dtype=np.float64)
    gas_volume = volumes[is_gas].sum()
    if gas_volume == 0.0:
        return {"liquid_in_gas": 0.0, "gas_in_liquid": 0.0}
    dom, flat = _dominance(positions, is_gas, volumes, dx, tuple(cells), dim)
    deep_gas = _interior(dom > 0).ravel()[flat]
    deep_liquid = _interior(dom < 0).ravel()[flat]
    return {
        "liquid_in_gas": float(volumes[~is_gas & deep_gas].sum() / gas_volume),
        "gas_in_liquid": float(volumes[is_gas & deep_liquid].sum() / gas_volume),
    }


def gas_centroid_and_diameter(positions, is_gas, volumes, dim: int) -> tuple[np.ndarray, float]:
    """Volume-weighted centroid of all gas and its volume-equivalent diameter d_e.

    In 2D (a slab one cell thick) the volume is an area times the slab thickness: pass volumes
    divided by that thickness to get the circle-equivalent diameter.
    """
    g = np.asarray(is_gas, dtype=bool)
    v = np.asarray(volumes, dtype=np.float64)[g]
    centroid = (np.asarray(positions, dtype=np.float64)[g] * v[:, None]).sum(0) / v.sum()
    total = v.sum()
    d_e = 2.0 * np.sqrt(total / np.pi) if dim == 2 else (6.0 * total / np.pi) ** (1.0 / 3.0)
    return centroid, float(d_e)


def bubble_volumes(positions, is_gas, volumes, dx: float, cells, dim: int) -> np.ndarray:
    """Gas volume of each bubble, largest first: connected gas-dominated cells (face neighbours)."""
    positions = np.asarray(positions, dtype=np.float64)
    is_gas = np.asarray(is_gas, dtype=bool)
    volumes = np.asarray(volumes, dtype=np.float64)
    if not is_gas.any():
        return np.zeros(0)
    dom, flat = _dominance(positions, is_gas, volumes, dx, tuple(cells), dim)
    gas_cells = np.argwhere(dom > 0)
    labels = np.full(dom.size, -1)
    labels[np.ravel_multi_index(gas_cells.T, dom.shape)] = connected_labels(gas_cells, dom.ndim, faces_only=True)
    particle_label = labels[flat]
    keep = is_gas & (particle_label >= 0)  # gas particles in liquid-dominated cells: dispersed, no bubble
    _, inverse = np.unique(particle_label[keep], return_inverse=True)
    return np.sort(np.bincount(inverse, weights=volumes[keep]))[::-1]


def void_cells(types, ghost, up) -> int:
    """Empty cells inside the liquid (issue #12): particle-free cells (grid.EMPTY) whose empty region
    is not open air. A face-connected empty region is open air when it reaches an open wall (its
    empty ghost cells) or the domain's top layer (against gravity; without gravity, any side).
    In a filled tank every empty cell is a void; above a free surface none is.

    types: the cell types of the last step (sim.fields.types.numpy()), ghost: sim.grid.ghost,
    up: sim.up ((axis, sign); axis -1 without gravity)."""
    from .core.grid import EMPTY

    types = np.asarray(types)
    empty = np.argwhere(types == EMPTY)
    if len(empty) == 0:
        return 0
    labels = connected_labels(empty, 3, faces_only=True)
    shape, ghost = np.array(types.shape), np.array(ghost)
    in_ghost = ((empty < ghost) | (empty >= shape - ghost)).any(axis=1)
    axis, sign = up
    if axis < 0:  # no "up": any side of the domain counts as the outside
        top = ((empty == ghost) | (empty == shape - ghost - 1)).any(axis=1)
    else:
        top_index = shape[axis] - ghost[axis] - 1 if sign > 0 else ghost[axis]
        top = empty[:, axis] == top_index
    open_labels = np.unique(labels[in_ghost | top])
    return int((~np.isin(labels, open_labels) & ~in_ghost).sum())
