"""Particle <-> grid transfers: APIC on a MAC grid with quadratic B-splines (Jiang et al. 2015).

Each velocity component lives on its own staggered face grid with its own offset. The particle's
affine matrix ``C`` stores, in row ``a``, the gradient of velocity component ``a``. In 2D the
stencil collapses to one node in z. The core transfers (P2G, G2P: one kernel per dimension) visit
every grid in one pass over the nodes; the per-component functions serve the effects' kernels.
"""

import warp as wp

from .geometry import GridGeometry
from .gas_law import gas_compressibility, gas_pressure
from .grid import ACTIVE, AIRBORNE, FLUID, LEAVING, PHASE_GAS, PHASE_LIQUID
from .boundary import clamp_to_domain, finite, fly, keep_in_domain, open_wall_exit, wall_stopped  # noqa: F401 (re-exported)
from .kernel_args import FaceField, FacePairs, Particles, Splat
from .lines import Lines, line_end, line_first, on_line

wp.set_module_options({"enable_backward": False})

# Stagger offsets in cell units: where sample (0,0,0) of each grid sits relative to the grid origin.
U_OFFSET = wp.constant(wp.vec3(0.0, 0.5, 0.5))
V_OFFSET = wp.constant(wp.vec3(0.5, 0.0, 0.5))
W_OFFSET = wp.constant(wp.vec3(0.5, 0.5, 0.0))
CELL_OFFSET = wp.constant(wp.vec3(0.5, 0.5, 0.5))


@wp.func
def bspline_weights(f: float):
    """Quadratic B-spline weights of nodes base, base+1, base+2 for f = X - base in [0.5, 1.5)."""
    return wp.vec3(0.5 * (1.5 - f) * (1.5 - f), 0.75 - (f - 1.0) * (f - 1.0), 0.5 * (f - 0.5) * (f - 0.5))


@wp.struct
class Stencil:
    """The 3x3x3 nodes (3x3x1 in 2D) a particle touches on one staggered grid, with their weights."""

    base: wp.vec3i  # lowest node index
    frac: wp.vec3  # particle position relative to the base node, in cells
    wx: wp.vec3
    wy: wp.vec3
    wz: wp.vec3
    nk: int  # nodes along z: 3, or 1 in 2D where node and particle share z (weight 1)


@wp.func
def make_stencil(X: wp.vec3, dim: int):
    s = Stencil()
    s.base = wp.vec3i(int(wp.floor(X[0] - 0.5)), int(wp.floor(X[1] - 0.5)), int(wp.floor(X[2] - 0.5)))
    s.frac = X - wp.vec3(float(s.base[0]), float(s.base[1]), float(s.base[2]))
    s.wx = bspline_weights(s.frac[0])
    s.wy = bspline_weights(s.frac[1])
    s.wz = bspline_weights(s.frac[2])
    s.nk = 3
    if dim == 2:
        s.base = wp.vec3i(s.base[0], s.base[1], 0)
        s.frac = wp.vec3(s.frac[0], s.frac[1], 0.0)
        s.wz = wp.vec3(1.0, 0.0, 0.0)
        s.nk = 1
    return s


@wp.kernel(enable_backward=False)
def book_outflow(active: wp.array(dtype=wp.int32), phase: wp.array(dtype=wp.int32), mass: wp.array(dtype=float),
                 outflow: wp.array(dtype=wp.float64)):
    """Retire the particles that crossed an open wall (active == LEAVING) and add their mass to
    outflow[phase], kg. Launched as one serial pass on the CPU, so the sum has a fixed order."""
    p = wp.tid()
    if active[p] == LEAVING:
        wp.atomic_add(outflow, phase[p], wp.float64(mass[p]))
        active[p] = 0


@wp.func
def grid_coord(x: wp.vec3, origin: wp.vec3, inv_dx: float, offset: wp.vec3):
    return (x - origin) * inv_dx - offset


@wp.kernel
def p2g_gas(p_atm: float, geo: GridGeometry, particles: Particles, splat: Splat, gas_count: wp.array3d(dtype=wp.int32),
            x_lo: int, x_hi: int):
    """Gas cell state, volume-weighted: splat's gas mass, current volume V0 J, p V and kappa V, and the
    gas particles per cell (runs only with gas). Only cells with x index in [x_lo, x_hi) are written (a
    slab a part, as p2g: every cell still sums in particle order, whatever the split)."""
    p = wp.tid()
    if particles.active[p] == 0 or particles.phase[p] != PHASE_GAS or not finite(particles.x[p]):
        return
    xp = clamp_to_domain(particles.x[p], geo.domain_hi, geo.dx, geo.dim)
    inv_dx = 1.0 / geo.dx
    s = make_stencil(grid_coord(xp, geo.origin, inv_dx, CELL_OFFSET), geo.dim)
    if s.base[0] + 2 < x_lo or s.base[0] >= x_hi:  # the stencil misses this part's slab
        return
    vol = particles.vol0[p] * particles.J[p]
    pg = gas_pressure(particles.gas_law[p], particles.J[p], particles.gas_gamma[p], p_atm)
    kappa = gas_compressibility(particles.gas_law[p], particles.J[p], particles.gas_gamma[p], p_atm)
    for i in range(wp.max(x_lo - s.base[0], 0), wp.min(x_hi - s.base[0], 3)):
        for j in range(3):
            for k in range(s.nk):
                w = s.wx[i] * s.wy[j] * s.wz[k]
                n = s.base + wp.vec3i(i, j, k)
                wp.atomic_add(splat.gas_mass, n[0], n[1], n[2], w * particles.mass[p])
                wp.atomic_add(splat.gas_volume, n[0], n[1], n[2], w * vol)
                wp.atomic_add(splat.gas_pv, n[0], n[1], n[2], w * vol * pg)
                wp.atomic_add(splat.gas_kv, n[0], n[1], n[2], w * vol * kappa)
    c = (xp - geo.origin) * inv_dx
    cell_x = int(wp.floor(c[0]))
    if cell_x >= x_lo and cell_x < x_hi:
        wp.atomic_add(gas_count, cell_x, int(wp.floor(c[1])), int(wp.floor(c[2])), 1)


@wp.kernel
def gas_volume_rate(
    lo: wp.vec3i,  # first index of the launch, which may cover a box (core/active_box.py)
    dx: float,
    dim: int,
    types: wp.array3d(dtype=wp.int32),
    vel: FaceField,
    gas_volume: wp.array3d(dtype=float),
    target_div: wp.array3d(dtype=float),
    rate: wp.array3d(dtype=float),
):
    """The volume change per second that belongs to the gas in each cell, per unit gas volume.

    The liquid is incompressible, so a cell's divergence (beyond what the volume correction asked
    of its liquid) is its gas expanding or compressing. Interpolating the divergence to every
    particle instead handed most of it to the liquid particles beside the interface, whose J
    nobody reads, and the gas's J lagged (tests/test_gas.py's collapse measured it).
    """
    i, j, k = wp.tid()
    i, j, k = i + lo[0], j + lo[1], k + lo[2]
    rate[i, j, k] = 0.0
    vg = gas_volume[i, j, k]
    if types[i, j, k] != FLUID or vg <= 0.0:
        return
    div = (vel.u[i + 1, j, k] - vel.u[i, j, k] + vel.v[i, j + 1, k] - vel.v[i, j, k]) / dx
    if dim == 3:
        div += (vel.w[i, j, k + 1] - vel.w[i, j, k]) / dx
    rate[i, j, k] = (div - target_div[i, j, k]) * dx * dx * dx / vg


@wp.func
def compressible_gas_stencil(geo: GridGeometry, particles: Particles, p: int):
    """(True, the stencil of the cells it splats to) for an active compressible gas particle (law not
    0) at a finite position; else (False, an empty stencil)."""
    if particles.active[p] == 0 or particles.phase[p] != PHASE_GAS or particles.gas_law[p] == 0:
        return False, Stencil()
    if not finite(particles.x[p]):
        return False, Stencil()
    xp = clamp_to_domain(particles.x[p], geo.domain_hi, geo.dx, geo.dim)
    return True, make_stencil(grid_coord(xp, geo.origin, 1.0 / geo.dx, CELL_OFFSET), geo.dim)


@wp.kernel
def update_gas_J(start: int, dt: float, geo: GridGeometry, rate: wp.array3d(dtype=float), particles: Particles):
    """Gas particles take their cells' gas volume change, shared in proportion to the volume
    each contributed in p2g_gas (same weights, same positions), so the gas as a whole changes
    volume exactly as its cells do: sum_p w_pc V_p J_p = V_gas,c. Incompressible gas (law 0) keeps
    its J: what its cells' divergence holds beyond the correction's target is the solve's residual
    and, in a closed tank, the mean the singular solve removes (a few percent of a bubble's
    volume over a rising-bubble benchmark). Particles start + tid (Simulation.launch_particles)."""
    p = wp.tid() + start
    gas, s = compressible_gas_stencil(geo, particles, p)
    if not gas:
        return
    r = float(0.0)
    for i in range(3):
        for j in range(3):
            for k in range(s.nk):
                r += s.wx[i] * s.wy[j] * s.wz[k] * rate[s.base[0] + i, s.base[1] + j, s.base[2] + k]
    # At most a factor e per step: a guard for a cell whose gas is a sliver (the volume change
    # shared by tiny gas volumes), never reached in the validation cases.
    particles.J[p] = particles.J[p] * wp.exp(wp.clamp(dt * r, -1.0, 1.0))


@wp.func
def gather_component(vel: wp.array3d(dtype=float), X: wp.vec3, dim: int, dx: float):
    """Interpolate one component and its APIC gradient (B-spline: D^-1 = 4/dx^2) at a particle."""
    s = make_stencil(X, dim)
    value = float(0.0)
    grad = wp.vec3(0.0)
    for i in range(3):
        for j in range(3):
            for k in range(s.nk):
                w = s.wx[i] * s.wy[j] * s.wz[k]
                g = vel[s.base[0] + i, s.base[1] + j, s.base[2] + k]
                dpos = (wp.vec3(float(i), float(j), float(k)) - s.frac) * dx
                value += w * g
                grad += (4.0 / (dx * dx)) * w * g * dpos
    return wp.vec4(value, grad[0], grad[1], grad[2])


@wp.func
def gather_velocity_and_affine(vel: FaceField, xp: wp.vec3, origin: wp.vec3, dx: float, dim: int):
    """APIC gather at xp: the velocity and the affine matrix C (rows: one per face component)."""
    inv_dx = 1.0 / dx
    gu = gather_component(vel.u, grid_coord(xp, origin, inv_dx, U_OFFSET), dim, dx)
    gv = gather_component(vel.v, grid_coord(xp, origin, inv_dx, V_OFFSET), dim, dx)
    gw = wp.vec4(0.0)
    if dim == 3:
        gw = gather_component(vel.w, grid_coord(xp, origin, inv_dx, W_OFFSET), dim, dx)
    C = wp.matrix_from_rows(wp.vec3(gu[1], gu[2], gu[3]), wp.vec3(gv[1], gv[2], gv[3]), wp.vec3(gw[1], gw[2], gw[3]))
    return wp.vec3(gu[0], gv[0], gw[0]), C


@wp.func
def interpolate_velocity(vel: FaceField, xp: wp.vec3, origin: wp.vec3, dx: float, dim: int):
    """The grid velocity at xp (PIC: without the APIC gradient), for the Lagrangian effects."""
    v, C = gather_velocity_and_affine(vel, xp, origin, dx, dim)
    return v


# ------------------------------------------------------------------------- fused transfers
# One kernel per direction and dimension (the node loops' bounds fixed at compile time, so they
# unroll). The stencils of the three face grids and the cell grid share their per-axis weights
# (along each axis, nodes sit on faces, offset 0, or at centres, offset 0.5).
# - p2g visits every grid in one pass over the nodes, with make_stencil's arithmetic per node, so
#   its sums are bit for bit those of one pass per component. Its cost is the number of
#   read-modify-writes (about the same for a vec2 as for a float), so it adds (momentum, mass)
#   pairs, split afterwards by split_pairs: 135 per particle instead of 270. Measured with
#   benchmarks/performance/transfers.py: 0.7x for the fused pass, then 0.76x for the pairs.
# - g2p applies the weights one axis at a time, two multiply-adds per node (it was compute-bound):
#   0.75x of the fused loop, equal to it within float32 rounding.


@wp.func
def axis_stencil(c: float, offset: float):
    """Base node, fraction and weights along one axis at cell coordinate c, nodes at `offset`."""
    X = c - offset
    base = int(wp.floor(X - 0.5))
    frac = X - float(base)
    return base, frac, bspline_weights(frac)


@wp.struct
class MacStencil:
    """The stencils of the u, v, w face grids and the cell grid of one particle (see mac_stencil)."""

    face_base: wp.vec3i  # per axis: nodes on faces, the grid of that axis' own component
    face_frac: wp.vec3
    face_w: wp.mat33  # row a: the weights along axis a
    centre_base: wp.vec3i  # per axis: nodes at cell centres (the cell grid, the other components)
    centre_frac: wp.vec3
    centre_w: wp.mat33


@wp.func
def mac_stencil(xp: wp.vec3, origin: wp.vec3, inv_dx: float, dim: int):
    c = (xp - origin) * inv_dx
    s = MacStencil()
    for a in range(3):
        b, f, w = axis_stencil(c[a], 0.0)
        s.face_base[a] = b
        s.face_frac[a] = f
        s.face_w[a] = w
        b, f, w = axis_stencil(c[a], 0.5)
        s.centre_base[a] = b
        s.centre_frac[a] = f
        s.centre_w[a] = w
    if dim == 2:  # one node along z, where the particle is
        s.face_base[2] = 0
        s.centre_base[2] = 0
        s.face_frac[2] = 0.0
        s.centre_frac[2] = 0.0
        s.face_w[2] = wp.vec3(1.0, 0.0, 0.0)
        s.centre_w[2] = wp.vec3(1.0, 0.0, 0.0)
    return s


@wp.func
def component_stencil(s: MacStencil, a: int):
    """The stencil of face component a (a = 3: the cell grid): faces along a, centres elsewhere."""
    out = Stencil()
    out.base = s.centre_base
    out.frac = s.centre_frac
    out.wx = s.centre_w[0]
    out.wy = s.centre_w[1]
    out.wz = s.centre_w[2]
    if a < 3:
        out.base[a] = s.face_base[a]
        out.frac[a] = s.face_frac[a]
    if a == 0:
        out.wx = s.face_w[0]
    if a == 1:
        out.wy = s.face_w[1]
    if a == 2:
        out.wz = s.face_w[2]
    return out


@wp.func
def pair_row(a: wp.array3d(dtype=wp.vec2), base: wp.vec3i, i: int, j: int):
    """Nodes (base + (i, j, 0..2)) of a contiguous array, as an array of 3 from base z on: the node
    is then reached at a constant offset (indexing `a` itself tests each of the three indices for a
    negative wrap and multiplies it by its stride, at every node). Bases are never negative:
    particles are clamped inside the domain, a ghost cell from the arrays' edge."""
    n = ((base[0] + i) * a.shape[1] + base[1] + j) * a.shape[2] + base[2]
    return wp.array(ptr=wp.uint64(a.ptr) + wp.uint64(n) * wp.uint64(8), shape=(3,), dtype=wp.vec2)



@wp.func
def value_row(a: wp.array3d(dtype=float), base: wp.vec3i, i: int, j: int):
    """pair_row for an array of floats."""
    n = ((base[0] + i) * a.shape[1] + base[1] + j) * a.shape[2] + base[2]
    return wp.array(ptr=wp.uint64(a.ptr) + wp.uint64(n) * wp.uint64(4), shape=(3,), dtype=float)


@wp.func
def splat_pair(face: wp.array3d(dtype=wp.vec2), s: Stencil, i: int, j: int, k: int, dx: float, m: float, vel: float,
               grad: wp.vec3):
    """Node (i, j, k)'s share of one particle's APIC momentum and mass of one component, added as a
    pair: one read-modify-write instead of two. `face` is contiguous (pair_row)."""
    w = s.wx[i] * s.wy[j] * s.wz[k]
    dpos = (wp.vec3(float(i), float(j), float(k)) - s.frac) * dx
    wm = w * m
    wp.atomic_add(pair_row(face, s.base, i, j), k, wp.vec2(wm * (vel + wp.dot(grad, dpos)), wm))


@wp.kernel(enable_backward=False)
def split_pairs(box: Lines, pairs: wp.array3d(dtype=wp.vec2), first: wp.array3d(dtype=float),
                second: wp.array3d(dtype=float)):
    """p2g's (momentum, mass) and (mass, volume) pairs into the separate arrays the grid phases read,
    over a box of them (core/lines.py)."""
    ti, tj, tk = wp.tid()
    first_cell = line_first(box, ti, tj, tk)
    for s in range(first_cell[box.axis], line_end(box, first_cell)):
        c = on_line(first_cell, box.axis, s)
        q = pairs[c[0], c[1], c[2]]
        first[c[0], c[1], c[2]] = q[0]
        second[c[0], c[1], c[2]] = q[1]


@wp.func
def owned(node_x: int, x_lo: int, x_hi: int):
    return node_x >= x_lo and node_x < x_hi


@wp.func
def splat_node(face_u: wp.array3d(dtype=wp.vec2), face_v: wp.array3d(dtype=wp.vec2), face_w: wp.array3d(dtype=wp.vec2),
               cell_mv: wp.array3d(dtype=wp.vec2), su: Stencil, sv: Stencil, sw: Stencil, sc: Stencil, i: int, j: int,
               k: int, dx: float, m: float, vol: float, vp: wp.vec3, Cp: wp.mat33, liquid: bool, u_owned: bool,
               c_owned: bool, dim: int):
    """Node (i, j, k) of a particle's stencils: its momentum pairs on the three face grids and, for the
    liquid, its (mass, volume) pair on the cell grid; the u faces if u_owned, the others if c_owned.
    The arrays are contiguous (pair_row)."""
    if u_owned:
        splat_pair(face_u, su, i, j, k, dx, m, vp[0], Cp[0])
    if c_owned:
        splat_pair(face_v, sv, i, j, k, dx, m, vp[1], Cp[1])
        if dim == 3:
            splat_pair(face_w, sw, i, j, k, dx, m, vp[2], Cp[2])
        if liquid:
            w = sc.wx[i] * sc.wy[j] * sc.wz[k]
            wp.atomic_add(pair_row(cell_mv, sc.base, i, j), k, wp.vec2(w * m, w * vol))


def _p2g_kernel(dim: int):
    NK = 3 if dim == 3 else 1

    @wp.kernel(enable_backward=False, name=f"p2g_{dim}d", module="unique")
    def p2g_fused(
        geo: GridGeometry,
        particles: Particles,
        faces: FacePairs,
        cell_mv: wp.array3d(dtype=wp.vec2),
        cell_count: wp.array3d(dtype=wp.int32),
        nonfinite: wp.array(dtype=wp.int32),
        x_lo: int,
        x_hi: int,
    ):
        """Momentum of every active grid-resolved particle; cell mass and rest volume of the liquid;
        particle counts. Foam and sub-grid bubbles (phase > PHASE_GAS) couple through their effects.

        Only nodes with x index in [x_lo, x_hi) are written, on every grid (core/threads.py: the parts
        of one splat own disjoint slabs and each node still sums in particle order); a particle whose
        stencil lies outside the slab is skipped after reading its position.

        A particle with a non-finite position or velocity is skipped and counted in nonfinite[0] (by
        the part that starts at node 0): the step then stops with a message instead of writing outside
        the grid.
        """
        x = particles.x
        phase = particles.phase
        face_u = faces.u
        face_v = faces.v
        face_w = faces.w
        origin = geo.origin
        dx = geo.dx
        p = wp.tid()
        if particles.active[p] != ACTIVE or phase[p] > PHASE_GAS:
            return
        vp = particles.v[p]
        if not (finite(x[p]) and finite(vp)):
            if x_lo == 0:
                wp.atomic_add(nonfinite, 0, 1)
            return
        xp = clamp_to_domain(x[p], geo.domain_hi, dx, wp.static(dim))
        inv_dx = 1.0 / dx
        cell_x = int(wp.floor((xp[0] - origin[0]) * inv_dx))
        if cell_x + 2 < x_lo or cell_x - 1 >= x_hi:  # every grid's stencil: nodes cell_x - 1 .. cell_x + 2
            return
        m = particles.mass[p]
        vol = particles.vol0[p]
        Cp = particles.C[p]
        liquid = phase[p] == PHASE_LIQUID
        s = mac_stencil(xp, origin, inv_dx, wp.static(dim))
        su = component_stencil(s, 0)
        sv = component_stencil(s, 1)
        sw = component_stencil(s, 2)
        sc = component_stencil(s, 3)
        if cell_x - 1 >= x_lo and cell_x + 2 < x_hi:  # the whole stencil is this part's (as a rule)
            for i in range(3):
                for j in range(3):
                    for k in range(wp.static(NK)):
                        splat_node(face_u, face_v, face_w, cell_mv, su, sv, sw, sc, i, j, k, dx, m, vol, vp, Cp,
                                   liquid, True, True, wp.static(dim))
        else:  # near the slab's edge: the slab's nodes only, along x (the u faces' index; the others' is the centres')
            for i in range(wp.max(x_lo - su.base[0], 0), wp.min(x_hi - su.base[0], 3)):
                for j in range(3):
                    for k in range(wp.static(NK)):
                        splat_node(face_u, face_v, face_w, cell_mv, su, sv, sw, sc, i, j, k, dx, m, vol, vp, Cp,
                                   liquid, True, False, wp.static(dim))
            for i in range(wp.max(x_lo - sc.base[0], 0), wp.min(x_hi - sc.base[0], 3)):
                for j in range(3):
                    for k in range(wp.static(NK)):
                        splat_node(face_u, face_v, face_w, cell_mv, su, sv, sw, sc, i, j, k, dx, m, vol, vp, Cp,
                                   liquid, False, True, wp.static(dim))
        c = (xp - origin) * inv_dx
        if owned(cell_x, x_lo, x_hi):
            wp.atomic_add(cell_count, cell_x, int(wp.floor(c[1])), int(wp.floor(c[2])), 1)

    return p2g_fused


def _gather_func(dim: int):
    NK = 3 if dim == 3 else 1

    @wp.func
    def gather_separable(vel: wp.array3d(dtype=float), s: Stencil, dx: float):
        """One component's value and APIC gradient (as gather_component), the weights applied one
        axis at a time: two multiply-adds per node instead of eighteen operations."""
        ijk = wp.vec3(0.0, 1.0, 2.0)
        dpx = (ijk - wp.vec3(s.frac[0])) * dx
        dpy = (ijk - wp.vec3(s.frac[1])) * dx
        dpz = (ijk - wp.vec3(s.frac[2])) * dx
        value = float(0.0)
        gx = float(0.0)
        gy = float(0.0)
        gz = float(0.0)
        for i in range(3):
            ty = float(0.0)
            tyy = float(0.0)
            tyz = float(0.0)
            for j in range(3):
                t = float(0.0)
                tz = float(0.0)
                for k in range(wp.static(NK)):
                    g = value_row(vel, s.base, i, j)[k]
                    t += s.wz[k] * g
                    tz += s.wz[k] * dpz[k] * g
                ty += s.wy[j] * t
                tyy += s.wy[j] * dpy[j] * t
                tyz += s.wy[j] * tz
            value += s.wx[i] * ty
            gx += s.wx[i] * dpx[i] * ty
            gy += s.wx[i] * tyy
            gz += s.wx[i] * tyz
        d = 4.0 / (dx * dx)  # B-spline: D^-1
        return wp.vec4(value, d * gx, d * gy, d * gz)

    @wp.func
    def gather_mac(vel: FaceField, s: MacStencil, dx: float):
        """gather_velocity_and_affine with the shared stencils."""
        gu = gather_separable(vel.u, component_stencil(s, 0), dx)
        gv = gather_separable(vel.v, component_stencil(s, 1), dx)
        gw = wp.vec4(0.0)
        if wp.static(dim == 3):
            gw = gather_separable(vel.w, component_stencil(s, 2), dx)
        C = wp.matrix_from_rows(wp.vec3(gu[1], gu[2], gu[3]), wp.vec3(gv[1], gv[2], gv[3]),
                                wp.vec3(gw[1], gw[2], gw[3]))
        return wp.vec3(gu[0], gv[0], gw[0]), C

    @wp.func
    def sample_separable(vel: wp.array3d(dtype=float), s: Stencil):
        """One component's value at the particle: gather_separable without the gradient, whose
        work a field that moves only positions does not need."""
        value = float(0.0)
        for i in range(3):
            ty = float(0.0)
            for j in range(3):
                row = value_row(vel, s.base, i, j)
                t = float(0.0)
                for k in range(wp.static(NK)):
                    t += s.wz[k] * row[k]
                ty += s.wy[j] * t
            value += s.wx[i] * ty
        return value

    @wp.func
    def sample_mac(vel: FaceField, s: MacStencil):
        """A face field's value at the particle, with the shared stencils."""
        u = wp.vec3(sample_separable(vel.u, component_stencil(s, 0)),
                    sample_separable(vel.v, component_stencil(s, 1)), 0.0)
        if wp.static(dim == 3):
            u[2] = sample_separable(vel.w, component_stencil(s, 2))
        return u

    return gather_mac, sample_mac


def _g2p_kernel(dim: int):
    gather_mac, sample_mac = _gather_func(dim)

    @wp.kernel(enable_backward=False, name=f"g2p_advect_{dim}d", module="unique")
    def g2p_fused(
        first: int,
        dt: float,
        gas_J_from_cells: int,
        slot: int,
        geo: GridGeometry,
        vel: FaceField,
        gas_vel: FaceField,
        shifting: int,
        shift: FaceField,
        particles: Particles,
        max_speed: wp.array(dtype=float),
    ):
        """Gather velocity and affine matrix, update J, move the particle and keep it in the domain
        (grid-resolved phases only: the effects move foam and sub-grid bubbles). Particles from
        `first` on (core/threads.py: the parts of one g2p); their fastest speed goes to
        max_speed[slot]. The gas gathers gas_vel (the liquid's field when the phases share one).
        shifting: the volume correction moves positions (core/volume_shift.py): liquid and gas of
        fixed density also move by dt shift(x), sampled with the same stencil; velocities keep none of it."""
        x = particles.x
        v = particles.v
        J = particles.J
        active = particles.active
        phase = particles.phase
        dx = geo.dx
        domain_hi = geo.domain_hi
        p = wp.tid() + first
        if active[p] == AIRBORNE:  # above an open top: free fall, no grid
            xf, vf, code = fly(x[p], v[p], geo, dt)
            x[p] = xf
            v[p] = vf
            active[p] = code
            wp.atomic_max(max_speed, slot, wp.length(vf))
            return
        if active[p] != ACTIVE or phase[p] > PHASE_GAS:
            return
        xp = clamp_to_domain(x[p], domain_hi, dx, wp.static(dim))
        s = mac_stencil(xp, geo.origin, 1.0 / dx, wp.static(dim))
        field = vel
        if phase[p] == PHASE_GAS:  # the gas's own field (the liquid's when phase velocities are shared)
            field = gas_vel
        vp, Cp = gather_mac(field, s, dx)  # one copy of the gather in the compiled code, not two
        if phase[p] != PHASE_GAS or gas_J_from_cells == 0:  # else update_gas_J, from its cells' volume change
            J[p] = J[p] * wp.exp(dt * wp.trace(Cp))  # dJ/dt = J div v; exp keeps a fast-compressed J positive
        # Advect, then clamp into the domain; a clamped particle loses the velocity that pushed it out.
        # Through an open wall it leaves (booked and retired by book_outflow), or flies (AIRBORNE).
        moved = xp + dt * vp
        if shifting != 0 and (phase[p] == PHASE_LIQUID or particles.gas_law[p] == 0):  # compressible gas: not asked
            moved += dt * sample_mac(shift, s)  # the volume correction's displacement, at the start position
        code = open_wall_exit(moved, geo, phase[p])
        xn, vn = keep_in_domain(moved, vp, code, geo)
        if code == AIRBORNE:
            Cp = wp.mat33(0.0)  # a free-falling drop moves as one
        active[p] = code
        x[p] = xn
        v[p] = vn
        particles.C[p] = Cp
        wp.atomic_max(max_speed, slot, wp.length(vn))

    return g2p_fused


@wp.kernel(enable_backward=False)
def fastest_of_parts(parts: wp.array(dtype=float), n: int, stride: int, max_speed: wp.array(dtype=float)):
    """max_speed[0] = the largest of the g2p parts' speeds, parts[q * stride] (one thread)."""
    for q in range(n):
        wp.atomic_max(max_speed, 0, parts[q * stride])


P2G = {2: _p2g_kernel(2), 3: _p2g_kernel(3)}
G2P = {2: _g2p_kernel(2), 3: _g2p_kernel(3)}
