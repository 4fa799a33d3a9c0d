"""Foam at the free surface: gas that reaches open air becomes foam instead of
venting, rides the surface for an exponentially distributed lifetime, then bursts.

Foam particles are the gas particles themselves, relabelled in place (phase PHASE_FOAM, the foam
material as their prototype): ids stay, so a renderer's motion blur follows a bubble from the water
into the foam, and the gas mass moves between the ledgers of `Simulation.gas_budget` without being
copied or rounded. The core transfers skip foam; this stage moves it (diffuse-particle rules after
Ihmsen et al. 2012, with the interpolated liquid fraction phi deciding the regime):

    phi >= AIRBORNE_PHI  on or in the liquid: the interpolated grid velocity (it rides the waves)
                         plus a drift toward the surface phi = SURFACE_PHI, up to `rise_speed`
                         (buoyant when submerged, settling when above)
    phi < AIRBORNE_PHI   no liquid within the stencil: ballistic under gravity

One-way coupled: foam is 1/20 of the water's density and a thin layer, so its weight and drag on
the liquid are left out, and its speed does not enter the CFL limit (it moves kinematically). A
scene with foam therefore simulates its liquid and gas bit for bit as the same scene without it.

Lifetimes: -lifetime * ln(1 - u), u from Warp's PCG hash of (scene seed, particle id): one draw
per particle, the same on every run and device, independent of launch order.
"""

from __future__ import annotations

import math

import warp as wp

from ..core.cells import cell_of, is_solid
from ..core.geometry import GridGeometry
from ..core.grid import PHASE_FOAM, PHASE_GAS, sphere_radius
from ..core.stage import Stage
from ..physics.gas import exposed_to_open_air
from ..scene.effects import Foam
from ..core.boundary import clamp_to_domain, open_wall_exit, wall_stopped
from ..core.transfer_kernels import (
    CELL_OFFSET, grid_coord, interpolate_velocity, make_stencil,
)

wp.set_module_options({"enable_backward": False})

SURFACE_PHI = wp.constant(0.5)  # the surface is where the liquid fraction crosses 1/2
AIRBORNE_PHI = wp.constant(0.05)  # below this the B-spline stencil holds (almost) no liquid


@wp.func
def liquid_fraction(
    liq_volume: wp.array3d(dtype=float), types: wp.array3d(dtype=wp.int32), X: wp.vec3, dim: int,
    inv_cell_vol: float,
):
    """B-spline interpolated liquid rest-volume fraction at grid coordinate X (cell-centred), over
    the cells that are not solid: a wall holds no liquid, but it is not air either (counted, it
    would sink the foam beside a wall by most of a cell)."""
    s = make_stencil(X, dim)
    phi = float(0.0)
    weight = float(0.0)
    for i in range(3):
        for j in range(3):
            for k in range(s.nk):
                n = s.base + wp.vec3i(i, j, k)
                if not is_solid(types[n[0], n[1], n[2]]):
                    w = s.wx[i] * s.wy[j] * s.wz[k]
                    phi += w * liq_volume[n[0], n[1], n[2]]
                    weight += w
    if weight > 0.0:
        phi = phi / weight
    return phi * inv_cell_vol


@wp.kernel
def advance_foam(
    vel_u: wp.array3d(dtype=float),
    vel_v: wp.array3d(dtype=float),
    vel_w: wp.array3d(dtype=float),
    liq_volume: wp.array3d(dtype=float),
    types: wp.array3d(dtype=wp.int32),
    geo: GridGeometry,
    dt: float,
    up: wp.vec3,
    rise_speed: float,
    phase: wp.array(dtype=wp.int32),
    mass: wp.array(dtype=float),
    life: wp.array(dtype=float),
    x: wp.array(dtype=wp.vec3),
    v: wp.array(dtype=wp.vec3),
    active: wp.array(dtype=wp.int32),
    vented_mass: wp.array(dtype=wp.float64),
):
    """Age every foam particle by dt; burst the expired ones (their gas joins the atmosphere's
    ledger); move the others by the regime of the liquid fraction around them."""
    origin = geo.origin
    dx = geo.dx
    dim = geo.dim
    domain_hi = geo.domain_hi
    gravity = geo.gravity
    p = wp.tid()
    if active[p] == 0 or phase[p] != PHASE_FOAM:
        return
    remaining = life[p] - dt
    life[p] = remaining
    if remaining <= 0.0:
        active[p] = 0
        wp.atomic_add(vented_mass, 0, wp.float64(mass[p]))
        return
    xp = clamp_to_domain(x[p], domain_hi, dx, dim)
    inv_dx = 1.0 / dx
    phi = liquid_fraction(liq_volume, types, grid_coord(xp, origin, inv_dx, CELL_OFFSET), dim, inv_dx * inv_dx * inv_dx)
    vp = v[p]
    if phi < AIRBORNE_PHI:
        vp = vp + dt * gravity  # spray: nothing to ride on
    else:
        # Relative to the liquid, foam settles where phi = 1/2: submerged it floats up (buoyant),
        # above the surface it sinks back (heavier than air), the faster the farther away.
        lift = rise_speed * wp.clamp((phi - SURFACE_PHI) / (1.0 - SURFACE_PHI), -1.0, 1.0)
        vp = interpolate_velocity(vel_u, vel_v, vel_w, xp, origin, dx, dim) + lift * up
    moved = xp + dt * vp
    active[p] = open_wall_exit(moved, geo, phase[p])  # LEAVING through an open wall: book_outflow retires it
    xn = clamp_to_domain(moved, domain_hi, dx, dim)
    x[p] = xn
    v[p] = wall_stopped(moved, xn, vp, dim)  # a wall stops the motion into it, as in g2p


@wp.kernel
def gas_to_foam(
    types: wp.array3d(dtype=wp.int32),
    ceiling: wp.array3d(dtype=wp.int32),
    geo: GridGeometry,
    foam_material: int,
    mean_life: float,
    seed: int,
    x: wp.array(dtype=wp.vec3),
    active: wp.array(dtype=wp.int32),
    phase: wp.array(dtype=wp.int32),
    material: wp.array(dtype=wp.int32),
    ids: wp.array(dtype=wp.int64),
    life: wp.array(dtype=float),
):
    """Gas in open air becomes foam (where the vent stage would retire it), with its lifetime."""
    up_axis = geo.up_axis
    up_sign = geo.up_sign
    origin = geo.origin
    dx = geo.dx
    dim = geo.dim
    p = wp.tid()
    if active[p] == 0 or phase[p] != PHASE_GAS:
        return
    if not exposed_to_open_air(types, ceiling, cell_of(x[p], origin, dx), up_axis, up_sign, dim):
        return
    phase[p] = PHASE_FOAM
    material[p] = foam_material
    # A hash of (seed, particle id): no generator state to carry or checkpoint, and the same draw
    # wherever compaction has moved the particle.
    state = wp.rand_init(seed, int(ids[p]))
    life[p] = -mean_life * wp.log(1.0 - wp.randf(state))  # exponential; randf is in [0, 1)


class FoamStage(Stage):
    """[effects.foam]: after g2p, in place of the gas stage's venting (which then does not run)."""

    name = "foam"
    Settings = Foam
    graph_safe = True
    gas_held = ("foam", "in foam")

    def __init__(self, ctx, settings):
        super().__init__(ctx, settings)
        self.material = list(ctx.scene.materials).index(settings.material)
        ctx.particles.add_field("foam_life", float)  # seconds left; checkpointed with the particles
        g = ctx.gravity
        g_mag = math.sqrt(sum(a * a for a in g))
        self._up = wp.vec3(*(-a / g_mag for a in g)) if g_mag > 0.0 else wp.vec3(0.0)
        self._seed = int(ctx.scene.solver.seed) & 0x7FFFFFFF

    def output_radii(self, particles: dict):
        """Foam bubbles are real: written with the radius of their own volume."""
        foam = particles["phase"] == PHASE_FOAM
        return foam, sphere_radius(particles["volume"][foam])

    def after_g2p(self, ctx, dt: float):
        if not ctx.has_gas:
            return  # no gas, nothing ever becomes foam
        f, p = ctx.fields, ctx.particles
        self.advance(ctx, dt)  # foam made this step has moved with the gas in g2p already
        ctx.launch(gas_to_foam, p.count,
                   [f.types, f.ceiling, ctx.geometry, self.material, self.settings.lifetime,
                    self._seed, p.x, p.active, p.phase, p.material, p.ids, p.foam_life])

    def advance(self, ctx, dt: float):
        f, p = ctx.fields, ctx.particles
        ctx.launch(advance_foam, p.count,
                   [*f.vel, f.liq_volume, f.types, ctx.geometry, dt, self._up, self.settings.rise_speed, p.phase, p.mass, p.foam_life, p.x, p.v, p.active,
                    f.vented_mass])
        ctx.book_outflow()  # foam blown through an open wall
