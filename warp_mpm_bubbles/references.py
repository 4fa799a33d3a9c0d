"""Analytic references the simulator is checked against, in the package so that an installed copy
can check its own physics (`warp-mpm-bubbles validate`) and the tests and benchmarks share one copy:
the Rayleigh-Plesset radius of a bubble (3D) or of a cylinder in a free liquid annulus (2D), by RK4.
"""

from __future__ import annotations

import math

import numpy as np

# Reference radius of an isothermal gas bubble in an inviscid liquid, by RK4 (docs/design.md#rayleigh-plesset).
#
# Units R0 = 1, rho_liquid = 1, p_inf = 1: time in R0 sqrt(rho/p_inf). No surface tension, no viscosity,
# gas p_g = p_g0 (R0/R)^d. The equations are those in the header of
# tests/data/rayleigh_plesset_isothermal_collapse_reference.csv:
#
#     3D: R R'' + 1.5 R'^2 = p_g - p_inf
#     2D: (R R'' + R'^2) ln(Rout/R) + 0.5 R'^2 (R^2/Rout^2 - 1) = p_g - p_inf,  Rout^2 = Rout0^2 + R^2 - R0^2
#
# (the 2D one: a planar bubble in a liquid annulus whose outer surface, radius Rout, is free at p_inf).


def acceleration(R: float, Rd: float, p_g0: float, dim: int, r_out0: float | None) -> float:
    p_g = p_g0 * R ** (-dim)
    if dim == 3:
        return (p_g - 1.0 - 1.5 * Rd * Rd) / R
    r_out = math.sqrt(r_out0 * r_out0 + R * R - 1.0)
    return ((p_g - 1.0) - 0.5 * Rd * Rd * (R * R / (r_out * r_out) - 1.0)) / (R * math.log(r_out / R)) - Rd * Rd / R


def radius_history(p_g0: float, dim: int, r_out0: float | None = None, t_end: float = 3.0,
                   dt: float = 1e-3) -> tuple[np.ndarray, np.ndarray]:
    """R(t) from rest at R = 1, classical RK4 with a fixed step (1e-3 matches the reference table to
    its 6 decimals; the bounce at the minimum is about 0.04 wide)."""
    n = int(round(t_end / dt))
    t = np.arange(n + 1) * dt
    R = np.empty(n + 1)
    r, v = 1.0, 0.0
    a = lambda r, v: acceleration(r, v, p_g0, dim, r_out0)  # noqa: E731
    R[0] = r
    for i in range(n):
        k1r, k1v = v, a(r, v)
        k2r, k2v = v + 0.5 * dt * k1v, a(r + 0.5 * dt * k1r, v + 0.5 * dt * k1v)
        k3r, k3v = v + 0.5 * dt * k2v, a(r + 0.5 * dt * k2r, v + 0.5 * dt * k2v)
        k4r, k4v = v + dt * k3v, a(r + dt * k3r, v + dt * k3v)
        r += dt / 6.0 * (k1r + 2 * k2r + 2 * k3r + k4r)
        v += dt / 6.0 * (k1v + 2 * k2v + 2 * k3v + k4v)
        R[i + 1] = r
    return t, R


def first_minimum(t: np.ndarray, R: np.ndarray) -> tuple[float, float]:
    """Time and radius of the first local minimum of sampled R(t), refined by a parabola through
    the lowest sample and its two neighbours."""
    i = next(i for i in range(1, len(R) - 1) if R[i] <= R[i - 1] and R[i] < R[i + 1])
    (t0, t1, t2), (r0, r1, r2) = t[i - 1:i + 2], R[i - 1:i + 2]
    a, b, c = np.polyfit([t0 - t1, 0.0, t2 - t1], [r0, r1, r2], 2)
    if a <= 0.0:
        return float(t1), float(r1)
    s = -b / (2 * a)
    return float(t1 + s), float(c - b * b / (4 * a))


# The near-vacuum cavity (2D): an empty cylinder R0 in a water annulus R_OUT0 R0 across, free at p_inf;
# no closed form exists in 2D (the energy holds ln(Rout/R)), so reference_times integrates it.
P_ATM = 101325.0
RHO = 1000.0
R0 = 0.01  # m
R_OUT0 = 3.0  # outer radius of the annulus, in R0
P_G0 = 1.0 / P_ATM  # gas at 1 Pa absolute: gauge -101324 Pa
T_UNIT = R0 * math.sqrt(RHO / P_ATM)  # s


def reference_times(radii=(0.5, 0.25), p_g0=P_G0, r_out0=R_OUT0, dt=1e-4) -> dict[float, float]:
    """t / T_UNIT at which the 2D Rayleigh-Plesset radius first falls to each of `radii` (in R0):
    RK4 from rest at R0 (the Rayleigh-Plesset section's equation), stopped at the smallest radius."""
    f = lambda r, v: acceleration(r, v, p_g0, 2, r_out0)  # noqa: E731
    t, r, v, out = 0.0, 1.0, 0.0, {}
    for target in sorted(radii, reverse=True):
        while r > target:
            k1r, k1v = v, f(r, v)
            k2r, k2v = v + 0.5 * dt * k1v, f(r + 0.5 * dt * k1r, v + 0.5 * dt * k1v)
            k3r, k3v = v + 0.5 * dt * k2v, f(r + 0.5 * dt * k2r, v + 0.5 * dt * k2v)
            k4r, k4v = v + dt * k3v, f(r + dt * k3r, v + dt * k3v)
            r_new = r + dt / 6.0 * (k1r + 2 * k2r + 2 * k3r + k4r)
            v += dt / 6.0 * (k1v + 2 * k2v + 2 * k3v + k4v)
            if r_new <= target:
                out[target] = t + dt * (r - target) / (r - r_new)
            t, r = t + dt, r_new
    return out
