"""Drainage of the liquid held in foam, by the foam-drainage equation (Verbist, Weaire & Kraynik 1996).

With z along gravity and alpha the liquid volume fraction of the foam,

    d(alpha)/dt + d/dz ( K1 alpha^2 - K2 alpha^(1/2) d(alpha)/dz ) = 0

    K1 = rho g L^2 / (delta_a C mu)                  m/s    (gravity through the Plateau borders)
    K2 = sqrt(C0) gamma L / (2 C mu sqrt(delta_a))    m^2/s  (capillary suction, wet to dry)

L = (pi / (6 sqrt 2))^(1/3) R is the Plateau-border (edge) length of a Kelvin cell of the bubbles'
volume (R the bubble radius), delta_a = 0.171 the Kelvin foam's geometric constant (alpha = delta_a
A / L^2, A a border's cross-section), C0 = sqrt(3) - pi/2 (A = C0 r^2, r the border's radius of
curvature) and C the borders' viscous drag coefficient (about 50 for rigid, no-slip walls). The
bracket is the liquid's flux along gravity, a volume per area per time.

Discretisation: the foam particles splat their gas and liquid volume to the cells (serially, so the
sums are the same on every run); every grid column is a 1D finite-volume problem along the up axis.
A run of cells holding foam exchanges liquid across the faces between its cells (face fraction the
mean of the two cells'); its top face is closed; its bottom face opens onto the cell below:

    liquid below  the pool: alpha = WET_LIMIT at the interface, half a cell from the bottom cell's
                  centre (a foam on its liquid is wet at the bottom; a drier foam draws liquid up)
    solid below   closed
    air below     free outflow, K1 alpha^2 (the liquid drips out of the foam)

Each cell's liquid changes by face area x dt x (flux in - flux out), so the liquid one cell loses its
neighbour gains, bit for bit; what crosses a run's bottom face leaves (or, drawn up, joins) the foam.
The explicit update sub-steps within the step (every column on its own), to the diffusive and
advective limits of its own run, so the simulation's time step does not change. The cells' new liquid
goes back to their particles in proportion to their gas volume (the films of one cell share one
fraction); the ledger books each particle's change, so the liquid the foam held, lent, drained and
lost to bursts balances to float64 round-off.
"""

from __future__ import annotations

import math

import warp as wp

from ..core.cells import cell_of, inside, is_solid
from ..core.geometry import GridGeometry
from ..core.grid import EMPTY, PHASE_FOAM
from ..core.kernel_args import Particles

wp.set_module_options({"enable_backward": False})

DELTA_A = 0.171  # Kelvin foam: alpha = DELTA_A * A / L^2
C0 = math.sqrt(3.0) - 0.5 * math.pi  # a Plateau border's cross-section: A = C0 r^2
KELVIN_EDGE = (math.pi / (6.0 * math.sqrt(2.0))) ** (1.0 / 3.0)  # L / R for a Kelvin cell of the sphere's volume
WET_LIMIT = wp.constant(0.36)  # random close packing: wetter than this, the bubbles separate
MAX_SUBSTEPS = wp.constant(4096)
SAFETY = wp.constant(0.4)  # of the explicit update's stability limit
PACKED_SPACING = wp.constant(0.5)  # of a cell: the least height of a head's cell of foam in the column solve
MIN_HEIGHT = wp.constant(0.1)  # of a cell: a nearly empty cell counts this tall (keeps sub-steps bounded)

# The liquid ledger's entries, float64 m^3 of liquid. LEFT: the films of foam that went out
# through an open wall (the liquid leaves the domain with them).
LENT, DRAINED, BURST, THROUGH_BOTTOM, LEFT = range(5)
LEDGER_SIZE = 5


@wp.struct
class FoamBook:
    """A foam particle's clock and films, and the books their liquid is kept in."""

    life: wp.array(dtype=float)  # seconds left
    liquid: wp.array(dtype=float)  # m^3 of liquid in its films
    ledger: wp.array(dtype=wp.float64)  # the stage's liquid ledger (LENT, DRAINED, BURST, THROUGH_BOTTOM, LEFT)
    # With a two-way head (foam_head.py): per grid column (at its cell of up index 0), the liquid
    # owed to the water, m^3 (lent to films: negative); without: a stand-in nothing reads.
    returned: wp.array3d(dtype=wp.float64)
    head: int  # 1 with a two-way head


def foam_book(life, liquid, ledger, returned, head: bool) -> FoamBook:
    b = FoamBook()
    b.life, b.liquid, b.ledger, b.returned, b.head = life, liquid, ledger, returned, int(head)
    return b


@wp.func
def book_to_column(book: FoamBook, c: wp.vec3i, up_axis: int, volume: wp.float64):
    """With a head: `volume` of liquid owed to the water of the column holding cell c."""
    if book.head == 0:
        return
    s = c
    s[up_axis] = 0
    if inside(book.returned, s):
        wp.atomic_add(book.returned, s[0], s[1], s[2], volume)


def drainage_coefficients(bubble_radius, density, gravity, viscosity, surface_tension, drag):
    """(K1 in m/s, K2 in m^2/s) of the drainage equation, from the foam's and liquid's properties."""
    edge = KELVIN_EDGE * bubble_radius
    k1 = density * gravity * edge * edge / (DELTA_A * drag * viscosity)
    k2 = math.sqrt(C0) * surface_tension * edge / (2.0 * drag * viscosity * math.sqrt(DELTA_A))
    return k1, k2


@wp.kernel
def splat_foam(geo: GridGeometry, particles: Particles, liquid: wp.array(dtype=float),
               gas_cells: wp.array3d(dtype=wp.float64), liquid_cells: wp.array3d(dtype=wp.float64)):
    """Each foam particle's gas and liquid volume into its cell. Launched serially: one summing order."""
    p = wp.tid()
    if particles.active[p] == 0 or particles.phase[p] != PHASE_FOAM:
        return
    c = cell_of(particles.x[p], geo.origin, geo.dx)
    if not inside(gas_cells, c):
        return
    wp.atomic_add(gas_cells, c[0], c[1], c[2], wp.float64(particles.vol0[p] * particles.J[p]))
    wp.atomic_add(liquid_cells, c[0], c[1], c[2], wp.float64(liquid[p]))


@wp.func
def fraction(gas: wp.float64, liq: wp.float64):
    return wp.max(float(liq / (gas + liq)), 0.0)


@wp.func
def face_flux(a_up: float, a_down: float, distance: float, k1: float, k2: float):
    """Flux along gravity (m/s: liquid volume per area per time) between the fraction above, a_up,
    and the one below, a_down, their centres `distance` apart."""
    a = 0.5 * (a_up + a_down)
    return k1 * a * a - k2 * wp.sqrt(a) * (a_down - a_up) / distance


@wp.func
def bottom_flux(a: float, below: int, liquid_below: float, half: float, k1: float, k2: float):
    """Flux out through a foam run's bottom face, by what lies below it (`half`: from the bottom
    cell's centre to the face)."""
    if is_solid(below):
        return 0.0
    if below != EMPTY and liquid_below > 0.5:
        return face_flux(a, WET_LIMIT, half, k1, k2)  # the pool
    return k1 * a * a  # free outflow into air


@wp.func
def cell_at(c0: wp.vec3i, axis: int, j: int):
    c = c0
    c[axis] = j
    return c


@wp.func
def next_foam(gas_cells: wp.array3d(dtype=wp.float64), c0: wp.vec3i, axis: int, j: int, step: int, n: int):
    """The index of the next cell after j (by `step`) in the column that holds foam; -1: none."""
    k = j + step
    while k >= 0 and k < n:
        c = cell_at(c0, axis, k)
        if gas_cells[c[0], c[1], c[2]] > wp.float64(0.0):
            return k
        k = k + step
    return -1


@wp.func
def run_substeps(gas_cells: wp.array3d(dtype=wp.float64), liquid_cells: wp.array3d(dtype=wp.float64),
                 c0: wp.vec3i, axis: int, lo: int, hi: int, dt: float, dx: float, k1: float, k2: float,
                 packed: int):
    """Sub-steps that keep the explicit update of cells lo..hi (one run) stable."""
    area = dx * dx
    a_max = float(WET_LIMIT)
    h_min = dx
    for j in range(lo, hi + 1):
        c = cell_at(c0, axis, j)
        if gas_cells[c[0], c[1], c[2]] <= wp.float64(0.0):
            continue  # a gap in a head's packed column
        a_max = wp.max(a_max, fraction(gas_cells[c[0], c[1], c[2]], liquid_cells[c[0], c[1], c[2]]))
        h = float(gas_cells[c[0], c[1], c[2]] + liquid_cells[c[0], c[1], c[2]]) / area
        h_min = wp.min(h_min, wp.max(h, MIN_HEIGHT * dx))
    # Diffusion across the half-cell to the pool, and gravity's wave speed 2 K1 alpha.
    diffusion = h_min * 0.5 * dx / (2.0 * k2 * wp.sqrt(a_max) + 1.0e-30)
    if packed != 0:  # centres as close as PACKED_SPACING / 2 cells
        diffusion = h_min * (0.5 * PACKED_SPACING) * dx / (2.0 * k2 * wp.sqrt(a_max) + 1.0e-30)
    limit = SAFETY * wp.min(diffusion, h_min / (2.0 * k1 * a_max + 1.0e-30))
    return wp.clamp(int(wp.ceil(dt / limit)), 1, MAX_SUBSTEPS)


@wp.func
def spacing(gas_cells: wp.array3d(dtype=wp.float64), liquid_cells: wp.array3d(dtype=wp.float64), c: wp.vec3i,
            dx: float, packed: int):
    """A cell's foam height along the column: dx, or packed, its volume over the cell's area (at
    least PACKED_SPACING dx: a cell holding one small bubble is not a thin layer of its own)."""
    if packed == 0:
        return dx
    h = float(gas_cells[c[0], c[1], c[2]] + liquid_cells[c[0], c[1], c[2]]) / (dx * dx)
    return wp.clamp(h, PACKED_SPACING * dx, dx)


@wp.func
def drain_run(gas_cells: wp.array3d(dtype=wp.float64), liquid_cells: wp.array3d(dtype=wp.float64),
              c0: wp.vec3i, axis: int, step: int, lo: int, hi: int, below: int, liquid_below: float,
              dt: float, dx: float, k1: float, k2: float, packed: int):
    """One explicit step of the cells lo..hi (bottom to top, `step` +1 or -1 along the index);
    returns the liquid volume that left through the bottom face. packed = 1: the cells' foam lies
    stacked, each cell's as tall as its volume over the cell's area, so centres are that far apart."""
    area = wp.float64(dx * dx)
    c = cell_at(c0, axis, lo)
    a = fraction(gas_cells[c[0], c[1], c[2]], liquid_cells[c[0], c[1], c[2]])
    size = spacing(gas_cells, liquid_cells, c, dx, packed)
    q_out = bottom_flux(a, below, liquid_below, 0.5 * size, k1, k2)
    left = wp.float64(dt * q_out) * area
    j = lo
    while True:
        q_in = float(0.0)  # the run's top face is closed
        a_next = float(0.0)
        j_next = j
        size_next = size
        if j != hi:
            j_next = next_foam(gas_cells, c0, axis, j, step, gas_cells.shape[axis])
            n = cell_at(c0, axis, j_next)
            a_next = fraction(gas_cells[n[0], n[1], n[2]], liquid_cells[n[0], n[1], n[2]])
            size_next = spacing(gas_cells, liquid_cells, n, dx, packed)
            distance = dx
            if packed != 0:
                distance = 0.5 * (size + size_next)
            q_in = face_flux(a_next, a, distance, k1, k2)
        change = wp.float64(dt * q_in) * area - wp.float64(dt * q_out) * area
        liquid_cells[c[0], c[1], c[2]] = liquid_cells[c[0], c[1], c[2]] + change
        if j == hi:
            break
        q_out = q_in  # the face between them: what j gains from above, the next loses below
        j = j_next
        c = cell_at(c0, axis, j)
        a = a_next
        size = size_next
    return left


@wp.kernel
def drain_columns(dt: float, k1: float, k2: float, dx: float, up_axis: int, up_sign: int,
                  types: wp.array3d(dtype=wp.int32), liq_volume: wp.array3d(dtype=float),
                  gas_cells: wp.array3d(dtype=wp.float64), liquid_cells: wp.array3d(dtype=wp.float64),
                  ledger: wp.array(dtype=wp.float64), head: int):
    """Drain every run of foam cells in a column (launched over the cells with the up axis's extent
    1). The liquid through a run's bottom is booked in ledger[THROUGH_BOTTOM]. With a head (head =
    1) a column's foam is one run, packed: a cell without foam between two with it is a gap between
    particles stacked on each other, not open air (its neighbours exchange liquid across it)."""
    i, j0, k = wp.tid()
    c0 = wp.vec3i(i, j0, k)
    n = types.shape[up_axis]
    cell_vol = dx * dx * dx
    lo = int(0)
    if up_sign < 0:
        lo = n - 1
    j = lo
    while j >= 0 and j < n:
        c = cell_at(c0, up_axis, j)
        if gas_cells[c[0], c[1], c[2]] <= wp.float64(0.0):
            j = j + up_sign
            continue
        top = j  # the run of foam cells from j upward
        while top + up_sign >= 0 and top + up_sign < n:
            u = cell_at(c0, up_axis, top + up_sign)
            if gas_cells[u[0], u[1], u[2]] <= wp.float64(0.0):
                above = next_foam(gas_cells, c0, up_axis, top, up_sign, n)
                if head == 0 or above < 0:
                    break
                top = above
            else:
                top = top + up_sign
        below = int(2)  # SOLID_FREE_SLIP: outside the grid is a wall
        liquid_below = float(0.0)
        if j - up_sign >= 0 and j - up_sign < n:
            b = cell_at(c0, up_axis, j - up_sign)
            below = types[b[0], b[1], b[2]]
            liquid_below = liq_volume[b[0], b[1], b[2]] / cell_vol
            if head != 0 and j - 2 * up_sign >= 0 and j - 2 * up_sign < n:
                # A head rests on its water: its lowest run drains into the pool the cell below
                # tops (that cell may be the surface's, partly full).
                b2 = cell_at(c0, up_axis, j - 2 * up_sign)
                if not is_solid(below) and liq_volume[b2[0], b2[1], b2[2]] / cell_vol > 0.5:
                    below = types[b2[0], b2[1], b2[2]]
                    liquid_below = liq_volume[b2[0], b2[1], b2[2]] / cell_vol
        subs = run_substeps(gas_cells, liquid_cells, c0, up_axis, wp.min(j, top), wp.max(j, top), dt, dx, k1, k2,
                            head)
        h = dt / float(subs)
        for s in range(subs):
            left = drain_run(gas_cells, liquid_cells, c0, up_axis, up_sign, j, top, below, liquid_below, h, dx, k1, k2,
                             head)
            wp.atomic_add(ledger, THROUGH_BOTTOM, left)
        j = top + up_sign


@wp.kernel
def gather_foam(geo: GridGeometry, particles: Particles, book: FoamBook,
                gas_cells: wp.array3d(dtype=wp.float64), liquid_cells: wp.array3d(dtype=wp.float64)):
    """The cells' drained liquid back to their foam particles, by gas volume; the ledger books
    each particle's change exactly (as the float32 it now holds), and with a head, its column."""
    p = wp.tid()
    if particles.active[p] == 0 or particles.phase[p] != PHASE_FOAM:
        return
    c = cell_of(particles.x[p], geo.origin, geo.dx)
    if not inside(gas_cells, c):
        return
    share = wp.float64(particles.vol0[p] * particles.J[p]) / gas_cells[c[0], c[1], c[2]]
    new = float(wp.max(liquid_cells[c[0], c[1], c[2]] * share, wp.float64(0.0)))
    drained = wp.float64(book.liquid[p]) - wp.float64(new)
    wp.atomic_add(book.ledger, DRAINED, drained)
    book_to_column(book, c, geo.up_axis, drained)
    book.liquid[p] = new


def column_launch_shape(shape, up_axis: int):
    """The cell shape with the up axis's extent 1: one thread a column."""
    return tuple(1 if a == up_axis else s for a, s in enumerate(shape))
