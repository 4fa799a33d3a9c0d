"""The liquid's surface as a triangle mesh, built on the Warp device from the liquid particles.

Field: a smoothed liquid volume fraction f(x) = sum_i V_i W(|x - x_i|, R) over the liquid particles
(phase == PHASE_LIQUID; foam, sub-grid bubbles and gas stay particles), W the normalised poly6 kernel
of radius R = smoothing * dx (default 1.25: at 1.0 the randomly seeded particles leave f < 0.5 in
spots inside the water, spurious voids that come and go between frames). Inside the liquid f ~ 1, in gas or air f = 0, and its 0.5 contour
sits where the particles' volume ends: the enclosed volume matches the particles' volume, and a
resolved bubble (gas particles, no liquid) is a hole with its own inner wall. This is a colour
function rather than Zhu & Bridson's distance, chosen because its 0.5 crossing conserves volume
without a per-scene radius calibration.

Walls: particles within R of a domain wall are mirrored across it, so f stays ~1 up to the wall, and
the grid has one layer of nodes outside the domain whose value is min(1 - f_inside, 0.25): the 0.5
crossing then falls on the wall itself (exactly where f_inside >= 0.75) and the mesh is closed where
the water touches a wall. Nodes sit at cell centres of a grid `resolution` times finer than the
simulation's, so the wall lies halfway between the last inside and the first outside node.

2D runs are a slab one cell thick (z in [0, dx]): the 2D field is extruded through the slab, so the
mesh is a closed prism whose volume / dx is the liquid's area. Colliders are not carved: the mesh
is closed against them, but water beside a collider keeps the kernel's half-width gap.

Marching cubes: Warp's ``wp.geometry.IsoSurfaceMarchingCubes`` (vertices shared between cells).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import warp as wp

THRESHOLD = 0.5
_NUDGE = 1e-4  # keeps nodes off the threshold: a vertex exactly on a node makes a zero-area face
THRESHOLD_C = wp.constant(THRESHOLD)
NUDGE_C = wp.constant(_NUDGE)


@dataclass
class SurfaceMesh:
    points: np.ndarray  # (V, 3) float32, metres
    indices: np.ndarray  # (F, 3) int32, counter-clockwise seen from outside the liquid
    normals: np.ndarray  # (V, 3) float32, unit, pointing out of the liquid

    @property
    def extent(self) -> np.ndarray:
        if not len(self.points):
            return np.zeros((2, 3), np.float32)
        return np.stack([self.points.min(axis=0), self.points.max(axis=0)]).astype(np.float32)

    def volume(self) -> float:
        """Enclosed volume (divergence theorem); > 0 for outward-facing triangles."""
        p = self.points.astype(np.float64)[self.indices]
        return float(np.einsum("ij,ij->i", p[:, 0], np.cross(p[:, 1], p[:, 2])).sum() / 6.0)

    def face_areas(self) -> np.ndarray:
        p = self.points.astype(np.float64)[self.indices]
        return 0.5 * np.linalg.norm(np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]), axis=1)

    def edge_face_counts(self) -> np.ndarray:
        """How many faces share each distinct edge (2 everywhere for a closed manifold mesh)."""
        e = np.concatenate([self.indices[:, [0, 1]], self.indices[:, [1, 2]], self.indices[:, [2, 0]]])
        e = np.sort(e, axis=1).astype(np.int64)
        _, counts = np.unique(e[:, 0] * (len(self.points) + 1) + e[:, 1], return_counts=True)
        return counts


@wp.func
def _kernel_weight(d2: float, r: float, norm: float):
    s = 1.0 - d2 / (r * r)
    if s <= 0.0:
        return 0.0
    return norm * s * s * s


@wp.kernel
def _splat(x: wp.array(dtype=wp.vec3), vol: wp.array(dtype=float), hi: wp.vec3, dim: int, h: float,
           pad: int, n_in: wp.vec3i, r: float, norm: float, field: wp.array3d(dtype=float)):
    """Scatter each particle and its mirror images across nearby walls onto the inside nodes."""
    p = wp.tid()
    xp = x[p]
    for combo in range(27):  # per axis: 0 itself, 1 mirrored at the low wall, 2 at the high wall
        img = wp.vec3(xp[0], xp[1], xp[2])
        ok = True
        rest = combo
        for a in range(3):
            m = rest % 3
            rest = rest // 3
            if m != 0 and (a >= dim or (m == 1 and xp[a] >= r) or (m == 2 and xp[a] <= hi[a] - r)):
                ok = False
            if m == 1:
                img[a] = -xp[a]
            elif m == 2:
                img[a] = 2.0 * hi[a] - xp[a]
        if ok:
            lo_i = wp.vec3i(0)
            hi_i = wp.vec3i(0)
            for a in range(3):  # node i sits at (i - pad + 0.5) h
                lo_i[a] = wp.max(pad, int(wp.ceil((img[a] - r) / h + float(pad) - 0.5)))
                hi_i[a] = wp.min(pad + n_in[a] - 1, int(wp.floor((img[a] + r) / h + float(pad) - 0.5)))
            if dim == 2:  # the slab's field does not depend on z: one layer, extruded later
                lo_i[2] = pad
                hi_i[2] = pad
            for i in range(lo_i[0], hi_i[0] + 1):
                for j in range(lo_i[1], hi_i[1] + 1):
                    for k in range(lo_i[2], hi_i[2] + 1):
                        node = wp.vec3((float(i - pad) + 0.5) * h, (float(j - pad) + 0.5) * h,
                                       (float(k - pad) + 0.5) * h)
                        d = node - img
                        if dim == 2:
                            d[2] = 0.0
                        w = _kernel_weight(wp.dot(d, d), r, norm)
                        if w > 0.0:
                            wp.atomic_add(field, i, j, k, w * vol[p])


@wp.kernel
def _close(raw: wp.array3d(dtype=float), dim: int, pad: int, n_in: wp.vec3i, out: wp.array3d(dtype=float)):
    """Inside nodes keep f (2D: the slab's one layer); outside nodes get min(1 - f_inside, 0.25)."""
    i, j, k = wp.tid()
    c = wp.vec3i(wp.clamp(i, pad, pad + n_in[0] - 1), wp.clamp(j, pad, pad + n_in[1] - 1),
                 wp.clamp(k, pad, pad + n_in[2] - 1))
    if dim == 2:
        c[2] = pad
    f = raw[c[0], c[1], c[2]]
    if i != c[0] or j != c[1] or (k < pad or k >= pad + n_in[2]):
        f = wp.min(1.0 - f, 0.25)
    if wp.abs(f - THRESHOLD_C) < NUDGE_C:
        f = THRESHOLD_C + wp.where(f < THRESHOLD_C, -NUDGE_C, NUDGE_C)
    out[i, j, k] = f


class SurfaceBuilder:
    """Builds the mesh of one frame; reuse it across frames (the field arrays are kept)."""

    def __init__(self, dim: int, dx: float, cells, resolution: int = 2, smoothing: float = 1.25, device=None):
        if dim not in (2, 3):
            raise ValueError(f"dim must be 2 or 3, got {dim}")
        if int(resolution) != resolution or resolution < 1:
            raise ValueError(f"resolution must be a whole number >= 1, got {resolution}")
        if not smoothing > 0:
            raise ValueError(f"smoothing must be > 0, got {smoothing}")
        self.dim, self.dx, self.res = dim, float(dx), int(resolution)
        self.h = self.dx / self.res
        self.radius = float(smoothing) * self.dx
        self.pad = 1  # one node layer beyond each wall closes the mesh there
        cells = tuple(int(n) for n in cells)[:3] + (1,) * (3 - len(cells))
        self.n_in = tuple(n * self.res for n in cells[:dim]) + ((self.res,) if dim == 2 else ())
        self.hi = tuple(n * self.dx for n in cells[:dim]) + ((self.dx,) if dim == 2 else ())
        self.shape = tuple(n + 2 * self.pad for n in self.n_in)
        self.norm = (315.0 / (64.0 * np.pi * self.radius**3) if dim == 3
                     else 4.0 / (np.pi * self.radius**2))  # integral of W = 1 (2D: over the plane)
        self.device = wp.get_device(device)
        self._raw = wp.zeros(self.shape, dtype=float, device=self.device)
        self._field = wp.zeros(self.shape, dtype=float, device=self.device)

    def field(self, positions: np.ndarray, volumes: np.ndarray) -> wp.array:
        """The closed volume-fraction field on the padded node grid (a device array)."""
        pos = np.ascontiguousarray(positions, np.float32).reshape(-1, 3)
        vol = np.ascontiguousarray(volumes, np.float32).reshape(-1)
        if self.dim == 2:
            vol = vol / np.float32(self.dx)  # a 2D particle's volume is its area times the slab
        self._raw.zero_()
        if len(pos):
            x = wp.array(pos, dtype=wp.vec3, device=self.device)
            v = wp.array(vol, dtype=float, device=self.device)
            wp.launch(_splat, dim=len(pos), device=self.device,
                      inputs=[x, v, wp.vec3(*self.hi), self.dim, self.h, self.pad, wp.vec3i(*self.n_in),
                              self.radius, float(self.norm), self._raw])
        wp.launch(_close, dim=self.shape, device=self.device,
                  inputs=[self._raw, self.dim, self.pad, wp.vec3i(*self.n_in), self._field])
        return self._field

    def build(self, positions: np.ndarray, volumes: np.ndarray) -> SurfaceMesh:
        """Mesh of the 0.5 contour of the field of these (liquid) particles."""
        field = self.field(positions, volumes)
        verts, tris = _marching_cubes(field, THRESHOLD)
        if verts is None or not len(verts):
            return _empty()
        idx = (verts.numpy().astype(np.float64) - self.pad + 0.5) * self.h  # node index -> metres
        faces = tris.numpy().reshape(-1, 3).astype(np.int32)
        mesh = SurfaceMesh(idx.astype(np.float32), faces, np.zeros((len(idx), 3), np.float32))
        if mesh.volume() < 0:  # Warp's winding faces into the >= threshold side: turn it outward
            mesh.indices = np.ascontiguousarray(mesh.indices[:, ::-1])
        mesh.normals = _vertex_normals(mesh.points, mesh.indices)
        return mesh


def liquid_surface(builder: SurfaceBuilder, particles: dict) -> SurfaceMesh:
    """The mesh of the liquid particles in a sim.particles_numpy() dict (phase == PHASE_LIQUID)."""
    from ..core.grid import PHASE_LIQUID

    keep = particles["phase"] == PHASE_LIQUID
    return builder.build(particles["positions"][keep], particles["volume"][keep])


def builder_for(sim, resolution: int = 2, smoothing: float = 1.25) -> SurfaceBuilder:
    g = sim.grid
    return SurfaceBuilder(g.dim, g.dx, g.interior, resolution, smoothing, device=sim.device)


def _marching_cubes(field: wp.array, threshold: float):
    try:
        from warp.geometry import IsoSurfaceMarchingCubes as mc
    except ImportError:
        mc = None
    if mc is None or not hasattr(mc, "extract"):
        raise RuntimeError("the liquid surface needs warp-lang >= 1.18 (wp.geometry.IsoSurfaceMarchingCubes): "
                           "pip install -U warp-lang")
    return mc.extract(field, float(threshold))


def _vertex_normals(points: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Area-weighted average of the adjacent faces' normals, unit length."""
    p = points.astype(np.float64)
    fn = np.cross(p[faces[:, 1]] - p[faces[:, 0]], p[faces[:, 2]] - p[faces[:, 0]])
    n = np.zeros_like(p)
    for c in range(3):
        np.add.at(n, faces[:, c], fn)
    length = np.linalg.norm(n, axis=1, keepdims=True)
    return (n / np.where(length > 0, length, 1.0)).astype(np.float32)


def _empty() -> SurfaceMesh:
    return SurfaceMesh(np.zeros((0, 3), np.float32), np.zeros((0, 3), np.int32), np.zeros((0, 3), np.float32))


def read_surface(stage_path, frame: int) -> SurfaceMesh | None:
    """The /World/LiquidSurface mesh of `frame` in a written file (None if the file has no surface)."""
    from pxr import Sdf, Usd, UsdGeom

    from .usd_output import SURFACE

    cached = Sdf.Layer.Find(str(stage_path))
    if cached:
        cached.Reload()  # the writer replaces the file every frame
    stage = Usd.Stage.Open(str(stage_path))
    mesh = UsdGeom.Mesh.Get(stage, SURFACE)
    if not mesh:
        return None
    get = lambda attr: attr.Get(frame)  # noqa: E731
    pts = get(mesh.GetPointsAttr())
    if pts is None or not len(pts):
        return _empty()
    counts = np.asarray(get(mesh.GetFaceVertexCountsAttr()))
    if (counts != 3).any():
        raise ValueError(f"{stage_path}: {SURFACE} at frame {frame} is not a triangle mesh")
    return SurfaceMesh(np.asarray(pts, np.float32), np.asarray(get(mesh.GetFaceVertexIndicesAttr()), np.int32)
                       .reshape(-1, 3), np.asarray(get(mesh.GetNormalsAttr()), np.float32))
