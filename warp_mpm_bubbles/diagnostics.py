"""Measurements on particle snapshots (host-side numpy): how well the phases stay apart, and where
the bubbles are. Used by tests, benchmarks and examples; nothing here runs inside a step.
"""

from __future__ import annotations

import numpy as np

from .core.grid import closed_empty_cells, connected_labels


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
    """How much each phase has leaked into the other, relative to the total gas volume:

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


def void_cells(types, ghost, up, gaps=None) -> int:
    """Empty cells inside the liquid: particle-free cells (grid.EMPTY) whose empty region
    is not open air. A face-connected empty region is open air when it reaches an open wall (its
    empty ghost cells) or the domain's top layer (against gravity; without gravity, any side).
    In a filled tank every empty cell is a void; above a free surface none is.

    types: the cell types of the last step (sim.fields.types.numpy()), ghost: sim.grid.ghost,
    up: sim.up ((axis, sign); axis -1 without gravity). gaps: a boolean cell array of the empty cells
    that are a bubble's gaps (sim.voids.gap_mask(): particle-free cells beside compressible gas, left
    EMPTY for the gas to fill): connected to a gas region, not closed off in the liquid, so left out."""
    cells = closed_empty_cells(np.asarray(types), ghost, up)[0]
    if gaps is not None and len(cells):
        cells = cells[~np.asarray(gaps)[tuple(cells.T)]]
    return len(cells)


def gap_cells(sim) -> int:
    """This step's bubble gaps (see void_cells): particle-free cells beside a bubble's compressible gas."""
    return len(sim.voids.gap_cells)


# --------------------------------------------------------------------- shape: circularity, sphericity
def gas_fraction(positions, is_gas, volumes, dx: float, cells, dim: int) -> np.ndarray:
    """Gas volume fraction per cell (array of the `dim` interior cell counts): particle volumes spread
    to cell centres with MPM's quadratic B-spline (a 3-cell kernel, so a few particles per cell give a
    smooth field), gas over all. Cells no particle reaches (voids) read 0: they are not gas."""
    shape = tuple(int(n) for n in cells[:dim])
    u = np.asarray(positions, dtype=np.float64)[:, :dim] / dx - 0.5  # in cell-centre index units
    base = np.rint(u).astype(int)
    d = u - base
    w = (0.5 * (0.5 - d) ** 2, 0.75 - d ** 2, 0.5 * (0.5 + d) ** 2)  # offsets -1, 0, +1
    v = np.asarray(volumes, dtype=np.float64)
    g = np.asarray(is_gas, dtype=bool)
    gas, total = np.zeros(int(np.prod(shape))), np.zeros(int(np.prod(shape)))
    for off in np.ndindex(*(3,) * dim):
        idx = base + np.array(off) - 1
        ok = ((idx >= 0) & (idx < np.array(shape))).all(axis=1)
        wt = np.prod([w[o][:, a] for a, o in enumerate(off)], axis=0) * v
        flat = np.ravel_multi_index(idx[ok].T, shape)
        total += np.bincount(flat, weights=wt[ok], minlength=total.size)
        gas += np.bincount(flat, weights=np.where(g, wt, 0.0)[ok], minlength=gas.size)
    frac = np.divide(gas, total, out=np.zeros_like(gas), where=total > 1e-9 * v.mean())
    return frac.reshape(shape)


def contour_2d(field, dx: float, level: float = 0.5) -> tuple[float, float]:
    """Area and perimeter of {field > level}, field sampled at cell centres, from the marching-squares
    contour (linear interpolation along the edges, saddles resolved by the centre value). The field is
    padded with "outside" so every contour closes; segments are oriented with the inside on their left,
    so the enclosed area follows from the shoelace sum."""
    f = np.pad(np.asarray(field, dtype=np.float64), 1, constant_values=-np.inf) - level
    f = np.maximum(f, -1.0)  # padding: outside, finite so the interpolation below stays finite
    c = np.stack([f[:-1, :-1], f[1:, :-1], f[1:, 1:], f[:-1, 1:]], axis=-1)  # corners counter-clockwise
    corner = np.array([(0, 0), (1, 0), (1, 1), (0, 1)], dtype=np.float64)
    inside = c > 0
    n_in = inside.sum(-1)
    sel = np.argwhere((n_in > 0) & (n_in < 4))
    if len(sel) == 0:
        return 0.0, 0.0
    cs, ins = c[sel[:, 0], sel[:, 1]], inside[sel[:, 0], sel[:, 1]]
    a, b = cs, np.roll(cs, -1, axis=1)  # edge k runs from corner k to corner k + 1
    t = np.clip(a / np.where(a == b, 1.0, a - b), 0.0, 1.0)
    pts = corner[None] + t[..., None] * (np.roll(corner, -1, axis=0) - corner)[None]  # crossing on each edge
    exits = ins & ~np.roll(ins, -1, axis=1)  # inside -> outside going counter-clockwise
    entries = ~ins & np.roll(ins, -1, axis=1)
    single = np.nonzero(exits.sum(1) == 1)[0]
    rows, starts, ends = [single], [exits[single].argmax(1)], [entries[single].argmax(1)]
    saddle = np.nonzero(exits.sum(1) == 2)[0]  # pair each exit with the next entry (centre inside) or previous
    if len(saddle):
        step = np.where(cs[saddle].mean(1) > 0, 1, -1)
        for k in np.nonzero(exits[saddle])[1].reshape(-1, 2).T:
            rows.append(saddle), starts.append(k), ends.append((k + step) % 4)
    rows, starts, ends = np.concatenate(rows), np.concatenate(starts), np.concatenate(ends)
    origin = sel[rows] - 0.5  # padded index i is the cell centre (i - 1 + 0.5) dx
    p, q = (origin + pts[rows, starts]) * dx, (origin + pts[rows, ends]) * dx
    area = 0.5 * float((p[:, 0] * q[:, 1] - p[:, 1] * q[:, 0]).sum())
    return area, float(np.linalg.norm(q - p, axis=1).sum())


# The 6 tetrahedra of a cube's Kuhn split (corner bits x + 2y + 4z): every tet runs 0 -> 7 along
# one axis order, so neighbouring cubes split their shared faces alike and the surface closes.
_KUHN = [(0, 1 << a, (1 << a) | (1 << b), 7) for a in range(3) for b in range(3) if a != b]
_TET_EDGES = [(0, 1), (0, 2), (0, 3), (1, 2), (1, 3), (2, 3)]


def contour_3d(field, dx: float, level: float = 0.5) -> tuple[float, float]:
    """Volume and area of {field > level}, field at cell centres, from the marching-tetrahedra surface
    (no ambiguous cases, unlike marching cubes). Each triangle is oriented against the tet's gradient
    (outward), so the enclosed volume is the divergence-theorem sum of p0 . (p1 x p2) / 6."""
    f = np.maximum(np.pad(np.asarray(field, dtype=np.float64), 1, constant_values=-1.0) - level, -1.0)
    n = np.array(f.shape) - 1
    origin = np.stack(np.meshgrid(*[np.arange(k) for k in n], indexing="ij"), -1).reshape(-1, 3) - 0.5
    corner_val = [f[(bit & 1):n[0] + (bit & 1), (bit >> 1 & 1):n[1] + (bit >> 1 & 1),
                    (bit >> 2 & 1):n[2] + (bit >> 2 & 1)].ravel() for bit in range(8)]
    corner_pos = np.array([(b & 1, b >> 1 & 1, b >> 2 & 1) for b in range(8)], dtype=np.float64)
    tris = []
    for tet in _KUHN:
        val = np.stack([corner_val[c] for c in tet], -1)
        cut = ((val > 0).sum(-1) % 4) > 0
        val = val[cut]
        pos = origin[cut][:, None, :] + corner_pos[list(tet)][None]
        grad = np.linalg.solve(pos[:, 1:] - pos[:, :1], (val[:, 1:] - val[:, :1])[..., None])[..., 0]
        inside = val > 0
        cross = {}
        for i, j in _TET_EDGES:
            t = np.clip(val[:, i] / np.where(val[:, i] == val[:, j], 1.0, val[:, i] - val[:, j]), 0, 1)
            cross[i, j] = pos[:, i] + t[:, None] * (pos[:, j] - pos[:, i])
        n_in = inside.sum(-1)
        for odd in (1, 3):  # one vertex on its own side: a triangle on its three edges
            rows = np.nonzero(n_in == odd)[0]
            lone = np.where(odd == 1, inside[rows], ~inside[rows]).argmax(1)
            for k in range(4):
                r = rows[lone == k]
                others = [e for e in _TET_EDGES if k in e]
                tris.append((np.stack([cross[e][r] for e in others], 1), grad[r]))
        rows = np.nonzero(n_in == 2)[0]  # a quad: the crossings around the loop a-c, a-d, b-d, b-c
        for pair in [(0, 1), (0, 2), (0, 3), (1, 2), (1, 3), (2, 3)]:
            r = rows[(inside[rows][:, list(pair)]).all(1)]
            a, b = pair
            c, d = [k for k in range(4) if k not in pair]
            q = [cross[tuple(sorted(e))][r] for e in ((a, c), (a, d), (b, d), (b, c))]
            tris.append((np.stack([q[0], q[1], q[2]], 1), grad[r]))
            tris.append((np.stack([q[0], q[2], q[3]], 1), grad[r]))
    p = np.concatenate([t[0] for t in tris]) * dx
    g = np.concatenate([t[1] for t in tris])
    normal = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
    flip = np.where((normal * g).sum(1) > 0, -1.0, 1.0)  # outward: against the gradient (f grows inward)
    volume = float((flip * (p[:, 0] * np.cross(p[:, 1], p[:, 2])).sum(1)).sum() / 6.0)
    return volume, float(0.5 * np.linalg.norm(normal, axis=1).sum())


def _smooth(field, passes: int):
    """[1, 2, 1] / 4 along each axis, `passes` times (edges repeat): a contour of a field whose
    interface is one cell sharp wiggles at the grid scale, a constant relative error on the perimeter
    (0.6% for a circle) that refinement never removes; one pass brings it below 0.1%."""
    f = np.asarray(field, dtype=np.float64)
    for _ in range(passes):
        for ax in range(f.ndim):
            g = np.pad(f, [(1, 1) if a == ax else (0, 0) for a in range(f.ndim)], mode="edge")
            part = [tuple(slice(s, s + f.shape[ax]) if a == ax else slice(None) for a in range(f.ndim))
                    for s in range(3)]
            f = 0.25 * g[part[0]] + 0.5 * g[part[1]] + 0.25 * g[part[2]]
    return f


def field_shape(field, dx: float, smooth: int = 1) -> dict[str, float]:
    """Shape of {field > 0.5} (field: a volume fraction at cell centres, 2D or 3D array).
    2D: area, perimeter and circularity 2 sqrt(pi A) / P, the perimeter of the circle of equal area over
    the perimeter (Hysing et al. 2009; its square 4 pi A / P^2 is the other common definition);
    3D: volume, area and sphericity pi^(1/3) (6 V)^(2/3) / A, the area of the ball of equal volume over
    the area. Both are 1 for a disc / ball and smaller for any other shape."""
    f = _smooth(field, smooth)
    if f.ndim == 2:
        area, perimeter = contour_2d(f, dx)
        return {"area": area, "perimeter": perimeter,
                "circularity": 2.0 * np.sqrt(np.pi * area) / perimeter if perimeter > 0 else float("nan")}
    volume, area = contour_3d(f, dx)
    return {"volume": volume, "area": area,
            "sphericity": np.pi ** (1 / 3) * (6.0 * volume) ** (2 / 3) / area if area > 0 else float("nan")}


def gas_shape(positions, is_gas, volumes, dx: float, cells, dim: int, smooth: int = 1) -> dict[str, float]:
    """field_shape of the gas region of a particle snapshot (gas_fraction, then `smooth` passes): the
    circularity (2D) or sphericity (3D) of a bubble, with the area / volume its contour encloses."""
    return field_shape(gas_fraction(positions, is_gas, volumes, dx, cells, dim), dx, smooth)
