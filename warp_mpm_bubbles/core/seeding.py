"""Particle seeding: jittered stratified samples in every grid cell, kept where a shape covers them.

Samples are generated one x-slab of cells at a time, each slab with its own
generator seeded with (solver.seed, slab index). Any slab can therefore be
regenerated on its own: scene validation uses that to check cheaply that a
shape receives particles, with exactly the samples the full seeding produces.

`domain` and `scene` are scene.model.Domain and Scene (not imported: the scene imports this module).
"""
from __future__ import annotations

import math

import numpy as np


def sub_cells_per_axis(ppc: int, dim: int) -> int:
    """Smallest k with k**dim >= ppc (integer arithmetic: 27**(1/3) > 3 in floating point)."""
    k = 1
    while k**dim < ppc:
        k += 1
    return k


def slab_samples(domain, ppc: int, seed: int, ix: int) -> np.ndarray:
    """Sample positions (M, dim) float64 for the cells with x index `ix`, cell-major order."""
    dim, h = domain.dim, domain.dx
    k = sub_cells_per_axis(ppc, dim)
    rest = np.indices(domain.cells[1:dim]).reshape(dim - 1, -1).T  # (n, dim-1) y[, z] indices
    cell = np.column_stack([np.full(len(rest), ix), rest])  # (n, dim)
    rng = np.random.default_rng([seed, ix])
    # argsort of uniform keys = an independent random permutation of the k**dim sub-cells per cell
    chosen = np.argsort(rng.random((len(cell), k**dim)), axis=1)[:, :ppc]
    sub = np.stack([chosen // k**a % k for a in range(dim)], axis=-1)  # (n, ppc, dim)
    jitter = rng.random(sub.shape)
    return ((cell[:, None, :] + (sub + jitter) / k) * h).reshape(-1, dim)


def _slabs_overlapping(lo_x: float, hi_x: float, domain) -> range:
    nx, h = domain.cells[0], domain.dx
    return range(max(0, math.floor(lo_x / h)), min(nx, math.floor(hi_x / h) + 1))


def shape_seeds_particles(shape, domain, ppc: int, seed: int) -> bool:
    """Whether `shape` contains at least one sample (ignoring later shapes overwriting it)."""
    lo, hi = shape.bounds()
    return any(shape.contains(slab_samples(domain, ppc, seed, ix)).any()
               for ix in _slabs_overlapping(lo[0], hi[0], domain))


def seed_particles(scene) -> dict[str, np.ndarray]:
    """Seed the scene's shapes with particles.

    Returns positions (N,3) float32 (2D: z = 0.5*dx), velocities (N,3) float32,
    material (N,) int32 (index into list(scene.materials)), volume (N,) float32 and the initial
    gauge pressure (N,) float32 of gas shapes.
    Each sample takes the material and velocity of the LAST shape containing it.
    """
    scene.validate()
    domain, solver = scene.domain, scene.solver
    dim, h, ppc = domain.dim, domain.dx, solver.particles_per_cell
    names = list(scene.materials)
    material_of = np.array([names.index(s.material) for s in scene.shapes], np.int32)
    velocity_of = np.zeros((len(scene.shapes), 3), np.float32)
    velocity_of[:, :dim] = [s.velocity for s in scene.shapes]
    pressure_of = np.array([s.pressure or 0.0 for s in scene.shapes], np.float32)

    # Slabs no shape reaches hold no particles; skipping them changes nothing (per-slab generators).
    bounds = [s.bounds() for s in scene.shapes]
    slabs = _slabs_overlapping(min(b[0][0] for b in bounds), max(b[1][0] for b in bounds), domain)

    pos_parts, owner_parts = [], []
    for ix in slabs:
        p = slab_samples(domain, ppc, solver.seed, ix)
        owner = np.full(len(p), -1, np.int32)  # index of the last shape containing each sample
        for i, shape in enumerate(scene.shapes):
            owner = np.where(shape.contains(p), np.int32(i), owner)
        keep = owner >= 0
        pos_parts.append(p[keep].astype(np.float32))
        owner_parts.append(owner[keep])

    owner = np.concatenate(owner_parts) if owner_parts else np.zeros(0, np.int32)
    n = len(owner)
    positions = np.zeros((n, 3), np.float32)
    if n:
        positions[:, :dim] = np.concatenate(pos_parts)
    if dim == 2:
        positions[:, 2] = 0.5 * h  # the 2D run is a slab one cell thick
    return {
        "positions": positions,
        "velocities": velocity_of[owner],
        "material": material_of[owner],
        "pressure": pressure_of[owner],  # initial gauge pressure (gas shapes; 0 elsewhere)
        # 2D too: each particle stands for a share of a dx**3 cell of the one-cell-thick slab
        "volume": np.full(n, h**3 / ppc, np.float32),
    }
