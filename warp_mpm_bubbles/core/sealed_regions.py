"""Sealed regions of the pressure system: fluid that no free surface or gas reaches.

The pressure system (core/pressure.py, PressureSystem) couples two fluid cells through a face of
positive weight; a connected set of fluid cells with no Dirichlet face (to an EMPTY cell) and no
compressible gas cell has the constants in its null space and is solvable only if its right-hand
side sums to zero there. A closed tank full of liquid is one such region, which the solver handles
by projecting the constant out of the whole system. Colliders and walls can cut off more: a rod
over a glass's wall seals a pocket of two cells against the tank's wall, a ball in a corner seals
the corner cell. Each region then has its own constant and its own condition, which one global
projection does not meet: the pocket takes a share of the main region's mean (the volume correction
asks every over-full cell to expand), CG cannot reduce that part of the residual, and the pressure
grows without bound (6 m/s in a tank at rest, then NaN).

So each step labels the fluid's connected regions on the device (every cell takes the smallest
linear index it reaches over faces of positive weight: sweeps along the grid's lines, a minimum, so
the labels do not depend on thread order) and counts regions and sealed regions into the step's
counters, which the host reads anyway (no read of its own). With no sealed region, or one sealed
region that is all the fluid, the solve is the one it always was. With a sealed region among
others, each sealed region is made solvable where it is: its mean right-hand side is removed (the
least-squares answer: a squeezed pocket is compressed evenly, which is all an incompressible solve
can say of a volume a solid takes away) and its root cell (the smallest index) gets its own
diagonal once more, which pins the region's constant (p = 0 there, exactly, for a consistent
right-hand side), so the whole system is nonsingular and needs no projection.
"""

from __future__ import annotations

import warp as wp

from .grid import FLUID
from .lines import Lines, line_first, line_end, on_line

# Where the counts go in row 0 of the step's counters (the slots after the nonfinite copy).
SLOT_REGIONS, SLOT_SEALED, SLOT_UNSETTLED = 3, 4, 5
# Rounds of sweeps (each along every axis, both ways) before the counts: two settle any region a
# line in one axis then a line in another reaches; the last round records whether a label moved,
# and only then does the host sweep on, reading after each round.
ROUNDS = 3


@wp.func
def linear(c: wp.vec3i, shape: wp.vec3i):
    return (c[0] * shape[1] + c[1]) * shape[2] + c[2]


@wp.func
def cell_of(label: int, shape: wp.vec3i):
    k = label % shape[2]
    rest = label // shape[2]
    return wp.vec3i(rest // shape[1], rest % shape[1], k)


@wp.kernel
def start_labels(types: wp.array3d(dtype=wp.int32), labels: wp.array3d(dtype=wp.int32),
                 pinned: wp.array3d(dtype=wp.int32), box: Lines):
    """labels = the cell's own linear index on fluid cells, -1 elsewhere; pinned = 0."""
    ti, tj, tk = wp.tid()
    first = line_first(box, ti, tj, tk)
    shape = wp.vec3i(types.shape[0], types.shape[1], types.shape[2])
    for s in range(first[box.axis], line_end(box, first)):
        c = on_line(first, box.axis, s)
        lab = int(-1)
        if types[c[0], c[1], c[2]] == FLUID:
            lab = linear(c, shape)
        labels[c[0], c[1], c[2]] = lab
        pinned[c[0], c[1], c[2]] = 0


@wp.func
def joined(types: wp.array3d(dtype=wp.int32), weight: wp.array3d(dtype=float), c: wp.vec3i, axis: int):
    """Cells c - e_axis and c are both fluid and coupled (the face between them, face c, has weight)."""
    b = c
    b[axis] = c[axis] - 1
    return (types[c[0], c[1], c[2]] == FLUID and types[b[0], b[1], b[2]] == FLUID
            and weight[c[0], c[1], c[2]] > 0.0)


@wp.kernel
def sweep_labels(types: wp.array3d(dtype=wp.int32), weight: wp.array3d(dtype=float),
                 labels: wp.array3d(dtype=wp.int32), moved: wp.array(dtype=wp.int32), slot: int, box: Lines):
    """Each thread walks its whole line along box.axis (the axis of `weight`'s faces) forward, then
    back, giving each fluid cell the smallest label of the coupled run it lies in; moved[slot] = 1
    if a label changed."""
    ti, tj, tk = wp.tid()
    first = line_first(box, ti, tj, tk)
    a = box.axis
    lo, hi = first[a], line_end(box, first)
    changed = int(0)
    for s in range(lo + 1, hi):
        c = on_line(first, a, s)
        if joined(types, weight, c, a):
            p = on_line(first, a, s - 1)
            if labels[p[0], p[1], p[2]] < labels[c[0], c[1], c[2]]:
                labels[c[0], c[1], c[2]] = labels[p[0], p[1], p[2]]
                changed = 1
    for s in range(hi - 1, lo, -1):
        c = on_line(first, a, s)
        if joined(types, weight, c, a):
            p = on_line(first, a, s - 1)
            if labels[c[0], c[1], c[2]] < labels[p[0], p[1], p[2]]:
                labels[p[0], p[1], p[2]] = labels[c[0], c[1], c[2]]
                changed = 1
    if changed != 0:
        wp.atomic_max(moved, slot, 1)


@wp.func
def is_pinned(types: wp.array3d(dtype=wp.int32), extra_diag: wp.array3d(dtype=float),
              inv_rho_u: wp.array3d(dtype=float), inv_rho_v: wp.array3d(dtype=float),
              inv_rho_w: wp.array3d(dtype=float), c: wp.vec3i, dim: int):
    """Row c of the system is strictly diagonally dominant: a gas term, or a face of weight to a cell
    that is not fluid (Dirichlet p = 0; a solid face has no weight)."""
    if extra_diag[c[0], c[1], c[2]] > 0.0:
        return True
    for a in range(dim):
        for side in range(2):
            n = c
            n[a] = c[a] + 2 * side - 1
            f = c
            f[a] = c[a] + side
            w = float(0.0)
            if a == 0:
                w = inv_rho_u[f[0], f[1], f[2]]
            elif a == 1:
                w = inv_rho_v[f[0], f[1], f[2]]
            else:
                w = inv_rho_w[f[0], f[1], f[2]]
            if w > 0.0 and types[n[0], n[1], n[2]] != FLUID:
                return True
    return False


@wp.kernel
def mark_pinned_roots(types: wp.array3d(dtype=wp.int32), extra_diag: wp.array3d(dtype=float),
                      inv_rho_u: wp.array3d(dtype=float), inv_rho_v: wp.array3d(dtype=float),
                      inv_rho_w: wp.array3d(dtype=float), labels: wp.array3d(dtype=wp.int32), dim: int,
                      pinned: wp.array3d(dtype=wp.int32), box: Lines):
    """pinned[root] = 1 for the root (the cell its label names) of each region with a pinned row."""
    ti, tj, tk = wp.tid()
    first = line_first(box, ti, tj, tk)
    shape = wp.vec3i(types.shape[0], types.shape[1], types.shape[2])
    for s in range(first[box.axis], line_end(box, first)):
        c = on_line(first, box.axis, s)
        if types[c[0], c[1], c[2]] == FLUID:
            if is_pinned(types, extra_diag, inv_rho_u, inv_rho_v, inv_rho_w, c, dim):
                r = cell_of(labels[c[0], c[1], c[2]], shape)
                wp.atomic_max(pinned, r[0], r[1], r[2], 1)


@wp.kernel
def count_regions(types: wp.array3d(dtype=wp.int32), labels: wp.array3d(dtype=wp.int32),
                  pinned: wp.array3d(dtype=wp.int32), counters: wp.array(dtype=wp.int32), box: Lines):
    """counters[SLOT_REGIONS] += regions (their roots), counters[SLOT_SEALED] += those unpinned."""
    ti, tj, tk = wp.tid()
    first = line_first(box, ti, tj, tk)
    shape = wp.vec3i(types.shape[0], types.shape[1], types.shape[2])
    for s in range(first[box.axis], line_end(box, first)):
        c = on_line(first, box.axis, s)
        if types[c[0], c[1], c[2]] == FLUID and labels[c[0], c[1], c[2]] == linear(c, shape):
            wp.atomic_add(counters, SLOT_REGIONS, 1)
            if pinned[c[0], c[1], c[2]] == 0:
                wp.atomic_add(counters, SLOT_SEALED, 1)


@wp.kernel
def clear_sums(sums: wp.array3d(dtype=wp.float64), sizes: wp.array3d(dtype=wp.int32), box: Lines):
    ti, tj, tk = wp.tid()
    first = line_first(box, ti, tj, tk)
    for s in range(first[box.axis], line_end(box, first)):
        c = on_line(first, box.axis, s)
        sums[c[0], c[1], c[2]] = wp.float64(0.0)
        sizes[c[0], c[1], c[2]] = 0


@wp.kernel
def sum_sealed(types: wp.array3d(dtype=wp.int32), labels: wp.array3d(dtype=wp.int32),
               pinned: wp.array3d(dtype=wp.int32), field: wp.array3d(dtype=float),
               sums: wp.array3d(dtype=wp.float64), sizes: wp.array3d(dtype=wp.int32), box: Lines):
    """sums[root], sizes[root] = the field's sum and the cell count of each sealed region.
    One launch, never split: on the CPU its threads run in order, so the float sums do too."""
    ti, tj, tk = wp.tid()
    first = line_first(box, ti, tj, tk)
    shape = wp.vec3i(types.shape[0], types.shape[1], types.shape[2])
    for s in range(first[box.axis], line_end(box, first)):
        c = on_line(first, box.axis, s)
        if types[c[0], c[1], c[2]] == FLUID:
            r = cell_of(labels[c[0], c[1], c[2]], shape)
            if pinned[r[0], r[1], r[2]] == 0:
                wp.atomic_add(sums, r[0], r[1], r[2], wp.float64(field[c[0], c[1], c[2]]))
                wp.atomic_add(sizes, r[0], r[1], r[2], 1)


@wp.kernel
def subtract_sealed_mean(types: wp.array3d(dtype=wp.int32), labels: wp.array3d(dtype=wp.int32),
                         pinned: wp.array3d(dtype=wp.int32), sums: wp.array3d(dtype=wp.float64),
                         sizes: wp.array3d(dtype=wp.int32), field: wp.array3d(dtype=float), box: Lines):
    """In each sealed region: field -= its mean (sum_sealed's)."""
    ti, tj, tk = wp.tid()
    first = line_first(box, ti, tj, tk)
    shape = wp.vec3i(types.shape[0], types.shape[1], types.shape[2])
    for s in range(first[box.axis], line_end(box, first)):
        c = on_line(first, box.axis, s)
        if types[c[0], c[1], c[2]] == FLUID:
            r = cell_of(labels[c[0], c[1], c[2]], shape)
            if pinned[r[0], r[1], r[2]] == 0:
                mean = sums[r[0], r[1], r[2]] / wp.float64(sizes[r[0], r[1], r[2]])
                field[c[0], c[1], c[2]] = float(wp.float64(field[c[0], c[1], c[2]]) - mean)


@wp.kernel
def pin_roots(types: wp.array3d(dtype=wp.int32), labels: wp.array3d(dtype=wp.int32),
              pinned: wp.array3d(dtype=wp.int32), diag: wp.array3d(dtype=float),
              extra_diag: wp.array3d(dtype=float), box: Lines):
    """The root of each sealed region gets its diagonal once more, as a mass term (extra_diag):
    the region's constant is pinned (p = 0 at the root for a consistent right-hand side)."""
    ti, tj, tk = wp.tid()
    first = line_first(box, ti, tj, tk)
    shape = wp.vec3i(types.shape[0], types.shape[1], types.shape[2])
    for s in range(first[box.axis], line_end(box, first)):
        c = on_line(first, box.axis, s)
        if types[c[0], c[1], c[2]] == FLUID and pinned[c[0], c[1], c[2]] == 0:
            if labels[c[0], c[1], c[2]] == linear(c, shape):
                d = diag[c[0], c[1], c[2]]
                extra_diag[c[0], c[1], c[2]] = extra_diag[c[0], c[1], c[2]] + d
                diag[c[0], c[1], c[2]] = d + d

def axis_lines(lo, hi, axis: int):
    """A Lines box [lo, hi) whose threads each walk a whole line along `axis` (on any device: a sweep
    carries the label along the line), and its launch dims."""
    box = Lines()
    box.lo, box.hi = wp.vec3i(*lo), wp.vec3i(*hi)
    box.axis = axis
    extent = [max(int(h) - int(l), 0) for l, h in zip(lo, hi)]  # noqa: E741
    box.length = max(extent[axis], 1)
    dims = list(extent)
    dims[axis] = 1 if extent[axis] else 0
    return box, tuple(dims)


class SealedRegions:
    """The labels and per-root scratch of one grid (arrays of its cells), and the host's side: label
    and count the regions before the step's counters are read, settle the sealed ones after."""

    def __init__(self, shape, device):
        cells = lambda dtype: wp.zeros(shape, dtype=dtype, device=device)  # noqa: E731
        self.labels, self.pinned, self.sizes = cells(wp.int32), cells(wp.int32), cells(wp.int32)
        self.sums = cells(wp.float64)
        self.moved = wp.zeros(1, dtype=wp.int32, device=device)

    def _sweeps(self, sim, types, inv_rho, moved, slot: int):
        """One round: a sweep along each axis of the grid box (each thread its own whole line)."""
        lo, hi = sim.region.box
        for a in sim.grid.axes:
            box, dims = axis_lines(lo, hi, a)
            if 0 not in dims:
                sim.launch(sweep_labels, dims, [types, inv_rho[a], self.labels, moved, slot, box])

    def count(self, sim, types, inv_rho, extra_diag, counters):
        """Label the fluid's regions and add the counts of regions, sealed regions and whether the
        labels were still moving in the last round into counters' row 0 (SLOT_*)."""
        lines = sim.region.cell_lines
        sim.launch_lines(start_labels, lines, [types, self.labels, self.pinned])
        for round_ in range(ROUNDS):
            last = round_ == ROUNDS - 1
            self._sweeps(sim, types, inv_rho, counters if last else self.moved, SLOT_UNSETTLED if last else 0)
        self._tally(sim, types, inv_rho, extra_diag, counters)

    def _tally(self, sim, types, inv_rho, extra_diag, counters):
        lines = sim.region.cell_lines
        sim.launch_lines(mark_pinned_roots, lines, [types, extra_diag, *inv_rho, self.labels, sim.grid.dim, self.pinned])
        sim.launch_lines(count_regions, lines, [types, self.labels, self.pinned, counters])

    def finish_labels(self, sim, types, inv_rho, extra_diag, counters) -> tuple[int, int]:
        """Sweep until no label moves (a region winding past ROUNDS turns), reading after each round;
        then count again. Returns (regions, sealed regions)."""
        while True:
            self.moved.zero_()
            self._sweeps(sim, types, inv_rho, self.moved, 0)
            if not int(sim.read_host(self.moved)[0]):
                break
        self.pinned.zero_()
        counters.zero_()
        self._tally(sim, types, inv_rho, extra_diag, counters)
        row = sim.read_host(counters)
        return int(row[SLOT_REGIONS]), int(row[SLOT_SEALED])

    def _remove_means(self, sim, types, field):
        lines = sim.region.cell_lines
        sim.launch_lines(clear_sums, lines, [self.sums, self.sizes])
        sim.launch(sum_sealed, lines[1], [types, self.labels, self.pinned, field, self.sums, self.sizes, lines[0]])
        sim.launch_lines(subtract_sealed_mean, lines, [types, self.labels, self.pinned, self.sums, self.sizes, field])

    def settle(self, sim, types, rhs, diag, extra_diag):
        """Make each sealed region solvable on its own (the module's docstring): mean rhs removed,
        root pinned."""
        self._remove_means(sim, types, rhs)
        sim.launch_lines(pin_roots, sim.region.cell_lines, [types, self.labels, self.pinned, diag, extra_diag])

    def center(self, sim, types, pressure):
        """After the solve: each sealed region's pressure to mean zero, the level the solver gives a
        closed tank (one sealed region), rather than the root's zero."""
        self._remove_means(sim, types, pressure)
