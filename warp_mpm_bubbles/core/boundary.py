"""Where a moved particle ends up at the domain's walls: clamped inside a closed wall (losing the
velocity that pushed it out), past an open wall LEAVING (booked as outflow, then retired), or, for
liquid past an open top, AIRBORNE in free fall above the domain until it falls back in. Functions
only: they compile into the movers' modules (g2p, the foam and sub-grid bubble movers)."""

import warp as wp

from .geometry import GridGeometry
from .grid import ACTIVE, AIRBORNE, LEAVING, PHASE_LIQUID


FLOAT_MAX = wp.constant(3.4028234663852886e38)  # the largest finite float32


@wp.func
def finite(v: wp.vec3):
    """wp.isfinite(v), inline: |c| <= FLOAT_MAX is false for an infinite and for a NaN component.
    wp.isfinite calls into Warp's runtime library, one call per component (p2g made six a particle
    in each of its parts before it could skip the particle)."""
    return wp.abs(v[0]) <= FLOAT_MAX and wp.abs(v[1]) <= FLOAT_MAX and wp.abs(v[2]) <= FLOAT_MAX


@wp.func
def clamp_to_domain(x: wp.vec3, domain_hi: wp.vec3, dx: float, dim: int):
    """x moved into [eps, size - eps] on the simulated axes, so every stencil lies inside the arrays
    (a particle exactly on the far wall would otherwise reach one node past the ghost layer)."""
    eps = 1.0e-4 * dx
    y = x
    for a in range(3):  # a constant range unrolls; a loop to `dim` kept y on the stack, each read stalled
        if a < dim:
            y[a] = wp.clamp(x[a], eps, domain_hi[a] - eps)
    return y


@wp.func
def wall_stopped(moved: wp.vec3, kept: wp.vec3, vp: wp.vec3, dim: int):
    """The velocity of a particle clamped from `moved` back to `kept`: it loses what pushed it out."""
    out = vp
    for a in range(3):  # unrolled, as in clamp_to_domain
        if a < dim:
            if moved[a] < kept[a]:
                out[a] = wp.max(vp[a], 0.0)
            if moved[a] > kept[a]:
                out[a] = wp.min(vp[a], 0.0)
    return out


@wp.func
def open_wall_exit(moved: wp.vec3, geo: GridGeometry, phase: int):
    """The `active` code of a particle moved to `moved`: ACTIVE inside the domain (or against a
    closed wall, which clamps it); LEAVING past the face of an open wall (its mass is then booked as
    outflow); but AIRBORNE for liquid past an open top, the wall against gravity, which it flies
    above and falls back through (a splash). A particle past two faces leaves unless both are the top."""
    code = int(ACTIVE)
    for a in range(3):  # unrolled, as in clamp_to_domain
        if a >= geo.dim:
            continue
        out_lo = geo.open_lo[a] != 0 and moved[a] < 0.0
        out_hi = geo.open_hi[a] != 0 and moved[a] > geo.domain_hi[a]
        if out_lo or out_hi:
            top = a == geo.up_axis and ((out_hi and geo.up_sign > 0) or (out_lo and geo.up_sign < 0))
            if top and phase == PHASE_LIQUID and code == ACTIVE:
                code = AIRBORNE
            else:
                code = LEAVING
    return code


@wp.func
def fly(x: wp.vec3, v: wp.vec3, geo: GridGeometry, dt: float):
    """One step of free fall for an AIRBORNE particle above the domain: (x, v, its new code)."""
    vn = v + dt * geo.gravity
    moved = x + dt * vn
    code = open_wall_exit(moved, geo, PHASE_LIQUID)  # still above: AIRBORNE; fell back in: ACTIVE
    xn, vc = keep_in_domain(moved, vn, code, geo)
    return xn, vc, code


@wp.func
def keep_in_domain(moved: wp.vec3, vp: wp.vec3, code: int, geo: GridGeometry):
    """Where a particle moved to `moved` with velocity vp stays, and its velocity: clamped into the
    domain, losing what pushed it into a wall; an AIRBORNE one keeps its height above the open top
    (and its speed along it), but stays above the domain, as if the closed walls went on up."""
    xn = clamp_to_domain(moved, geo.domain_hi, geo.dx, geo.dim)
    vn = wall_stopped(moved, xn, vp, geo.dim)
    if code == AIRBORNE:
        xn[geo.up_axis] = moved[geo.up_axis]
        vn[geo.up_axis] = vp[geo.up_axis]
    return xn, vn
