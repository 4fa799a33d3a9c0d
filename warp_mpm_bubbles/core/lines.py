"""One thread a line of cells: how the cell kernels of the pressure solve walk their box.

Warp runs a CPU launch as one loop that calls the kernel once per thread. For a kernel doing a few
dozen flops per cell, that call and the split of the thread index into (i, j, k) cost more than the
work: a red-black sweep took 23 ns a cell with a thread per cell and 7.5 ns with a thread per line of
cells, the same sweep bit for bit (docs/performance.md, "Lines"). So these kernels take a `Lines` box
and each thread walks `length` cells along `axis`, the last simulated axis (contiguous in memory):
the whole line on the CPU, one cell on a GPU, where a thread per cell is the right grain. Threads
and the cells within a line both run in row-major order, so on the CPU the cells are visited in the
order a thread per cell visits them, and sums accumulated in thread order are unchanged.

    ti, tj, tk = wp.tid()
    first = line_first(box, ti, tj, tk)
    for s in range(first[box.axis], line_end(box, first)):
        c = on_line(first, box.axis, s)
"""

from __future__ import annotations

import warp as wp


@wp.struct
class Lines:
    lo: wp.vec3i  # the box [lo, hi) of cells
    hi: wp.vec3i
    axis: int  # the axis a thread walks: the last simulated one
    length: int  # cells a thread walks: the box's extent along axis on the CPU, 1 on a GPU


@wp.func
def line_first(box: Lines, ti: int, tj: int, tk: int):
    """The first cell of thread (ti, tj, tk)'s line."""
    t = wp.vec3i(ti, tj, tk)
    c = box.lo + t
    c[box.axis] = box.lo[box.axis] + t[box.axis] * box.length
    return c


@wp.func
def line_end(box: Lines, first: wp.vec3i):
    """One past the last index along the axis of the line starting at `first`."""
    return wp.min(first[box.axis] + box.length, box.hi[box.axis])


@wp.func
def on_line(first: wp.vec3i, axis: int, s: int):
    """The cell at index s along the axis of the line through `first`."""
    c = first
    c[axis] = s
    return c


@wp.func
def in_box(lo: wp.vec3i, hi: wp.vec3i, c: wp.vec3i):
    """Cell c lies in the box [lo, hi)."""
    if c[0] < lo[0] or c[1] < lo[1] or c[2] < lo[2]:
        return False
    if c[0] >= hi[0] or c[1] >= hi[1] or c[2] >= hi[2]:
        return False
    return True


def make_lines(lo, hi, dim: int, device) -> tuple[Lines, tuple[int, int, int]]:
    """The Lines struct for box [lo, hi) of a dim-D grid and the launch dimensions that walk it."""
    box = Lines()
    box.lo, box.hi = wp.vec3i(*lo), wp.vec3i(*hi)
    box.axis = dim - 1
    extent = [max(int(h) - int(l), 0) for l, h in zip(lo, hi)]  # noqa: E741
    n = extent[box.axis]
    box.length = max(n, 1) if wp.get_device(device).is_cpu else 1
    dims = list(extent)
    dims[box.axis] = (n + box.length - 1) // box.length
    return box, tuple(dims)


def split_lines(box: Lines, dims, parts: int) -> list[tuple[Lines, tuple[int, int, int]]]:
    """box as `parts` slabs along axis 0 (never the axis threads walk), each with its launch dims; a
    kernel that writes only the cells it walks runs on the slabs at once with the box's result."""
    n = dims[0]
    parts = max(1, min(parts, n))
    out = []
    for q in range(parts):
        a, b = n * q // parts, n * (q + 1) // parts
        slab = Lines()
        slab.lo = wp.vec3i(box.lo[0] + a, box.lo[1], box.lo[2])
        slab.hi = wp.vec3i(box.lo[0] + b, box.hi[1], box.hi[2])
        slab.axis, slab.length = box.axis, box.length
        out.append((slab, (b - a, dims[1], dims[2])))
    return out
