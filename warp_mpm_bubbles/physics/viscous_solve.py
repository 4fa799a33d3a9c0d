"""The viscous stress div(mu (grad u + grad u^T)) on the MAC grid, explicit or implicit (docs/viscosity.md).

Layout (Batty & Bridson 2008, two fluids instead of one with a free surface):

    u_a            on the faces normal to axis a (the grid's own velocity)
    mu_c, tau_aa   at cell centres: tau_aa = 2 mu_c du_a/dx_a (normal stress)
    mu_e, tau_ab   on the edges of plane (a, b) (2D: cell corners): tau_ab = mu_e (du_a/dx_b + du_b/dx_a)

The operator K u = -div(tau) is the gradient of the dissipation sum_c mu_c sum_a D_aa^2 +
sum_e 2 mu_e D_ab^2, so K is symmetric positive semi-definite and the implicit system
(rho/dt + K) u = (rho/dt) u*, scaled by dt, is symmetric positive definite. The unknowns are the
faces the pressure acts on (inv_rho > 0); every other face keeps u* (walls, moving colliders).

mu_c mixes the phases by the volume each holds in the cell (harmonic mean; Batty's volume weights
where one phase is inviscid). tau_ab is a traction component on both planes through the edge and
is continuous across the interface (stresses in series), so mu_e is a harmonic mix too: by the
liquid share of the edge's own square (psi linear between the cell centres), or the harmonic
mean of its cells where a neighbour is not fluid. An edge beside an EMPTY cell or a free-slip
solid carries no stress (free surface, slip); beside a no-slip solid the face inside the wall
mirrors the fluid face about the wall's velocity (the value the wall face holds: 0, or a moving
collider's).
"""

from __future__ import annotations

import math

import warp as wp

from ..core.grid import EMPTY, FLUID, SOLID_FREE_SLIP
from ..core.cells import cell_type_at, is_solid, unit
from ..core.lines import Lines, line_end, line_first, make_lines, split_lines
from ..core.threads import SPLIT_CELLS, Parallel
from .viscous_iterate import ImplicitSolve
from .viscous_pcg import EXPLICIT, OPERATOR, RED, RHS, AroundFace, value_at  # noqa: F401 (RED: for the tests)

wp.set_module_options({"enable_backward": False})

# An array of this many faces (or edges) runs in slabs on the CPU's threads: the pressure solve's
# threshold. Splitting from 4096 faces doubled the stage's time on a 1000:1 tank at 80 cells (12 s
# against 6 s, 120 steps) on a shared two-core machine, where the hand-off waits for a core.
SPLIT_FACES = SPLIT_CELLS
MAX_RECORDED = 256  # recorded launches kept (ViscousSolver._replay): the PCG needs a few dozen


@wp.func
def inside_solid(types: wp.array3d(dtype=wp.int32), g: wp.vec3i, axis: int):
    """Face g of `axis` has solid cells on both sides (a wall's tangential face)."""
    return is_solid(cell_type_at(types, g - unit(axis))) and is_solid(cell_type_at(types, g))


@wp.func
def mirrored(types: wp.array3d(dtype=wp.int32), other: wp.vec3i, axis: int):
    """1 if `other`, the far face of a difference along an edge, is a wall face to mirror."""
    return int(inside_solid(types, other, axis))


@wp.func
def difference(x: wp.array3d(dtype=float), types: wp.array3d(dtype=wp.int32), hi: wp.vec3i, lo: wp.vec3i,
               axis: int):
    """x[hi] - x[lo] for two faces of `axis` one cell apart across an edge. A face inside a solid
    holds the wall's velocity; the wall is half-way, so its ghost value is 2 u_wall - u_fluid."""
    v_hi = value_at(x, hi)
    v_lo = value_at(x, lo)
    s_hi = inside_solid(types, hi, axis)
    s_lo = inside_solid(types, lo, axis)
    if s_lo and not s_hi:
        v_lo = 2.0 * v_lo - v_hi
    if s_hi and not s_lo:
        v_hi = 2.0 * v_hi - v_lo
    return v_hi - v_lo


@wp.kernel
def cell_viscosity(types: wp.array3d(dtype=wp.int32), liq_volume: wp.array3d(dtype=float),
                   gas_volume: wp.array3d(dtype=float), two_phase: int, mu_liquid: float, mu_gas: float,
                   mu: wp.array3d(dtype=float)):
    """mu of a fluid cell from the volume each phase holds there; 0 elsewhere. Two viscous phases:
    the volume-weighted harmonic mean (layers in series carry one shear stress). An inviscid phase
    counts as empty space (Batty's volume weights: mu = share of the viscous phase x its mu)."""
    i, j, k = wp.tid()
    m = float(0.0)
    if types[i, j, k] == FLUID:
        m = mu_liquid
        if two_phase != 0:
            vl = liq_volume[i, j, k]
            vg = gas_volume[i, j, k]
            if vl + vg > 0.0:
                if mu_liquid > 0.0 and mu_gas > 0.0:
                    m = (vl + vg) / (vl / mu_liquid + vg / mu_gas)
                else:
                    m = (vl * mu_liquid + vg * mu_gas) / (vl + vg)
    mu[i, j, k] = m


@wp.func
def level(liq_volume: wp.array3d(dtype=float), gas_volume: wp.array3d(dtype=float), c: wp.vec3i):
    """psi = (vl - vg) / (vl + vg): +1 liquid, -1 gas, 0 on the interface."""
    vl = liq_volume[c[0], c[1], c[2]]
    vg = gas_volume[c[0], c[1], c[2]]
    return (vl - vg) / wp.max(vl + vg, 1.0e-30)


@wp.func
def liquid_share(p1: float, p2: float):
    """Share of the segment between two cell centres on the liquid side, psi linear along it."""
    if p1 >= 0.0 and p2 >= 0.0:
        if p1 == 0.0 and p2 == 0.0:
            return 0.5
        return 1.0
    if p1 <= 0.0 and p2 <= 0.0:
        return 0.0
    return wp.max(p1, p2) / (wp.abs(p1) + wp.abs(p2))


@wp.func
def edge_liquid_share(liq_volume: wp.array3d(dtype=float), gas_volume: wp.array3d(dtype=float), e: wp.vec3i,
                      a: int, b: int):
    """Liquid share of the square between the 4 cell centres around edge e (ghost-fluid style): the
    segments' shares across the interface, weighted by how much the interface's normal lies along
    them (psi's gradient), so a layer boundary through a row of centres is placed exactly."""
    p00 = level(liq_volume, gas_volume, e - unit(a) - unit(b))
    p10 = level(liq_volume, gas_volume, e - unit(b))
    p01 = level(liq_volume, gas_volume, e - unit(a))
    p11 = level(liq_volume, gas_volume, e)
    ga = p10 + p11 - p00 - p01
    gb = p01 + p11 - p00 - p10
    share_a = 0.5 * (liquid_share(p00, p10) + liquid_share(p01, p11))  # segments along a
    share_b = 0.5 * (liquid_share(p00, p01) + liquid_share(p10, p11))
    w = ga * ga + gb * gb
    if w > 1.0e-12:
        return (ga * ga * share_a + gb * gb * share_b) / w
    return 0.5 * (share_a + share_b)


@wp.kernel
def edge_viscosity(types: wp.array3d(dtype=wp.int32), mu_cell: wp.array3d(dtype=float),
                   liq_volume: wp.array3d(dtype=float), gas_volume: wp.array3d(dtype=float), two_phase: int,
                   mu_liquid: float, mu_gas: float, a: int, b: int, mu: wp.array3d(dtype=float)):
    """mu on edge e of plane (a, b): 0 beside EMPTY or free-slip cells (or an inviscid one); with four
    fluid cells and two viscous phases, the harmonic mix by the edge's own liquid share (so the
    jump sits where the interface crosses the edge's square); else the harmonic mean of its cells."""
    i, j, k = wp.tid()
    e = wp.vec3i(i, j, k)
    n = int(0)
    inv_sum = float(0.0)
    stress_free = int(0)
    for s in range(4):
        c = e - (s % 2) * unit(a) - (s // 2) * unit(b)
        t = cell_type_at(types, c)
        if t == EMPTY or t == SOLID_FREE_SLIP:
            stress_free = 1
        elif t == FLUID:
            m = mu_cell[c[0], c[1], c[2]]
            if m > 0.0:
                inv_sum += 1.0 / m
                n += 1
            else:
                stress_free = 1  # an inviscid phase carries no shear
    m_e = float(0.0)
    if stress_free == 0 and n > 0:
        m_e = float(n) / inv_sum
        if n == 4 and two_phase != 0 and mu_liquid > 0.0 and mu_gas > 0.0:
            theta = edge_liquid_share(liq_volume, gas_volume, e, a, b)
            m_e = 1.0 / (theta / mu_liquid + (1.0 - theta) / mu_gas)
    mu[i, j, k] = m_e


@wp.func
def normal_stress(mu: wp.array3d(dtype=float), x: wp.array3d(dtype=float), c: wp.vec3i, axis: int, inv_dx: float):
    """tau_aa = 2 mu du_a/dx_a at cell c (0 outside the cells). Computed where a face needs it, twice
    per cell: cheaper on the CPU than a pass that stores it (a launch's per-cell cost is its price)."""
    m = value_at(mu, c)
    t = float(0.0)
    if m > 0.0:
        t = 2.0 * m * (value_at(x, c + unit(axis)) - value_at(x, c)) * inv_dx
    return t


@wp.kernel
def edge_stress(walk: Lines, types: wp.array3d(dtype=wp.int32), mu: wp.array3d(dtype=float), xa: wp.array3d(dtype=float),
                xb: wp.array3d(dtype=float), a: int, b: int, inv_dx: float, tau: wp.array3d(dtype=float)):
    """tau_ab = mu_e (du_a/dx_b + du_b/dx_a) on the edges of plane (a, b)."""
    ti, tj, tk = wp.tid()
    first = line_first(walk, ti, tj, tk)
    s0 = first[walk.axis]
    a1 = int(walk.axis == 1)
    a2 = int(walk.axis == 2)
    for line_s in range(s0, line_end(walk, first)):
        i = first[0]
        j = first[1] + (line_s - s0) * a1
        k = first[2] + (line_s - s0) * a2
        e = wp.vec3i(i, j, k)
        m = mu[i, j, k]
        t = float(0.0)
        if m > 0.0:
            t = m * (difference(xa, types, e, e - unit(b), a) + difference(xb, types, e, e - unit(a), b)) * inv_dx
        tau[i, j, k] = t


@wp.func
def stress_divergence(tau: AroundFace, x: wp.array3d(dtype=float), f: wp.vec3i, a: int, inv_dx: float):
    """(div tau)_a at face f: normal stress from its two cells (tau.cells holds mu there), shear from
    its edges along b1 (and b2)."""
    div = normal_stress(tau.cells, x, f, a, inv_dx) - normal_stress(tau.cells, x, f - unit(a), a, inv_dx)
    div += value_at(tau.edges_1, f + unit(tau.b1)) - value_at(tau.edges_1, f)
    if tau.b2 >= 0:
        div += value_at(tau.edges_2, f + unit(tau.b2)) - value_at(tau.edges_2, f)
    return div * inv_dx


@wp.kernel
def face_operator(walk: Lines, mode: int, a: int, inv_dx: float, dt: float, tau: AroundFace, x: wp.array3d(dtype=float),
                  inv_rho: wp.array3d(dtype=float), out: wp.array3d(dtype=float), dots: wp.array2d(dtype=wp.float64)):
    """On the unknown faces (inv_rho > 0), with K x = -div tau(x) (tau: the shear stresses on the
    edges, and mu at the cells for the normal ones):
    OPERATOR: out = rho x + dt K x (dots[0] += x . out); RHS: out = -dt K x;
    EXPLICIT: out = x - dt/rho K x. Elsewhere out = 0 (EXPLICIT: x, the value is kept)."""
    ti, tj, tk = wp.tid()
    first = line_first(walk, ti, tj, tk)
    s0 = first[walk.axis]
    a1 = int(walk.axis == 1)
    a2 = int(walk.axis == 2)
    acc0 = wp.float64(0.0)
    for line_s in range(s0, line_end(walk, first)):
        i = first[0]
        j = first[1] + (line_s - s0) * a1
        k = first[2] + (line_s - s0) * a2
        f = wp.vec3i(i, j, k)
        ir = inv_rho[i, j, k]
        xf = x[i, j, k]
        if ir == 0.0:
            if mode == EXPLICIT:
                out[i, j, k] = xf
            else:
                out[i, j, k] = 0.0
            continue
        kx = -stress_divergence(tau, x, f, a, inv_dx)
        if mode == OPERATOR:
            y = xf / ir + dt * kx
            out[i, j, k] = y
            acc0 += wp.float64(xf * y)
        elif mode == RHS:
            out[i, j, k] = -dt * kx
        else:
            out[i, j, k] = xf - dt * ir * kx
    wp.atomic_add(dots, first[0], 0, acc0)


@wp.func
def edge_weight(types: wp.array3d(dtype=wp.int32), mu_e: wp.array3d(dtype=float), e: wp.vec3i,
                other: wp.vec3i, a: int):
    """mu_e dx^2 times d(tau_e)/d(u_f) sign-free: doubled where the other face mirrors across a wall."""
    return value_at(mu_e, e) * float(1 + mirrored(types, other, a))


@wp.kernel
def face_diagonal(a: int, inv_dx2: float, dt: float, types: wp.array3d(dtype=wp.int32),
                  inv_rho: wp.array3d(dtype=float), mu: AroundFace, diag: wp.array3d(dtype=float),
                  rate: wp.array(dtype=float)):
    """diag = rho + dt K_ff (the Jacobi preconditioner); rate[0] = max over faces of
    inv_rho * (Gershgorin row sum of K): explicit Euler is stable for dt <= 2 / rate."""
    mu_c = mu.cells
    mu_1 = mu.edges_1
    mu_2 = mu.edges_2
    b1 = mu.b1
    b2 = mu.b2
    i, j, k = wp.tid()
    f = wp.vec3i(i, j, k)
    ir = inv_rho[i, j, k]
    if ir == 0.0:
        diag[i, j, k] = 0.0
        return
    normal = 2.0 * (value_at(mu_c, f) + value_at(mu_c, f - unit(a)))
    shear = edge_weight(types, mu_1, f + unit(b1), f + unit(b1), a) + edge_weight(types, mu_1, f, f - unit(b1), a)
    # Each edge's row entries sum to 4 mu_e: 1 (or 2 mirrored) on the diagonal, 1 (or 0) to the
    # face beyond it, 1 to each of its two crossing faces.
    row = 2.0 * normal + 4.0 * (value_at(mu_1, f + unit(b1)) + value_at(mu_1, f))
    if b2 >= 0:
        shear += edge_weight(types, mu_2, f + unit(b2), f + unit(b2), a) + edge_weight(types, mu_2, f, f - unit(b2), a)
        row += 4.0 * (value_at(mu_2, f + unit(b2)) + value_at(mu_2, f))
    diag[i, j, k] = 1.0 / ir + dt * (normal + shear) * inv_dx2
    wp.atomic_max(rate, 0, ir * row * inv_dx2)


class ViscousSolver(ImplicitSolve):
    """The stress operator on one grid: viscosities, explicit step, implicit PCG (its iteration and
    preconditioners: physics/viscous_iterate.py). Scratch arrays are allocated once; dot products
    accumulate in float64 (deterministic on the CPU)."""

    def __init__(self, grid, device, launch=None, preconditioner: str = "sgs", launch_parts=None, threads: int = 1,
                 parallel=None, counter=None):
        """launch(kernel, shape, inputs): the simulation's, so its launch counter sees these kernels;
        launch_parts(kernel, [(dims, inputs), ...]): its launch of slabs at once on `threads` CPU threads;
        parallel: those threads (core/threads.py); counter: the simulation's launch counter, which the
        replayed launches of the line kernels add to."""
        if preconditioner not in self.PRECONDITIONERS:
            raise ValueError(f"preconditioner {preconditioner!r}: use one of {self.PRECONDITIONERS}")
        self.grid, self.device, self.preconditioner = grid, device, preconditioner
        self._lines = {}  # array shape -> [(Lines, launch dims)], one a slab
        self._launch_parts = launch_parts
        self.threads = threads if launch_parts is not None and wp.get_device(device).is_cpu else 1
        self.sweeps = 1
        self._launcher = launch
        self.dim, self.inv_dx = grid.dim, 1.0 / grid.dx
        cells = grid.cells
        zeros = lambda shape: wp.zeros(shape, dtype=float, device=device)  # noqa: E731
        faces = lambda: [zeros(grid.face_shape(a)) for a in grid.axes]  # noqa: E731
        self.planes = [(a, b) for a in grid.axes for b in grid.axes if a < b]
        edge_shape = lambda a, b: tuple(n + int(i in (a, b)) for i, n in enumerate(cells))  # noqa: E731
        self.mu_cell = zeros(cells)
        self.mu_edge = {p: zeros(edge_shape(*p)) for p in self.planes}
        self.tau_edge = {p: zeros(edge_shape(*p)) for p in self.planes}
        self.r, self.z, self.d, self.Ad, self.diag, self.delta, self.tmp, self.previous = (faces() for _ in range(8))
        # Dot products: each line adds its sum to its plane's row (a plane along x lies in one slab),
        # and the host adds the rows in order, so the sums do not depend on the slabs (core/threads.py).
        self.dots = wp.zeros((max(grid.face_shape(a)[0] for a in grid.axes), 3), dtype=wp.float64, device=device)
        self.rate = wp.zeros(1, dtype=float, device=device)
        # The structs the kernels read (their arrays are allocated once): built once, not per launch.
        self.mu_around = [self._around(a, self.mu_cell, self.mu_edge) for a in grid.axes]
        # The shear stresses on the edges; the normal ones are computed in place from mu at the cells.
        self.tau_around = [self._around(a, self.mu_cell, self.tau_edge) for a in grid.axes]
        self._parallel = parallel or Parallel(self.threads)
        self._counter = counter
        self._recorded = {}  # the line kernels' recorded launches, by kernel, shape and arrays (_walk)
        self.multigrid = None  # one V-cycle per component, allocated on first use
        self.warm_start = True  # start from the last solve's change (physics/viscous_iterate.py)
        self._guess_dt = 0.0  # the dt of the change self.delta holds (0: none)
        self._previous_dt = 0.0  # the dt of the one before it, in self.previous (0: none)

    def _launch(self, kernel, shape, inputs):
        if self._launcher is not None:
            self._launcher(kernel, shape, inputs)
        else:
            wp.launch(kernel, shape, inputs=inputs, device=self.device)

    def _walk(self, kernel, shape, inputs):
        """Launch a kernel that walks an array of `shape` a line per thread (core/lines.py: on the CPU
        a thread's fixed cost exceeds a face's work), its Lines box first; an array of SPLIT_FACES
        or more in slabs along x at once on the CPU's threads (each writes only what it walks)."""
        slabs = self._lines.get(shape)
        if slabs is None:
            box, dims = make_lines((0, 0, 0), shape, self.dim, self.device)
            split = self.threads > 1 and math.prod(shape) >= SPLIT_FACES
            slabs = self._lines[shape] = split_lines(box, dims, self.threads) if split else [(box, dims)]
        if self._counter is None and self._launcher is not None:  # no counter to add replays to
            if len(slabs) == 1:
                self._launch(kernel, slabs[0][1], [slabs[0][0], *inputs])
            else:
                self._launch_parts(kernel, [(dims, [box, *inputs]) for box, dims in slabs])
            return
        self._replay(kernel, shape, slabs, inputs)

    def _replay(self, kernel, shape, slabs, inputs):
        """Launch recorded once per kernel, shape and arrays, its scalars set at each replay: Warp packs
        a launch's arguments in Python (about a quarter of the solve's time on the CPU at 80 x 160
        cells), a replay only the scalars. The slabs run at once on the CPU's threads."""
        key = (kernel.key, shape, *(arg.ptr if isinstance(arg, wp.array) else None if isinstance(arg, (int, float))
                                    else id(arg) for arg in inputs))
        scalars = [(index + 1, arg) for index, arg in enumerate(inputs) if isinstance(arg, (int, float))]
        recorded = self._recorded.get(key)
        if recorded is None:
            if len(self._recorded) > MAX_RECORDED:  # arrays reallocated: forget the old ones
                self._recorded.clear()
            recorded = self._recorded[key] = ([wp.launch(kernel, dims, inputs=[box, *inputs], device=self.device,
                                                         record_cmd=True) for box, dims in slabs], dict(scalars))
        launches, last = recorded
        for index, arg in scalars:  # only those that changed: setting one costs a few microseconds
            if last[index] != arg:
                last[index] = arg
                for launch in launches:
                    launch.set_param_at_index(index, arg)
        if self._counter is not None:
            self._counter[kernel.key] += len(launches)
        if len(launches) == 1:
            launches[0].launch()
        else:
            self._parallel.run([launch.launch for launch in launches])

    def _around(self, a: int, cells, edges: dict) -> AroundFace:
        """The quantity on `cells` and on the edges of the planes through axis a (edges: by plane);
        2D pads the second plane with the first, across axis -1."""
        pairs = [(edges[p], p[1] if p[0] == a else p[0]) for p in self.planes if a in p]
        if len(pairs) == 1:
            pairs.append((pairs[0][0], -1))
        around = AroundFace()
        around.cells = cells
        (around.edges_1, around.b1), (around.edges_2, around.b2) = pairs
        return around

    def set_viscosity(self, types, liq_volume, gas_volume, two_phase: int, mu_liquid: float, mu_gas: float):
        """Cell and edge viscosities from this step's cell types and phase volumes."""
        self._launch(cell_viscosity, self.grid.cells,
                     [types, liq_volume, gas_volume, int(two_phase), float(mu_liquid), float(mu_gas), self.mu_cell])
        for (a, b), mu in self.mu_edge.items():
            self._launch(edge_viscosity, mu.shape, [types, self.mu_cell, liq_volume, gas_volume, int(two_phase),
                                                    float(mu_liquid), float(mu_gas), a, b, mu])

    def prepare(self, types, inv_rho, dt: float) -> float:
        """The Jacobi diagonal for this dt; returns the explicit rate (1/s): stable for dt <= 2/rate."""
        self.rate.zero_()
        inv_dx2 = self.inv_dx * self.inv_dx
        for a in self.grid.axes:
            self._launch(face_diagonal, self.diag[a].shape,
                         [a, inv_dx2, float(dt), types, inv_rho[a], self.mu_around[a], self.diag[a], self.rate])
        return float(self.rate.numpy()[0])

    def _stresses(self, types, x):
        for (a, b), tau in self.tau_edge.items():
            self._walk(edge_stress, tau.shape, [types, self.mu_edge[(a, b)], x[a], x[b], a, b, self.inv_dx, tau])

    def apply(self, mode: int, types, inv_rho, x, dt: float, out) -> float:
        """out = the face operator of `mode` on the face field x; returns x . out (OPERATOR)."""
        self._stresses(types, x)
        self.dots.zero_()
        for a in self.grid.axes:
            self._walk(face_operator, x[a].shape,
                         [mode, a, self.inv_dx, float(dt), self.tau_around[a], x[a], inv_rho[a], out[a], self.dots])
        return float(self._sums()[0]) if mode == OPERATOR else 0.0

    def explicit(self, types, inv_rho, vel, dt: float):
        """vel <- vel + dt/rho div tau(vel) on the unknown faces (forward Euler), in place."""
        self.apply(EXPLICIT, types, inv_rho, vel, dt, self.tmp)
        for a in self.grid.axes:
            wp.copy(vel[a], self.tmp[a])

    def _sums(self):
        """The three dot products: the planes' partial sums added in plane order."""
        return self.dots.numpy().sum(axis=0)
