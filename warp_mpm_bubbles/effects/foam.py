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

One-way coupled by default: foam is 1/20 of the water's density and a thin layer, so its weight and
drag on the liquid are left out, and its speed does not enter the CFL limit (it moves kinematically).
A scene with such foam simulates its liquid and gas bit for bit as the same scene without it. With
head = true the foam is a two-way head instead (foam_head.py): it stacks on the water, loads it, and
trades liquid with it.

Lifetimes: -lifetime * ln(1 - u), u from Warp's PCG hash of (scene seed, particle id): one draw
per particle, the same on every run and device, independent of launch order; or, with lifetimes =
"stratified", u from a low-discrepancy (golden-ratio) sequence over the ids, so a head's volume
follows Bikerman's exp(-t / lifetime) without the sampling noise of a few hundred particles.

The films' liquid drains by the foam-drainage equation (foam_drainage.py, docs/foam.md).
"""

from __future__ import annotations

import math

import numpy as np
import warp as wp

from ..core.cells import cell_of, inside, is_solid
from ..core import kernel_args
from ..core.geometry import GridGeometry
from ..core.kernel_args import FaceField, Particles
from ..core.grid import LEAVING, PHASE_FOAM, PHASE_GAS, sphere_radius
from ..core.stage import Stage
from . import foam_drainage, foam_head
from .foam_drainage import (BURST, DRAINED, LEDGER_SIZE, LEFT, LENT, THROUGH_BOTTOM, FoamBook, book_to_column,
                            foam_book)
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
    dt: float,
    rise_speed: float,
    up: wp.vec3,
    geo: GridGeometry,
    vel: FaceField,
    liq_volume: wp.array3d(dtype=float),
    types: wp.array3d(dtype=wp.int32),
    particles: Particles,
    life: wp.array(dtype=float),
    vented_mass: wp.array(dtype=wp.float64),
    liquid: wp.array(dtype=float),
    liquid_ledger: wp.array(dtype=wp.float64),
):
    """Age every foam particle by dt; burst the expired ones (their gas joins the atmosphere's
    ledger, the liquid of their films the liquid ledger's BURST); move the others by the regime of
    the liquid fraction around them."""
    p = wp.tid()
    if particles.active[p] == 0 or particles.phase[p] != PHASE_FOAM:
        return
    remaining = life[p] - dt
    life[p] = remaining
    if remaining <= 0.0:
        particles.active[p] = 0
        wp.atomic_add(vented_mass, 0, wp.float64(particles.mass[p]))
        wp.atomic_add(liquid_ledger, BURST, wp.float64(liquid[p]))
        return
    xp = clamp_to_domain(particles.x[p], geo.domain_hi, geo.dx, geo.dim)
    inv_dx = 1.0 / geo.dx
    phi = liquid_fraction(liq_volume, types, grid_coord(xp, geo.origin, inv_dx, CELL_OFFSET), geo.dim,
                          inv_dx * inv_dx * inv_dx)
    vp = particles.v[p]
    if phi < AIRBORNE_PHI:
        vp = vp + dt * geo.gravity  # spray: nothing to ride on
    else:
        # Relative to the liquid, foam settles where phi = 1/2: submerged it floats up (buoyant),
        # above the surface it sinks back (heavier than air), the faster the farther away.
        lift = rise_speed * wp.clamp((phi - SURFACE_PHI) / (1.0 - SURFACE_PHI), -1.0, 1.0)
        vp = interpolate_velocity(vel, xp, geo.origin, geo.dx, geo.dim) + lift * up
    moved = xp + dt * vp
    # LEAVING through an open wall: book_outflow retires it (its gas), and its films' liquid leaves
    code = open_wall_exit(moved, geo, particles.phase[p])
    if code == LEAVING:
        wp.atomic_add(liquid_ledger, LEFT, wp.float64(liquid[p]))
    particles.active[p] = code
    xn = clamp_to_domain(moved, geo.domain_hi, geo.dx, geo.dim)
    particles.x[p] = xn
    particles.v[p] = wall_stopped(moved, xn, vp, geo.dim)  # a wall stops the motion into it, as in g2p


@wp.func
def weyl_fraction(i: wp.int64):
    """The fractional part of (i + 1/2) / golden ratio, in float64 (exact enough for any id): a
    low-discrepancy sequence, so the lifetimes of any run of ids sample the exponential law evenly
    (its error falls as 1/n instead of 1/sqrt(n))."""
    x = (wp.float64(i) + wp.float64(0.5)) * wp.float64(0.6180339887498949)
    return float(x - wp.floor(x))


@wp.kernel
def gas_to_foam(foam_material: int, mean_life: float, seed: int, geo: GridGeometry, types: wp.array3d(dtype=wp.int32),
                ceiling: wp.array3d(dtype=wp.int32), particles: Particles, book: FoamBook, wet: float,
                stratified: int, surface: wp.array3d(dtype=float), vented_mass: wp.array(dtype=wp.float64)):
    """Gas in open air becomes foam (where the vent stage would retire it), with its lifetime and
    the liquid of its films, wet / (1 - wet) of its gas volume (liquid fraction `wet`), which the
    liquid ledger books as lent by the water (with a head, by its column's water). With a head,
    gas in open air over a column without water (`surface`, foam_head.head_columns) vents as it
    would without foam: there is no water its films could be made of. Made there, their liquid
    was a debt no water could pay, and it came out of nothing as water made where they burst, or
    left the box with them through an open wall."""
    p = wp.tid()
    if particles.active[p] == 0 or particles.phase[p] != PHASE_GAS:
        return
    c = cell_of(particles.x[p], geo.origin, geo.dx)
    if not exposed_to_open_air(types, ceiling, c, geo.up_axis, geo.up_sign, geo.dim):
        return
    if book.head != 0:
        slot = c
        slot[geo.up_axis] = 0
        if not inside(surface, slot) or surface[slot[0], slot[1], slot[2]] <= 0.5 * foam_head.NO_SURFACE:
            particles.active[p] = 0
            wp.atomic_add(vented_mass, 0, wp.float64(particles.mass[p]))
            return
    particles.phase[p] = PHASE_FOAM
    particles.material[p] = foam_material
    # A hash of (seed, particle id): no generator state to carry or checkpoint, and the same draw
    # wherever compaction has moved the particle.
    state = wp.rand_init(seed, int(particles.ids[p]))
    u = wp.randf(state)  # in [0, 1)
    if stratified != 0:
        u = weyl_fraction(particles.ids[p])
    book.life[p] = -mean_life * wp.log(1.0 - u)  # exponential
    held = wet / (1.0 - wet) * particles.vol0[p] * particles.J[p]
    book.liquid[p] = held
    wp.atomic_add(book.ledger, LENT, wp.float64(held))
    book_to_column(book, c, geo.up_axis, -wp.float64(held))


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
        # Liquid volume its films hold (its liquid fraction is foam_liquid / (foam_liquid + volume)).
        ctx.particles.add_field("foam_liquid", float)
        # float64 m^3 of liquid: lent by the water to new films, drained back, lost to bursts (rained
        # back), through the runs' bottoms in the column solve, and carried out through open walls
        # (foam_drainage's indices).
        self.liquid_ledger = wp.zeros(LEDGER_SIZE, dtype=wp.float64, device=ctx.device)
        g = ctx.gravity
        g_mag = math.sqrt(sum(a * a for a in g))
        if settings.drainage:  # the foam's gas and liquid per cell, float64 (two cell arrays)
            shape = ctx.fields.types.shape
            self._gas_cells = wp.zeros(shape, dtype=wp.float64, device=ctx.device)
            self._liquid_cells = wp.zeros(shape, dtype=wp.float64, device=ctx.device)
            self._k1, self._k2 = foam_drainage.drainage_coefficients(
                settings.bubble_radius, self._liquid_density(ctx.scene), g_mag, settings.viscosity,
                settings.surface_tension, settings.permeability_constant)
        self._up = wp.vec3(*(-a / g_mag for a in g)) if g_mag > 0.0 else wp.vec3(0.0)
        self._seed = int(ctx.scene.solver.seed) & 0x7FFFFFFF
        # A two-way head (foam_head.py) owes liquid to its columns' water; without, a stand-in.
        self.head = foam_head.Head(ctx, settings, self._liquid_density(ctx.scene)) if settings.head else None
        self._returned = self.head.cells.returned if self.head else wp.zeros((1, 1, 1), dtype=wp.float64,
                                                                              device=ctx.device)
        self._surface = self.head.cells.surface if self.head else wp.zeros((1, 1, 1), dtype=float, device=ctx.device)

    def hooks(self) -> set[str]:
        hooks = super().hooks()
        if self.head is None:
            hooks.discard("force")  # one-way foam leaves the water alone
        return hooks

    def summary_lines(self, ctx) -> list[str]:
        """A head says which collapse it runs and how tall it stands (one-way foam: nothing)."""
        if self.head is None:
            return []
        s = self.settings
        mode = (f"films burst below a liquid fraction of {s.burst_fraction:g}" if s.collapse == "drainage"
                else f"bubbles burst at drawn lifetimes (mean {s.lifetime:g} s)")
        return [f"  foam: a two-way head, {mode}; it stands {self.head.height() * 1e3:.3g} mm tall on average"]

    def dt_limit(self, ctx) -> float:
        # A head's bubbles settle toward their places at rise_speed x (distance / dx): within a step
        # they must not overshoot them (one-way foam moves kinematically and sets no limit).
        if self.head is None or self.settings.rise_speed <= 0.0:
            return math.inf
        return ctx.grid.dx / self.settings.rise_speed

    def _book(self, ctx) -> FoamBook:
        p = ctx.particles
        return foam_book(p.foam_life, p.foam_liquid, self.liquid_ledger, self._returned, self.head is not None)

    @staticmethod
    def _liquid_density(scene) -> float:
        """The films' liquid: the scene's first liquid material."""
        return next((m.density for m in scene.materials.values() if m.kind == "liquid"), 1000.0)

    def output_radii(self, particles: dict):
        """Foam bubbles are real: written with the radius of their own volume."""
        foam = particles["phase"] == PHASE_FOAM
        return foam, sphere_radius(particles["volume"][foam])

    def force(self, ctx, dt: float):
        self.head.load(ctx)  # the head's weight and drag on the water, before the solve

    def after_g2p(self, ctx, dt: float):
        if not ctx.has_gas:
            return  # no gas, nothing ever becomes foam
        f, p = ctx.fields, ctx.particles
        # foam made this step has moved with the gas in g2p already
        if self.head is not None:
            self.head.advance(ctx, dt, self._book(ctx), f.vented_mass)
        else:
            self.advance(ctx, dt)
        ctx.launch(gas_to_foam, p.count,
                   [self.material, self.settings.lifetime, self._seed, ctx.geometry, f.types, f.ceiling,
                    kernel_args.particle_arrays(p), self._book(ctx), self.settings.liquid_fraction,
                    int(self.settings.lifetimes == "stratified"), self._surface, f.vented_mass])
        if self.settings.drainage and ctx.geometry.up_axis >= 0:
            self.drain(ctx, dt)
        if self.head is not None:
            self.head.return_water(ctx)

    def drain(self, ctx, dt: float):
        """The foam's liquid drains down its columns (foam_drainage); the water is not changed."""
        f, p, geo = ctx.fields, ctx.particles, ctx.geometry
        self._gas_cells.zero_()
        self._liquid_cells.zero_()
        parts = kernel_args.particle_arrays(p)
        ctx.launch(foam_drainage.splat_foam, p.count, [geo, parts, p.foam_liquid, self._gas_cells, self._liquid_cells])
        ctx.launch(foam_drainage.drain_columns, foam_drainage.column_launch_shape(f.types.shape, geo.up_axis),
                   [dt, self._k1, self._k2, geo.dx, geo.up_axis, geo.up_sign, f.types, f.liq_volume,
                    self._gas_cells, self._liquid_cells, self.liquid_ledger, int(self.head is not None)])
        ctx.launch(foam_drainage.gather_foam, p.count,
                   [geo, parts, self._book(ctx), self._gas_cells, self._liquid_cells])

    # The liquid ledger is summed on the device, so it is checkpointed from there (not a HostState).
    def state_arrays(self) -> dict:
        head = self.head.state_arrays() if self.head is not None else {}
        return {"foam_liquid_ledger": self.liquid_ledger.numpy().copy(), **head}

    def load_state(self, arrays: dict) -> None:
        if "foam_liquid_ledger" in arrays:
            ledger = np.zeros(LEDGER_SIZE, np.float64)  # a checkpoint from before LEFT has 4 entries
            saved_ledger = np.asarray(arrays["foam_liquid_ledger"], np.float64)
            ledger[:len(saved_ledger)] = saved_ledger
            self.liquid_ledger.assign(wp.array(ledger, dtype=wp.float64, device=self.liquid_ledger.device))
        if self.head is not None:
            self.head.load_state(arrays)

    def liquid_budget(self, ctx) -> dict[str, float]:
        """The films' liquid, m^3: lent by the water, held now, drained back, burst, left (in foam
        gone through an open wall); balanced, lent = held + drained + burst + left to float64
        round-off."""
        n = ctx.particles.count
        phase, active = ctx.particles.numpy("phase")[:n], ctx.particles.numpy("active")[:n]
        held = ctx.particles.numpy("foam_liquid")[:n][(phase == PHASE_FOAM) & (active != 0)]
        ledger = self.liquid_ledger.numpy()
        budget = {"lent": float(ledger[LENT]), "held": float(held.astype("float64").sum()),
                  "drained": float(ledger[DRAINED]), "burst": float(ledger[BURST]),
                  "through_bottom": float(ledger[THROUGH_BOTTOM]), "left": float(ledger[LEFT])}
        if self.head is not None:  # made into water particles, and still owed to the water
            budget["water_made"] = self.head.state.water_made * self.head.particle_volume
            budget["owed"] = self.head.owed()
        return budget

    def advance(self, ctx, dt: float):
        f, p = ctx.fields, ctx.particles
        ctx.launch(advance_foam, p.count,
                   [dt, self.settings.rise_speed, self._up, ctx.geometry, kernel_args.face_field(f.vel), f.liq_volume,
                    f.types, kernel_args.particle_arrays(p), p.foam_life, f.vented_mass, p.foam_liquid,
                    self.liquid_ledger])
        ctx.book_outflow()  # foam blown through an open wall
