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
right-hand side), so the whole system is nonsingular and needs no projection. After the solve each
sealed region's pressure is shifted to mean zero, the level the projection gives a closed tank.
"""

from __future__ import annotations

import math

import warp as wp

from .cells import cell_divergence
from .grid import FLUID
from .threads import SPLIT_CELLS, split
from .lines import Lines, line_first, line_end, on_line

# Where the counts go in row 0 of the step's counters (the slots after the nonfinite copy).
SLOT_REGIONS, SLOT_SEALED, SLOT_UNSETTLED = 3, 4, 5
# Rounds of sweeps (each along every axis, both ways) before the counts. One settles a box-shaped
# region (a line along x, then y, then z reaches every cell); two, most others. The count checks
# every coupled face, and only if two labels still differ does the host sweep on, with reads.
ROUNDS = 2
# Where the solids' push into sealed liquid so far goes (thousandths of a cell's volume), and how much
# of the fluid's volume it may reach before the run stops. Sealed liquid has no room: what a solid
# pushes in (a piston entering a full closed box, a ball closing a corner) is compressed away, which
# the volume correction then fights. A rigid collider inside the liquid pushes in nothing (the flux
# through a closed solid surface moving rigidly is zero); only one that enters the domain or closes
# on a wall does. A ball squeezing a corner cell takes about one cell; 5% of the fluid is a piston
# with nowhere for the liquid to go, a fifth of the way to the 10% squeeze that is plainly wrong.
SLOT_SQUEEZED, SQUEEZE_LIMIT = 6, 0.05


@wp.func
def linear(c: wp.vec3i, shape: wp.vec3i):
    return (c[0] * shape[1] + c[1]) * shape[2] + c[2]


@wp.func
def cell_of(label: int, shape: wp.vec3i):
    k = label % shape[2]
    rest = label // shape[2]
    return wp.vec3i(rest // shape[1], rest % shape[1], k)


@wp.kernel
def start_labels(box: Lines, types: wp.array3d(dtype=wp.int32), labels: wp.array3d(dtype=wp.int32),
                 pinned: wp.array3d(dtype=wp.int32)):
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


@wp.kernel
def sweep_labels(box: Lines, types: wp.array3d(dtype=wp.int32), weight: wp.array3d(dtype=float),
                 labels: wp.array3d(dtype=wp.int32)):
    """Each thread walks its whole line along box.axis (the axis of `weight`'s faces; face s lies
    between cells s - 1 and s) forward, then back, giving each fluid cell the smallest label of the
    run of coupled cells it lies in."""
    ti, tj, tk = wp.tid()
    first = line_first(box, ti, tj, tk)
    a = box.axis
    lo, hi = first[a], line_end(box, first)
    carry = int(-1)  # the previous cell's label while it is fluid, else -1
    for s in range(lo, hi):
        c = on_line(first, a, s)
        lab = int(-1)
        if types[c[0], c[1], c[2]] == FLUID:
            lab = labels[c[0], c[1], c[2]]
            if carry >= 0 and carry < lab and weight[c[0], c[1], c[2]] > 0.0:
                lab = carry
                labels[c[0], c[1], c[2]] = lab
        carry = lab
    carry = int(-1)
    for s in range(hi - 1, lo - 1, -1):
        c = on_line(first, a, s)
        lab = int(-1)
        if types[c[0], c[1], c[2]] == FLUID:
            lab = labels[c[0], c[1], c[2]]
            f = on_line(first, a, s + 1)  # the face to the cell walked before
            if carry >= 0 and carry < lab and weight[f[0], f[1], f[2]] > 0.0:
                lab = carry
                labels[c[0], c[1], c[2]] = lab
        carry = lab


@wp.func
def face_weight(inv_rho_u: wp.array3d(dtype=float), inv_rho_v: wp.array3d(dtype=float),
                inv_rho_w: wp.array3d(dtype=float), f: wp.vec3i, axis: int):
    if axis == 0:
        return inv_rho_u[f[0], f[1], f[2]]
    if axis == 1:
        return inv_rho_v[f[0], f[1], f[2]]
    return inv_rho_w[f[0], f[1], f[2]]


@wp.kernel
def check_and_mark(box: Lines, types: wp.array3d(dtype=wp.int32), extra_diag: wp.array3d(dtype=float),
                   inv_rho_u: wp.array3d(dtype=float), inv_rho_v: wp.array3d(dtype=float),
                   inv_rho_w: wp.array3d(dtype=float), labels: wp.array3d(dtype=wp.int32), dim: int,
                   pinned: wp.array3d(dtype=wp.int32), counters: wp.array(dtype=wp.int32)):
    """counters[SLOT_UNSETTLED] = 1 if two coupled fluid cells still differ in label (the sweeps go on);
    pinned[root] = 1 for the root (the cell its label names) of each region with a pinned row: a gas
    term, or a face of weight to a cell that is not fluid (Dirichlet p = 0; a solid face has none)."""
    ti, tj, tk = wp.tid()
    first = line_first(box, ti, tj, tk)
    shape = wp.vec3i(types.shape[0], types.shape[1], types.shape[2])
    for s in range(first[box.axis], line_end(box, first)):
        c = on_line(first, box.axis, s)
        if types[c[0], c[1], c[2]] != FLUID:
            continue
        lab = labels[c[0], c[1], c[2]]
        pin = extra_diag[c[0], c[1], c[2]] > 0.0
        for a in range(dim):
            for side in range(2):
                n = c
                n[a] = c[a] + 2 * side - 1
                f = c
                f[a] = c[a] + side
                if face_weight(inv_rho_u, inv_rho_v, inv_rho_w, f, a) > 0.0:
                    if types[n[0], n[1], n[2]] != FLUID:
                        pin = True
                    elif labels[n[0], n[1], n[2]] != lab:
                        wp.atomic_max(counters, SLOT_UNSETTLED, 1)
        if pin:
            r = cell_of(lab, shape)
            wp.atomic_max(pinned, r[0], r[1], r[2], 1)


@wp.kernel
def clear_pinned(box: Lines, pinned: wp.array3d(dtype=wp.int32)):
    ti, tj, tk = wp.tid()
    first = line_first(box, ti, tj, tk)
    for s in range(first[box.axis], line_end(box, first)):
        c = on_line(first, box.axis, s)
        pinned[c[0], c[1], c[2]] = 0


@wp.kernel
def count_regions(box: Lines, types: wp.array3d(dtype=wp.int32), labels: wp.array3d(dtype=wp.int32),
                  pinned: wp.array3d(dtype=wp.int32), counters: wp.array(dtype=wp.int32)):
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
def clear_sums(box: Lines, sums: wp.array3d(dtype=wp.float64), sizes: wp.array3d(dtype=wp.int32)):
    ti, tj, tk = wp.tid()
    first = line_first(box, ti, tj, tk)
    for s in range(first[box.axis], line_end(box, first)):
        c = on_line(first, box.axis, s)
        sums[c[0], c[1], c[2]] = wp.float64(0.0)
        sizes[c[0], c[1], c[2]] = 0


@wp.func
def sealed_root(types: wp.array3d(dtype=wp.int32), labels: wp.array3d(dtype=wp.int32),
                pinned: wp.array3d(dtype=wp.int32), c: wp.vec3i, shape: wp.vec3i):
    """The root cell of fluid cell c's region when that region is sealed (no pinned cell), else (-1, -1, -1)."""
    r = wp.vec3i(-1, -1, -1)
    if types[c[0], c[1], c[2]] == FLUID:
        root = cell_of(labels[c[0], c[1], c[2]], shape)
        if pinned[root[0], root[1], root[2]] == 0:
            r = root
    return r


@wp.kernel
def sum_sealed(box: Lines, types: wp.array3d(dtype=wp.int32), labels: wp.array3d(dtype=wp.int32),
               pinned: wp.array3d(dtype=wp.int32), field: wp.array3d(dtype=float),
               sums: wp.array3d(dtype=wp.float64), sizes: wp.array3d(dtype=wp.int32)):
    """sums[root], sizes[root] = the field's sum and the cell count of each sealed region.
    One launch, never split: on the CPU its threads run in order, so the float sums do too."""
    ti, tj, tk = wp.tid()
    first = line_first(box, ti, tj, tk)
    shape = wp.vec3i(types.shape[0], types.shape[1], types.shape[2])
    for s in range(first[box.axis], line_end(box, first)):
        c = on_line(first, box.axis, s)
        r = sealed_root(types, labels, pinned, c, shape)
        if r[0] >= 0:
            wp.atomic_add(sums, r[0], r[1], r[2], wp.float64(field[c[0], c[1], c[2]]))
            wp.atomic_add(sizes, r[0], r[1], r[2], 1)


@wp.kernel
def subtract_sealed_mean(box: Lines, types: wp.array3d(dtype=wp.int32), labels: wp.array3d(dtype=wp.int32),
                         pinned: wp.array3d(dtype=wp.int32), sums: wp.array3d(dtype=wp.float64),
                         sizes: wp.array3d(dtype=wp.int32), field: wp.array3d(dtype=float)):
    """In each sealed region: field -= its mean (sum_sealed's)."""
    ti, tj, tk = wp.tid()
    first = line_first(box, ti, tj, tk)
    shape = wp.vec3i(types.shape[0], types.shape[1], types.shape[2])
    for s in range(first[box.axis], line_end(box, first)):
        c = on_line(first, box.axis, s)
        r = sealed_root(types, labels, pinned, c, shape)
        if r[0] >= 0:
            mean = sums[r[0], r[1], r[2]] / wp.float64(sizes[r[0], r[1], r[2]])
            field[c[0], c[1], c[2]] = float(wp.float64(field[c[0], c[1], c[2]]) - mean)


@wp.kernel
def pin_roots(box: Lines, types: wp.array3d(dtype=wp.int32), labels: wp.array3d(dtype=wp.int32),
              pinned: wp.array3d(dtype=wp.int32), diag: wp.array3d(dtype=float),
              extra_diag: wp.array3d(dtype=float)):
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

@wp.kernel
def sum_sealed_inflow(box: Lines, types: wp.array3d(dtype=wp.int32), labels: wp.array3d(dtype=wp.int32),
                      pinned: wp.array3d(dtype=wp.int32), vel_u: wp.array3d(dtype=float),
                      vel_v: wp.array3d(dtype=float), vel_w: wp.array3d(dtype=float), dim: int,
                      scale: wp.float64, squeezed: wp.array(dtype=wp.float64)):
    """squeezed[0] -= scale * the net outflow of the sealed cells: the faces between two of them
    cancel, so what is left is what the solid faces around the sealed regions push in. One launch,
    never split (on the CPU its threads run in order, so the float sum does too)."""
    ti, tj, tk = wp.tid()
    first = line_first(box, ti, tj, tk)
    shape = wp.vec3i(types.shape[0], types.shape[1], types.shape[2])
    for s in range(first[box.axis], line_end(box, first)):
        c = on_line(first, box.axis, s)
        r = sealed_root(types, labels, pinned, c, shape)
        if r[0] >= 0:
            wp.atomic_add(squeezed, 0, -scale * wp.float64(cell_divergence(vel_u, vel_v, vel_w, c, dim)))


@wp.kernel
def report_squeezed(squeezed: wp.array(dtype=wp.float64), counters: wp.array(dtype=wp.int32), slot: int):
    counters[slot] = int(wp.clamp(squeezed[0], wp.float64(0.0), wp.float64(2.0e9)))


def axis_lines(lo, hi, axis: int, threads: int = 1) -> list:
    """Lines boxes covering [lo, hi) whose threads each walk a whole line along `axis` (on any device:
    a sweep carries the label along the line), with their launch dims: slabs across another axis,
    one a CPU thread, when the box holds SPLIT_CELLS or more (no line is cut, so the same result)."""
    extent = [max(int(h) - int(l), 0) for l, h in zip(lo, hi)]  # noqa: E741
    across = 1 if axis == 0 else 0
    parts = threads if math.prod(extent) >= SPLIT_CELLS else 1
    out = []
    for a, b in zip(cuts := split(lo[across], hi[across], max(1, min(parts, extent[across]))), cuts[1:]):
        box = Lines()
        slab_lo, slab_hi = list(lo), list(hi)
        slab_lo[across], slab_hi[across] = a, b
        box.lo, box.hi = wp.vec3i(*slab_lo), wp.vec3i(*slab_hi)
        box.axis, box.length = axis, max(extent[axis], 1)
        dims = [h - l for l, h in zip(slab_lo, slab_hi)]  # noqa: E741
        dims[axis] = 1 if extent[axis] else 0
        if 0 not in dims:
            out.append((box, tuple(dims)))
    return out


class SealedRegions:
    """The labels and per-root scratch of one grid (arrays of its cells), and the host's side: label
    and count the regions before the step's counters are read, settle the sealed ones after."""

    def __init__(self, shape, device):
        cells = lambda dtype: wp.zeros(shape, dtype=dtype, device=device)  # noqa: E731
        self.labels, self.pinned, self.sizes = cells(wp.int32), cells(wp.int32), cells(wp.int32)
        self.sums = cells(wp.float64)
        self.squeezed = wp.zeros(1, dtype=wp.float64, device=device)  # thousandths of a cell, this run

    def _round(self, sim, types, inv_rho):
        """One round: a sweep along each axis of the grid box (each thread its own whole line)."""
        lo, hi = sim.region.box
        for a in sim.grid.axes:
            slabs = axis_lines(lo, hi, a, sim.parallel.threads)
            if slabs:
                sim.launch_parts(sweep_labels, [(d, [box, types, inv_rho[a], self.labels]) for box, d in slabs])

    def _tally(self, sim, types, inv_rho, extra_diag, counters):
        lines = sim.region.cell_lines
        sim.launch_lines(check_and_mark, lines, [types, extra_diag, *inv_rho, self.labels, sim.grid.dim, self.pinned,
                                                 counters])
        sim.launch_lines(count_regions, lines, [types, self.labels, self.pinned, counters])

    def count(self, sim, fields):
        """Label the fluid's regions and add into counters' row 0 (SLOT_*) the counts of regions and
        sealed regions, and whether the labels are unsettled (then the counts are not yet right)."""
        types, inv_rho = fields.types, fields.inv_rho
        sim.launch_lines(start_labels, sim.region.cell_lines, [types, self.labels, self.pinned])
        for _ in range(ROUNDS):
            self._round(sim, types, inv_rho)
        self._tally(sim, types, inv_rho, fields.extra_diag, fields.counters)
        sim.launch(report_squeezed, 1, [self.squeezed, fields.counters, SLOT_SQUEEZED])

    def finish_labels(self, sim, types, inv_rho, extra_diag, counters) -> tuple[int, int]:
        """Sweep on, a round and a count at a time, each with a read (a region winding past what
        ROUNDS settle; rare), until the labels settle. Returns (regions, sealed regions). Each round
        that finds two coupled labels apart lowers one, so a path through every cell of the box ends
        it; more rounds than that would be a bug here, which must not hang the run."""
        for _ in range(math.prod(sim.region.cells)):
            self._round(sim, types, inv_rho)
            sim.launch_lines(clear_pinned, sim.region.cell_lines, [self.pinned])
            counters.zero_()
            self._tally(sim, types, inv_rho, extra_diag, counters)
            row = sim.read_host(counters)
            if not row[SLOT_UNSETTLED]:
                return int(row[SLOT_REGIONS]), int(row[SLOT_SEALED])
        raise RuntimeError("the sealed-region labels did not settle (a bug in core/sealed_regions.py)")

    def _remove_means(self, sim, types, field):
        lines = sim.region.cell_lines
        sim.launch_lines(clear_sums, lines, [self.sums, self.sizes])
        sim.launch(sum_sealed, lines[1], [lines[0], types, self.labels, self.pinned, field, self.sums, self.sizes])
        sim.launch_lines(subtract_sealed_mean, lines, [types, self.labels, self.pinned, self.sums, self.sizes, field])

    def settle(self, sim, fields, counts, dt: float) -> bool:
        """After the counts are read (counts: row 0 of the counters): with a sealed region among
        others, make each sealed region solvable on its own (the module's docstring: mean rhs
        removed, root pinned) and return True; else leave the system as it is and return False.
        With any sealed region, book what the solids push into it this step (SLOT_SQUEEZED)."""
        regions, sealed = int(counts[SLOT_REGIONS]), int(counts[SLOT_SEALED])
        if counts[SLOT_UNSETTLED]:  # a region winding past ROUNDS: sweep on, with reads (rare)
            regions, sealed = self.finish_labels(sim, fields.types, fields.inv_rho, fields.extra_diag, fields.counters)
        if not sealed:
            return False
        lines = sim.region.cell_lines
        sim.launch(sum_sealed_inflow, lines[1], [lines[0], fields.types, self.labels, self.pinned, *fields.vel,
                                                 sim.grid.dim, wp.float64(1000.0 * dt / sim.grid.dx), self.squeezed])
        if regions == 1:
            return False
        self._remove_means(sim, fields.types, fields.rhs)
        sim.launch_lines(pin_roots, lines, [fields.types, self.labels, self.pinned, fields.diag, fields.extra_diag])
        return True

    @staticmethod
    def squeeze_error(counts, n_fluid: int) -> str | None:
        """The reason to stop when the solids have pushed more than SQUEEZE_LIMIT of the fluid's
        volume into sealed liquid (booked up to the previous step), else None."""
        cells = counts[SLOT_SQUEEZED] / 1000.0
        if cells <= SQUEEZE_LIMIT * n_fluid:
            return None
        return (f"the colliders have pushed {cells:.3g} cells' volume into liquid that fills a closed region "
                f"({100 * cells / max(n_fluid, 1):.3g}% of the fluid's {n_fluid} cells), which has no room "
                f"for it and is being compressed. Leave the liquid room: fill less ([shapes]), open a wall "
                f"([domain].walls), or stop the collider sooner or keep it off the walls ([colliders.N].stop, "
                f".velocity, .acceleration, .center)")

    def remove_rhs_means(self, sim, fields):
        """Each sealed region's right-hand side to mean zero, as settle() made the step's: for a
        second solve of the same system (core/volume_shift.py)."""
        self._remove_means(sim, fields.types, fields.rhs)

    def center(self, sim, fields):
        """After a solve that settle() prepared: each sealed region's pressure to mean zero, the level
        the solver gives a closed tank (one sealed region), rather than the root's zero."""
        self._remove_means(sim, fields.types, fields.pressure)
