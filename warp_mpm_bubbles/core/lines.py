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

import linecache

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


def slab_planes(n: int, parts: int) -> list[tuple[int, int]]:
    """The planes [a, b) of each slab that split_lines cuts n planes into: `parts` of them, at most n
    (but at least one)."""
    parts = max(1, min(parts, n))
    return [(n * q // parts, n * (q + 1) // parts) for q in range(parts)]


def set_slab(slab: Lines, box: Lines, a: int, b: int):
    """slab = planes [a, b) of box (counted from its low end along axis 0), written in place."""
    slab.lo = wp.vec3i(box.lo[0] + a, box.lo[1], box.lo[2])
    slab.hi = wp.vec3i(box.lo[0] + b, box.hi[1], box.hi[2])
    slab.axis, slab.length = box.axis, box.length


def split_lines(box: Lines, dims, parts: int) -> list[tuple[Lines, tuple[int, int, int]]]:
    """box as `parts` slabs along axis 0 (never the axis threads walk), each with its launch dims; a
    kernel that writes only the cells it walks runs on the slabs at once with the box's result."""
    out = []
    for a, b in slab_planes(dims[0], parts):
        slab = Lines()
        set_slab(slab, box, a, b)
        out.append((slab, (b - a, dims[1], dims[2])))
    return out


# The kernel that line_kernel writes for a cell function `cell(args..., i, j, k)`: the box first, then
# the function's own arguments but the cell.
_WALK = '''\
def {name}(box, {args}):
    ti, tj, tk = wp.tid()
    first = line_first(box, ti, tj, tk)
    for s in range(first[box.axis], line_end(box, first)):
        c = on_line(first, box.axis, s)
        cell({args}, c[0], c[1], c[2])
'''


def line_kernel(cell) -> wp.Kernel:
    """The kernel that walks a Lines box calling the wp.func `cell` at each of its cells: `cell`'s
    last three arguments are the cell's indices i, j, k; the kernel's arguments are the box, then
    `cell`'s others in their order. Named as `cell` without its `_at` suffix, in `cell`'s module,
    documented by its docstring: so each cell kernel is written once, as a function of one cell.

    Warp reads a kernel's Python source, which this writes (the loop in this module's docstring) and
    registers with linecache under a name of its own, as dataclasses does for the methods it writes."""
    names = list(cell.input_types)[:-3]
    name = cell.key.removesuffix("_at")
    module = cell.func.__module__
    source = _WALK.format(name=name, args=", ".join(names))
    filename = f"<line kernel {module}.{name}>"
    linecache.cache[filename] = (len(source), None, source.splitlines(True), filename)
    scope = {"wp": wp, "line_first": line_first, "line_end": line_end, "on_line": on_line, "cell": cell}
    exec(compile(source, filename, "exec"), scope)  # noqa: S102 (the source is the template above)
    walk = scope[name]
    walk.__annotations__ = {"box": Lines, **{n: cell.input_types[n] for n in names}}
    walk.__module__, walk.__qualname__, walk.__doc__ = module, name, cell.func.__doc__
    return wp.kernel(enable_backward=False)(walk)
