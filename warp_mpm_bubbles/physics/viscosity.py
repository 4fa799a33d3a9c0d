"""Viscosity (docs/design.md, "Viscosity"): runs when any material has viscosity > 0.

    force     explicit diffusion of u*, u += dt nu lap(u), nu of the phase beside each face
    dt_limit  explicit diffusion's stability: dt <= dx^2 / (2 dim nu)

nu is the largest kinematic viscosity of each phase's materials.
"""

import warp as wp

from ..core.grid import SOLID_NO_SLIP
from ..core.grid_kernels import cell_type_at, is_liquid_cell, is_solid, unit
from ..core.stage import Stage

wp.set_module_options({"enable_backward": False})


@wp.kernel
def diffuse_velocity(
    types: wp.array3d(dtype=wp.int32),
    phase: wp.array3d(dtype=wp.int32),
    inv_rho: wp.array3d(dtype=float),
    vel: wp.array3d(dtype=float),
    nu_liquid: float,
    nu_gas: float,
    axis: int,
    dim: int,
    dx: float,
    dt: float,
    out: wp.array3d(dtype=float),
):
    """Explicit viscosity: u += dt nu lap(u) on the faces the pressure acts on, nu of the phase beside
    the face (the liquid's if either side is liquid).

    A neighbour face outside the material contributes nothing (zero gradient: a stress-free
    surface or a free-slip wall); a tangential neighbour inside a no-slip wall is taken as -u, so
    the velocity is zero on the wall.
    """
    i, j, k = wp.tid()
    u = vel[i, j, k]
    out[i, j, k] = u
    if inv_rho[i, j, k] == 0.0:
        return
    hi = wp.vec3i(i, j, k)
    lo = hi - unit(axis)
    nu = nu_gas
    if is_liquid_cell(types, phase, lo) or is_liquid_cell(types, phase, hi):
        nu = nu_liquid
    lap = float(0.0)
    for a in range(dim):
        for s in range(2):
            n = hi + (2 * s - 1) * unit(a)
            if n[0] < 0 or n[1] < 0 or n[2] < 0 or n[0] >= vel.shape[0] or n[1] >= vel.shape[1] or n[2] >= vel.shape[2]:
                continue
            t_a = cell_type_at(types, n - unit(axis))
            t_b = cell_type_at(types, n)
            if inv_rho[n[0], n[1], n[2]] > 0.0:
                lap += vel[n[0], n[1], n[2]] - u
            elif a == axis and (is_solid(t_a) or is_solid(t_b)):
                lap += vel[n[0], n[1], n[2]] - u  # the wall's normal face: the wall's velocity, 0
            elif a != axis and (t_a == SOLID_NO_SLIP or t_b == SOLID_NO_SLIP):
                lap += -2.0 * u  # mirrored across a no-slip wall half a cell away
    out[i, j, k] = u + dt * nu * lap / (dx * dx)


class ViscosityStage(Stage):
    name = "viscosity"
    limit = "viscous"

    def __init__(self, sim, settings=None):
        super().__init__(sim, settings)
        materials = sim.scene.materials.values()
        nu = lambda ms: max((m.viscosity / m.density for m in ms), default=0.0)  # noqa: E731
        self.nu_liquid = nu([m for m in materials if m.kind == "liquid"])
        self.nu_gas = nu([m for m in materials if m.is_gas])

    def dt_limit(self, sim) -> float:
        return sim.grid.dx**2 / (2 * sim.grid.dim * max(self.nu_liquid, self.nu_gas))

    def force(self, sim, dt: float):
        g, f = sim.grid, sim.fields
        for a in g.axes:
            sim.launch(diffuse_velocity, g.face_shape(a),
                       [f.types, f.phase_cells, f.inv_rho[a], f.vel[a], self.nu_liquid, self.nu_gas, a, g.dim, g.dx,
                        dt, f.vel_tmp[a]])
            f.vel[a], f.vel_tmp[a] = f.vel_tmp[a], f.vel[a]
