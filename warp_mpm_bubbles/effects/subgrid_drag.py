"""The sub-grid bubbles' drag (effects/subgrid.py): Schiller-Naumann's law, the implicit relative
speed it gives in one step, and the reaction's spreading over the faces the bubble's B-spline
touches, in proportion to the fluid mass each holds. Functions only: they compile into the kernels of
effects/subgrid.py that call them.

The bubble's side is implicit: w_new solves w (m + dt k(|w|)) = m (v - u_l) + dt F_b, bisected. The
fluid takes the reaction explicitly (next step, deposit_drag_reaction), and an explicit drag moves a
mass M by dt k / M of the relative velocity: beyond 1 it drags the fluid past the bubble, without
bound as M -> 0. So dt k is capped at M, the fluid mass the bubble's stencil holds (face_fluid_mass).
In the liquid M ~ rho_l dx^3 >> dt k (1e-5 against 1e-8 kg for the pour's bubbles) and the cap never
acts; it acts where the stencil holds next to no fluid (a bubble in a resolved bubble's particle-free
gap), where the bubble then keeps its momentum instead of throwing a few picograms of gas at 3e8 m/s
(the pour's frame 38, before the cap).
"""

from __future__ import annotations

import math

import warp as wp

from ..core.kernel_args import FaceField
from ..core.transfer_kernels import U_OFFSET, V_OFFSET, W_OFFSET, grid_coord, make_stencil

wp.set_module_options({"enable_backward": False})

ADDED_MASS = wp.constant(0.5)  # added-mass coefficient of a sphere
RE_NEWTON = wp.constant(1000.0)  # Schiller-Naumann's upper end, where C_D levels off at 0.44
CD_NEWTON = wp.constant(0.44)
BISECTION_STEPS = wp.constant(40)  # float32 interval [0, b/m] halves to its last bit in ~25
PI = wp.constant(math.pi)


@wp.func
def drag_per_speed(s: float, r: float, rho_l: float, mu: float):
    """k(s) with |drag| = k(s) s at relative speed s; C_D s stays finite as s -> 0 (Stokes)."""
    re = rho_l * s * 2.0 * r / mu
    cd_s = CD_NEWTON * s
    if re < RE_NEWTON:
        cd_s = 24.0 * mu / (rho_l * 2.0 * r) * (1.0 + 0.15 * wp.pow(re, 0.687))
    return 0.5 * rho_l * cd_s * PI * r * r


@wp.func
def drag_impulse_per_speed(s: float, dt: float, r: float, rho_l: float, mu: float, fluid_mass: float):
    """The step's drag impulse per unit relative speed, dt k(s), at most the fluid mass the bubble's
    stencil holds: the fluid takes the reaction explicitly (next step, deposit_drag_reaction), and an
    explicit drag on a mass M moves it by dt k / M of the relative velocity, so dt k <= M is what keeps
    the fluid from being dragged past the bubble (see advance_subgrid)."""
    return wp.min(dt * drag_per_speed(s, r, rho_l, mu), fluid_mass)


@wp.func
def implicit_relative_speed(b: float, m: float, dt: float, r: float, rho_l: float, mu: float, fluid_mass: float):
    """s >= 0 with s (m + c(s)) = b, c = drag_impulse_per_speed; s (m + c(s)) increases with s (c is
    non-decreasing), so bisect on [0, b/m]."""
    lo = float(0.0)
    hi = b / m
    for _ in range(BISECTION_STEPS):
        mid = 0.5 * (lo + hi)
        if mid * (m + drag_impulse_per_speed(mid, dt, r, rho_l, mu, fluid_mass)) > b:
            hi = mid
        else:
            lo = mid
    return 0.5 * (lo + hi)


@wp.func
def stencil_mass(mass: wp.array3d(dtype=float), X: wp.vec3, dim: int):
    """M = sum_i w_i m_i: the fluid mass the B-spline at X sees on one face grid."""
    s = make_stencil(X, dim)
    total = float(0.0)
    for i in range(3):
        for j in range(3):
            for k in range(s.nk):
                total += s.wx[i] * s.wy[j] * s.wz[k] * mass[s.base[0] + i, s.base[1] + j, s.base[2] + k]
    return total


@wp.func
def face_fluid_mass(face_mass: FaceField, xp: wp.vec3, origin: wp.vec3, dx: float, dim: int):
    """The fluid mass a bubble at xp drags (this step's face masses): the smallest stencil_mass over
    the face grids, the most the drag's dt k may be (advance_subgrid)."""
    inv_dx = 1.0 / dx
    m = wp.min(stencil_mass(face_mass.u, grid_coord(xp, origin, inv_dx, U_OFFSET), dim),
               stencil_mass(face_mass.v, grid_coord(xp, origin, inv_dx, V_OFFSET), dim))
    if dim == 3:
        m = wp.min(m, stencil_mass(face_mass.w, grid_coord(xp, origin, inv_dx, W_OFFSET), dim))
    return m


@wp.func
def add_face_impulse(
    vel: wp.array3d(dtype=float), mass: wp.array3d(dtype=float), X: wp.vec3, dim: int, impulse: float
):
    """Spread one impulse component J over the faces the B-spline touches, in proportion to the mass
    each holds there: node i gains w_i J / M, M = sum_j w_j m_j (stencil_mass). The nodes' momenta
    sum to J exactly, and none changes by more than J / M, the whole stencil's share. (It was
    w_i J / m_i: exact too, but a face holding only a gas particle's B-spline tail, 5e-14 kg in the
    pour's bubble gap, took 3e8 m/s from a 3.5e-5 kg m/s impulse.)"""
    total = stencil_mass(mass, X, dim)
    if total <= 0.0:
        return
    s = make_stencil(X, dim)
    for i in range(3):
        for j in range(3):
            for k in range(s.nk):
                n = s.base + wp.vec3i(i, j, k)
                if mass[n[0], n[1], n[2]] > 0.0:
                    wp.atomic_add(vel, n[0], n[1], n[2], s.wx[i] * s.wy[j] * s.wz[k] * impulse / total)
