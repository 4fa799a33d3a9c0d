"""The surface's curvature for surface tension (physics/tension.py), from height functions
(docs/design.md, "Surface tension", steps 3-6; docs/convergence.md, "The curvature estimate"):

    height_fraction    the fraction the columns sum: the liquid's share L / (L + G), L / V beside air
    column_heights     per cell and axis, the liquid's height in a column of 7 cells
    surface_curvature  kappa from the heights along the axis nearest the normal; div(n) of the
                       smoothed level set where no column fits
    average_curvature  each height-function kappa becomes the mean of those in its 3^dim block

Each kernel walks a line of cells a thread (core/lines.py) and writes only the cells it walks.
"""

import warp as wp

from ..core.grid import EMPTY
from ..core.cells import inside, is_solid, unit
from ..core.lines import Lines, in_box, line_end, line_first, line_kernel, on_line

wp.set_module_options({"enable_backward": False})

CURVATURE_AVERAGING = 2  # passes of average_curvature (docs/convergence.md, "The curvature estimate")


@wp.func
def inner_level(level: wp.array3d(dtype=float), types: wp.array3d(dtype=wp.int32), c: wp.vec3i, centre: float):
    """The level set at c, a cell inside the arrays; a solid cell mirrors `centre` (a 90 degree contact,
    as tension.mirrored_level)."""
    return wp.where(is_solid(types[c[0], c[1], c[2]]), centre, level[c[0], c[1], c[2]])


@wp.func
def height_fraction_at(inv_cell_vol: float, dim: int, has_gas: int, liq_volume: wp.array3d(dtype=float),
                       gas_volume: wp.array3d(dtype=float), types: wp.array3d(dtype=wp.int32),
                       fraction: wp.array3d(dtype=float), i: int, j: int, k: int):
    """The liquid fraction the heights sum, as psi = 2 phi - 1 (not clamped). Away from air (no EMPTY
    cell in the 3^dim block) it is the liquid's share of the particles' volume, L / (L + G): exactly
    +-1 in either bulk, where L / V alone carries the particles' packing noise (6% a cell), which the
    column sums would turn into curvature noise. Beside air, L / V: air holds no particles to share with."""
    liquid = liq_volume[i, j, k]
    if liquid == 0.0:  # -1 either way: no neighbourhood to look at (most of a box around a splash)
        fraction[i, j, k] = -1.0
        return
    beside_air = bool(False)
    nx, ny, nz = types.shape[0] - 1, types.shape[1] - 1, types.shape[2] - 1
    for a in range(-1, 2):  # constant loops, unrolled; a neighbour beyond the arrays clamps onto the block
        for b in range(-1, 2):
            for c in range(-1, 2):
                if dim == 3 or c == 0:
                    if types[wp.clamp(i + a, 0, nx), wp.clamp(j + b, 0, ny), wp.clamp(k + c, 0, nz)] == EMPTY:
                        beside_air = True
    total = liquid
    if has_gas != 0:
        total += gas_volume[i, j, k]
    value = 2.0 * liquid * inv_cell_vol - 1.0
    if not beside_air and total > 0.0:
        value = 2.0 * liquid / total - 1.0
    fraction[i, j, k] = value


height_fraction = line_kernel(height_fraction_at)


COLUMN_HALF = 3  # a height column spans 2 * 3 + 1 cells: the splat's 1.5 cells each side, and a slope of 1


@wp.func
def boxed_fraction(fraction: wp.array3d(dtype=float), q: wp.vec3i, lo: wp.vec3i, hi: wp.vec3i):
    """The fraction at q; outside the launch box [lo, hi), which holds no liquid (core/active_box.py),
    psi = -1 without reading it."""
    psi = float(-1.0)
    if in_box(lo, hi, q):
        psi = fraction[q[0], q[1], q[2]]
    return psi


@wp.func
def column_height(fraction: wp.array3d(dtype=float), types: wp.array3d(dtype=wp.int32), c: wp.vec3i, axis: int,
                  lo: wp.vec3i, hi: wp.vec3i):
    """The liquid's height in the column of 2 COLUMN_HALF + 1 cells along `axis` centred on c, in cells
    (-1: not valid): the sum of the liquid fraction (psi + 1) / 2. Valid when the column lies in the
    arrays, ends on opposite sides of the surface (checked first: most columns do not) and crosses
    no solid."""
    e = unit(axis)
    first = c - e * COLUMN_HALF
    last = c + e * COLUMN_HALF
    if not (inside(types, first) and inside(types, last)):
        return -1.0
    if boxed_fraction(fraction, first, lo, hi) * boxed_fraction(fraction, last, lo, hi) >= -0.25:
        return -1.0
    total = float(0.0)
    solid = int(0)
    for s in range(-COLUMN_HALF, COLUMN_HALF + 1):
        q = c + e * s
        solid += int(is_solid(types[q[0], q[1], q[2]]))
        total += 0.5 * (boxed_fraction(fraction, q, lo, hi) + 1.0)
    if solid > 0:
        return -1.0
    return total


@wp.kernel
def column_heights(box: Lines, dim: int, lo: wp.vec3i, hi: wp.vec3i, fraction: wp.array3d(dtype=float),
                   types: wp.array3d(dtype=wp.int32), heights: wp.array3d(dtype=wp.vec3)):
    """Per cell, the column_height along each axis (-1 where the column is not valid; a height is
    >= 0). Launched over the box [lo, hi) grown by a cell, since the curvature at a cell reads the
    columns of its neighbours: each column is summed once, not by all nine cells."""
    ti, tj, tk = wp.tid()
    first = line_first(box, ti, tj, tk)
    for s in range(first[box.axis], line_end(box, first)):
        c = on_line(first, box.axis, s)
        h = wp.vec3(-1.0)
        for a in range(3):
            if a < dim:
                h[a] = column_height(fraction, types, c, a, lo, hi)
        heights[c[0], c[1], c[2]] = h


@wp.func
def height_curvature(heights: wp.array3d(dtype=wp.vec3), c: wp.vec3i, axis: int, dim: int, dx: float):
    """kappa from the heights of the 3 (2D) or 3 x 3 (3D) columns along `axis` around c (Popinet 2009),
    central differences: second order on exact fractions (docs/convergence.md, "The curvature
    estimate"). h is the liquid's height whichever side it is on, so kappa = h'' / (1 + h'^2)^(3/2)
    (2D) and its 3D form are +1/R for a bubble, as div(n) with n into the liquid. The second value
    is 1 when every column is valid."""
    b = (axis + 1) % 3
    t = (axis + 2) % 3
    if dim == 2:
        b = 1 - axis  # the slab's other in-plane axis; no second transverse axis
    h = wp.mat33(0.0)  # h[u + 1, v + 1]: the column offset by u along b and v along t
    valid = float(1.0)
    for u in range(-1, 2):
        for v in range(-1, 2):
            if dim == 3 or v == 0:
                q = c + unit(b) * u + unit(t) * v
                hq = heights[q[0], q[1], q[2]][axis]
                h[u + 1, v + 1] = hq
                if hq < 0.0:
                    valid = 0.0
    if valid == 0.0:
        return wp.vec2(0.0, 0.0)
    hb = 0.5 * (h[2, 1] - h[0, 1])  # derivatives in cells: the heights are in cells too
    hbb = h[2, 1] - 2.0 * h[1, 1] + h[0, 1]
    if dim == 2:
        return wp.vec2(hbb / (dx * wp.pow(1.0 + hb * hb, 1.5)), 1.0)
    ht = 0.5 * (h[1, 2] - h[1, 0])
    htt = h[1, 2] - 2.0 * h[1, 1] + h[1, 0]
    hbt = 0.25 * (h[2, 2] - h[2, 0] - h[0, 2] + h[0, 0])
    num = (1.0 + ht * ht) * hbb + (1.0 + hb * hb) * htt - 2.0 * hb * ht * hbt
    return wp.vec2(num / (dx * wp.pow(1.0 + hb * hb + ht * ht, 1.5)), 1.0)


CENTRING_SHIFT = 2  # the most cells centred_column moves along the axis (the band is about +-2 cells)


@wp.func
def centred_column(heights: wp.array3d(dtype=wp.vec3), c: wp.vec3i, axis: int, liquid_up: float, dim: int):
    """The cell along `axis` from c whose column the surface crosses nearest its centre. A column centred
    two cells off the surface holds the surface's transition near one end, truncated, and its height
    reads off (docs/convergence.md, "Best-centred height columns"); every cell of the band measures
    the same stretch of surface, so each takes the curvature of the best-centred column (Popinet 2009).
    `liquid_up` > 0 where the liquid lies towards +axis. c itself where its column is not valid or
    the move would leave the interior."""
    h = heights[c[0], c[1], c[2]][axis]
    if h < 0.0:
        return c
    half = float(COLUMN_HALF) + 0.5  # the column spans [-half, half] about c's centre, in cells
    d = h - half  # the surface's offset from c's centre: liquid fills the column from its low end
    if liquid_up > 0.0:
        d = half - h  # from its high end
    shift = wp.clamp(int(wp.round(d)), -CENTRING_SHIFT, CENTRING_SHIFT)
    moved = c + unit(axis) * shift
    for a in range(3):
        if a < dim and (moved[a] < 1 or moved[a] > heights.shape[a] - 2):
            return c
    return moved


@wp.func
def surface_curvature_at(dx: float, dim: int, types: wp.array3d(dtype=wp.int32), level: wp.array3d(dtype=float),
                         heights: wp.array3d(dtype=wp.vec3), curvature: wp.array3d(dtype=float),
                         from_heights: wp.array3d(dtype=float), i: int, j: int, k: int):
    """kappa near the liquid's surface only (where the smoothed psi, `level`, is not +-1): from the
    column `heights` along the axis nearest the normal where the columns around the cell are valid
    (`from_heights` 1), else div(grad psi / |grad psi|) of `level`, central differences (thin films,
    walls, the arrays' edge).

    The normal points into the liquid, so kappa = +(d-1)/R for a bubble of radius R and -(d-1)/R
    for a drop: the pressure jump (non-liquid minus liquid) is sigma kappa in both cases. Clamped
    to 1/dx, the largest curvature the grid can carry.
    """
    c = wp.vec3i(i, j, k)
    curvature[i, j, k] = 0.0
    from_heights[i, j, k] = 0.0
    if is_solid(types[i, j, k]):
        return
    if i == 0 or j == 0 or i == types.shape[0] - 1 or j == types.shape[1] - 1:
        return
    if dim == 3 and (k == 0 or k == types.shape[2] - 1):
        return
    p0 = level[i, j, k]
    if wp.abs(p0) >= 0.99:
        return
    grad = wp.vec3(0.0)
    hess = wp.mat33(0.0)
    for a in range(3):  # constant loops (unrolled); the axes past dim are skipped; no neighbour is outside
        if a < dim:
            ea = unit(a)
            pp = inner_level(level, types, c + ea, p0)
            pm = inner_level(level, types, c - ea, p0)
            grad[a] = (pp - pm) / (2.0 * dx)
            hess[a, a] = (pp - 2.0 * p0 + pm) / (dx * dx)
            for b in range(3):
                if b > a and b < dim:
                    eb = unit(b)
                    cross = (inner_level(level, types, c + ea + eb, p0)
                             - inner_level(level, types, c + ea - eb, p0)
                             - inner_level(level, types, c - ea + eb, p0)
                             + inner_level(level, types, c - ea - eb, p0)) / (4.0 * dx * dx)
                    hess[a, b] = cross
                    hess[b, a] = cross
    g2 = wp.dot(grad, grad)
    if g2 < 1.0e-12 / (dx * dx):
        return
    axis = int(0)  # the axis nearest the normal: the surface's slope across it is at most 1
    if wp.abs(grad[1]) > wp.abs(grad[axis]):
        axis = 1
    if dim == 3 and wp.abs(grad[2]) > wp.abs(grad[axis]):
        axis = 2
    kh = height_curvature(heights, centred_column(heights, c, axis, grad[axis], dim), axis, dim, dx)
    # div(n) = (|g|^2 tr(H) - g^T H g) / |g|^3
    kappa = (g2 * wp.trace(hess) - wp.dot(grad, hess * grad)) / (g2 * wp.sqrt(g2))
    if kh[1] > 0.0:
        kappa = kh[0]
        from_heights[i, j, k] = 1.0
    curvature[i, j, k] = wp.clamp(kappa, -1.0 / dx, 1.0 / dx)


surface_curvature = line_kernel(surface_curvature_at)


@wp.func
def average_curvature_at(dim: int, curvature: wp.array3d(dtype=float), from_heights: wp.array3d(dtype=float),
                         out: wp.array3d(dtype=float), i: int, j: int, k: int):
    """A height-function curvature becomes the mean of those in its 3^dim block (binomial weights).
    Each measures the same stretch of surface, so on a circle they agree and the mean keeps the value
    (no bias, where smoothing the fraction first flattened the heights: +6% at 8 cells per radius);
    the particles' noise averages out. div(n) cells are left as they are."""
    out[i, j, k] = curvature[i, j, k]
    if from_heights[i, j, k] == 0.0:
        return
    total = float(0.0)
    weight = float(0.0)
    for a in range(-1, 2):  # constant loops, unrolled (a loop over block_offset cost several times more)
        for b in range(-1, 2):
            for c in range(-1, 2):
                if dim == 3 or c == 0:
                    n = wp.vec3i(i + a, j + b, k + c)
                    if inside(from_heights, n):
                        w = float((2 - wp.abs(a)) * (2 - wp.abs(b)) * (2 - wp.abs(c))) * from_heights[n[0], n[1], n[2]]
                        total += w * curvature[n[0], n[1], n[2]]
                        weight += w
    out[i, j, k] = total / weight


average_curvature = line_kernel(average_curvature_at)
