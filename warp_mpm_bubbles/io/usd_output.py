"""Particle output as USD animation (PointInstancer and/or Points), written frame by frame.

Storage layout (value clips)::

    out/sim.usdc                    top-level stage: /World, prototypes, metadata, clip template
    out/sim_frames/manifest.usdc    declares which attributes come from the clips
    out/sim_frames/sim.000042.usdc  time samples of frame 42 only
    out/sim_frames/.warp_mpm_bubbles  marker: the run id; only marked folders are ever cleared
    out/sim.usdc.lock               while a run writes (io/ownership.py)

Why not one .usdc saved after every frame: its save time is flat (crate appends in place,
~3 ms/frame for 50k particles, same at frame 1 and 200), but that in-place append first
overwrites the old table of contents and only then rewrites the header, so a kill -9 inside
Save() leaves a file that no longer opens -- every frame is lost (reproduced by killing the
writer at each pwrite with strace fault injection). Here every file is written to a temp
name, fsynced and os.replace()d, so a kill at any moment leaves the previous complete state,
and the per-frame cost is flat: one frame layer plus a constant-size top layer.
Value clips are core USD composition, so Blender, Houdini and Omniverse resolve them when
opening the top file; move the top file together with its ``*_frames`` folder.
"""

from __future__ import annotations

import errno
import os
import time
from pathlib import Path

import numpy as np
from pxr import Gf, Sdf, Tf, Usd, UsdGeom, Vt

from ..scene.model import OUTPUT_FORMATS
from .ownership import LAYER_KEY, OutputClaim, temp_path

FORMATS = OUTPUT_FORMATS  # [output].format: one definition, in the scene's schema
INSTANCER = "/World/Particles"
POINTS = "/World/ParticlePoints"
SURFACE = "/World/LiquidSurface"  # the liquid's surface mesh (io/surface.py), with `surface=True`
_T = Sdf.ValueTypeNames
# Time-varying attributes per prim; they live in the per-frame clip layers.
_CLIP_ATTRS = {
    INSTANCER: [("protoIndices", _T.IntArray), ("positions", _T.Point3fArray),
                ("ids", _T.Int64Array), ("velocities", _T.Vector3fArray),
                ("scales", _T.Float3Array), ("extent", _T.Float3Array)],
    POINTS: [("points", _T.Point3fArray), ("widths", _T.FloatArray), ("ids", _T.Int64Array),
             ("velocities", _T.Vector3fArray), ("extent", _T.Float3Array),
             ("primvars:displayColor", _T.Color3fArray), ("primvars:materialIndex", _T.IntArray)],
    SURFACE: [("points", _T.Point3fArray), ("faceVertexCounts", _T.IntArray),
              ("faceVertexIndices", _T.IntArray), ("normals", _T.Normal3fArray), ("extent", _T.Float3Array)],
}


def _fsync(path: Path, flags: int) -> None:
    fd = os.open(path, flags)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def _atomic_export(layer: Sdf.Layer, path: Path, tmp_dir: Path | None = None) -> None:
    """Export to a temp file, fsync, rename: readers see the old or the new file, never half.
    The temp name is unique to this process (with a shared one, two runs writing the same
    file would rename each other's temp file away); a failed write removes it and raises OSError naming `path`."""
    tmp = temp_path((tmp_dir or path.parent) / path.name)  # same suffix: it picks the file format
    try:
        try:
            ok = layer.Export(str(tmp))
        except Tf.ErrorException as err:  # USD reports the OS error as text
            text = str(err)
            code = next((c for c, words in _OS_ERRORS if words in text), errno.EIO)
            raise OSError(code, f"{os.strerror(code)} (USD: {text.strip().splitlines()[-1].strip()})",
                          str(path)) from None
        if not ok:
            raise OSError(errno.EIO, "USD could not write the file", str(path))
        _fsync(tmp, os.O_RDWR)
        os.replace(tmp, path)
    except OSError as err:
        tmp.unlink(missing_ok=True)
        if err.filename is None or Path(err.filename) == tmp:
            err.filename = str(path)
        raise
    if os.name == "posix":  # persist the rename too, so frames reach disk before the top file
        _fsync(path.parent, os.O_RDONLY)


_OS_ERRORS = [(errno.ENOSPC, "No space left on device"), (errno.EDQUOT, "quota exceeded"),
              (errno.EFBIG, "File too large"), (errno.EACCES, "Permission denied"),
              (errno.EROFS, "Read-only file system")]


def non_finite_frame(frame: int, name: str, bad: int, n: int) -> ValueError:
    """The error for a frame whose particles hold NaN or Inf: the simulation diverged, which is a
    SimulationError (a run that stops: exit 1, its written frames kept) as well as the ValueError the
    writer raises for data it cannot write. Nothing of the frame is written. The simulation's module
    (and Warp) is imported only here, so reading and previewing output do not load it."""
    from ..core.simulation import SimulationError

    class NonFiniteFrameError(SimulationError, ValueError):
        pass

    return NonFiniteFrameError(
        f"frame {frame}: {name} contains NaN or inf ({bad} of {n} particles), so the frame is not "
        f"written: the simulation diverged during it. Likely cause: a time step too large for the "
        f"scene (lower [solver].cfl or set [solver].max_dt), or a moving collider squeezing liquid "
        f"it has shut in against a wall or another collider (slow its [colliders.N].velocity or "
        f"acceleration, or start it a cell or more away)")


class StageWriter:
    """Writes one USD frame per write_frame(); every returned frame is durable on disk."""

    def __init__(self, path, *, fps: float, materials: list[tuple[str, tuple[float, float, float]]],
                 particle_radius: float, format: str = "instancer", up_axis: str = "Y",
                 meters_per_unit: float = 1.0, resume_after: int | None = None, decorate=None,
                 overwrite: bool = False, claim: OutputClaim | None = None, surface: bool = False,
                 prototype_of=()):
        """resume_after=k keeps the frames already on disk up to k (a resumed run) and goes on
        from k + 1; otherwise an existing output is refused (OutputExists) unless overwrite=True,
        which deletes only the files this project wrote. claim: an OutputClaim the caller already
        holds (run_scene, which claims before building the simulation); without one the writer
        takes its own and releases it on close(). decorate(stage), if given, adds prims that do
        not change per frame (or are sampled up front: colliders) to the top layer. surface=True
        adds the clip-animated mesh SURFACE, filled by write_frame(surface=...).
        prototype_of: (material index, phase) for each of the last len(prototype_of) entries of
        `materials`, a prototype of its own for the particles of that material in that phase (the
        sub-grid bubbles: scene_prototypes); the entries before them are the scene's materials,
        prototype i = material i. With any, write_frame needs each particle's phase."""
        t0 = time.perf_counter()
        if format not in FORMATS:
            raise ValueError(f"format must be one of {FORMATS}, got {format!r}")
        if up_axis not in ("Y", "Z"):
            raise ValueError(f"up_axis must be 'Y' or 'Z', got {up_axis!r}")
        if not materials:
            raise ValueError("materials must not be empty")
        if not fps > 0 or not particle_radius > 0:
            raise ValueError("fps and particle_radius must be > 0")
        self.path = Path(path)
        self.format = format
        self.radius = float(particle_radius)
        self.seconds = 0.0
        self._colors = np.array([c for _, c in materials], dtype=np.float32).reshape(-1, 3)
        self._prototype_of = [(int(m), int(ph)) for m, ph in prototype_of]
        self._n_mat = len(materials) - len(self._prototype_of)  # the scene's materials
        if self._n_mat < 1 or any(not 0 <= m < self._n_mat for m, _ in self._prototype_of):
            raise ValueError("prototype_of must name materials among the first entries of materials")
        self._prims = [p for p, on in ((INSTANCER, format != "points"),
                                       (POINTS, format != "instancer")) if on]
        if surface:
            self._prims.append(SURFACE)
        ext = ".usda" if self.path.suffix == ".usda" else ".usdc"
        self._frames_dir = self.path.with_name(self.path.stem + "_frames")
        self._ext = ext
        self._manifest = self._frames_dir / ("manifest" + ext)
        self._last = None
        self._closed = False
        self._own_claim = claim is None
        self._claim = claim or OutputClaim(self.path, overwrite=overwrite,
                                           resume=resume_after is not None).__enter__()
        try:
            self._open(materials, fps, up_axis, meters_per_unit, resume_after, decorate)
        except BaseException:
            self.close()
            raise
        self.seconds += time.perf_counter() - t0

    def _open(self, materials, fps, up_axis, meters_per_unit, resume_after, decorate) -> None:
        """Trim or clear the output (the claim checked it is ours), then write manifest and top."""
        start = None
        if resume_after is not None:
            start = Sdf.Layer.OpenAsAnonymous(str(self.path)).startTimeCode  # not the layer cache
        self._claim.prepare(resume_after)
        self._meta = {"run_id": self._claim.run_id}
        self._top = self._build_top(materials, fps, up_axis, meters_per_unit, decorate)
        self._top.customLayerData = {LAYER_KEY: self._meta}
        manifest = Sdf.Layer.CreateAnonymous(self._ext)
        self._declare(manifest)
        _atomic_export(manifest, self._manifest)
        if start is None:
            self._export_top()  # valid (empty) stage even before frame 0
        else:
            self._top.startTimeCode = start
            self._publish(int(resume_after))  # the kept frames stay visible from the first moment

    def _export_top(self) -> None:
        # its temp goes in the frames folder: a kill leaves nothing stray beside the stage
        _atomic_export(self._top, self.path, tmp_dir=self._frames_dir)

    def _build_top(self, materials, fps, up_axis, meters_per_unit, decorate=None) -> Sdf.Layer:
        layer = Sdf.Layer.CreateAnonymous(self._ext)  # we hold it, not the stage
        stage = Usd.Stage.Open(layer)
        world = UsdGeom.Xform.Define(stage, "/World")  # typed: Blender skips untyped parents
        stage.SetDefaultPrim(world.GetPrim())
        UsdGeom.SetStageUpAxis(stage, up_axis)
        UsdGeom.SetStageMetersPerUnit(stage, meters_per_unit)
        stage.SetTimeCodesPerSecond(fps)
        stage.SetFramesPerSecond(fps)
        # Attributes are declared here (no values) so their types and primvar interpolation
        # exist in the composed stage; the values come from the clips.
        if INSTANCER in self._prims:
            inst = UsdGeom.PointInstancer.Define(stage, INSTANCER)
            UsdGeom.Scope.Define(stage, INSTANCER + "/Prototypes")
            names = [Tf.MakeValidIdentifier(name) for name, _ in materials]
            if len(set(names)) != len(names):
                raise ValueError(f"material names are not unique as USD prim names: {names}")
            protos = []
            for name, (_, color) in zip(names, materials):
                sphere = UsdGeom.Sphere.Define(stage, f"{INSTANCER}/Prototypes/{name}")
                sphere.CreateRadiusAttr(1.0)  # scaled per instance by `scales` = radius
                sphere.CreateExtentAttr([(-1, -1, -1), (1, 1, 1)])
                sphere.CreateDisplayColorAttr([Gf.Vec3f(*map(float, color))])
                protos.append(sphere.GetPath())
            inst.GetPrototypesRel().SetTargets(protos)  # index i = materials[i]
            for create in (inst.CreateProtoIndicesAttr, inst.CreatePositionsAttr, inst.CreateIdsAttr,
                           inst.CreateVelocitiesAttr, inst.CreateScalesAttr, inst.CreateExtentAttr):
                create()
        if POINTS in self._prims:
            pts = UsdGeom.Points.Define(stage, POINTS)
            for create in (pts.CreatePointsAttr, pts.CreateIdsAttr, pts.CreateVelocitiesAttr,
                           pts.CreateExtentAttr):
                create()
            pts.CreateWidthsAttr()
            pts.SetWidthsInterpolation(UsdGeom.Tokens.vertex)
            pts.CreateDisplayColorPrimvar(UsdGeom.Tokens.vertex)
            UsdGeom.PrimvarsAPI(pts).CreatePrimvar("materialIndex", _T.IntArray, UsdGeom.Tokens.vertex)
        if SURFACE in self._prims:
            _define_surface(stage)
        if decorate is not None:
            decorate(stage)
        return layer  # the stage is dropped: later edits go straight to the layer

    def _declare(self, layer: Sdf.Layer) -> dict:
        """Create the clip prim/attribute specs in `layer`; returns {(prim, name): spec path}."""
        paths = {}
        for prim in self._prims:
            spec = Sdf.CreatePrimInLayer(layer, prim)
            for name, type_name in _CLIP_ATTRS[prim]:
                paths[prim, name] = Sdf.AttributeSpec(spec, name, type_name).path
        return paths

    def write_frame(self, frame: int, positions: np.ndarray, velocities: np.ndarray,
                    ids: np.ndarray, material: np.ndarray, radii: np.ndarray | None = None,
                    surface=None, phase: np.ndarray | None = None) -> None:
        """radii (N,), metres: per-particle sizes (foam, sub-grid bubbles); None: particle_radius for all.
        phase (N,): each particle's phase, which picks the prototypes of `prototype_of`.
        surface: the liquid's mesh this frame (io/surface.SurfaceMesh) when the writer has one; None: empty."""
        t0 = time.perf_counter()
        if self._closed:
            raise ValueError("write_frame after close()")
        frame = int(frame)
        if frame < 0:  # clip file names are zero-padded frame numbers
            raise ValueError(f"frame {frame} must be >= 0")
        if self._last is not None and frame <= self._last:
            raise ValueError(f"frame {frame} must be greater than the last frame {self._last}")
        pos, vel, ids, mat = self._validate(frame, positions, velocities, ids, material)
        n = len(pos)
        rad = self._radii(frame, radii, n)
        proto = self._proto_indices(frame, mat, phase)

        if n and radii is None:
            lo, hi = pos.min(axis=0) - self.radius, pos.max(axis=0) + self.radius
        elif n:
            lo, hi = (pos - rad[:, None]).min(axis=0), (pos + rad[:, None]).max(axis=0)
        else:
            lo = hi = np.zeros(3, np.float32)
        extent = Vt.Vec3fArray([Gf.Vec3f(*map(float, lo)), Gf.Vec3f(*map(float, hi))])
        v_pos, v_vel = Vt.Vec3fArray.FromNumpy(pos), Vt.Vec3fArray.FromNumpy(vel)
        v_ids, v_mat = Vt.Int64Array.FromNumpy(ids), Vt.IntArray.FromNumpy(mat)
        values = {
            (INSTANCER, "protoIndices"): Vt.IntArray.FromNumpy(proto), (INSTANCER, "positions"): v_pos,
            (INSTANCER, "ids"): v_ids, (INSTANCER, "velocities"): v_vel,
            (INSTANCER, "extent"): extent,
            (POINTS, "points"): v_pos, (POINTS, "ids"): v_ids, (POINTS, "velocities"): v_vel,
            (POINTS, "extent"): extent, (POINTS, "primvars:materialIndex"): v_mat,
        }
        if INSTANCER in self._prims:
            values[INSTANCER, "scales"] = Vt.Vec3fArray.FromNumpy(np.repeat(rad[:, None], 3, axis=1))
        if POINTS in self._prims:
            values[POINTS, "widths"] = Vt.FloatArray.FromNumpy(2 * rad)
            values[POINTS, "primvars:displayColor"] = Vt.Vec3fArray.FromNumpy(self._colors[mat])
        if SURFACE in self._prims:
            values.update(_surface_values(surface))
        elif surface is not None:
            raise ValueError("write_frame got a surface but the writer was made without surface=True")

        layer = Sdf.Layer.CreateAnonymous(self._ext)
        layer.customLayerData = {LAYER_KEY: self._meta}  # which run wrote this frame
        for key, attr_path in self._declare(layer).items():
            layer.SetTimeSample(attr_path, frame, values[key])
        name = f"{self.path.stem}.{frame:06d}{self._ext}"
        _atomic_export(layer, self._frames_dir / name)

        # Then publish it. Template clips keep the top file constant-size (an explicit clip list
        # made it grow, 3 -> 25 ms/frame over 5000 frames); USD skips template paths with no
        # file, so gaps in the frame numbers are fine.
        if self._last is None:
            self._top.startTimeCode = frame
        self._publish(frame)
        self.seconds += time.perf_counter() - t0

    def _publish(self, frame: int) -> None:
        """Point the top file's clips at frames start..frame and replace it atomically."""
        self._top.endTimeCode = frame
        self._top.GetPrimAtPath("/World").SetInfo("clips", {"default": {
            "primPath": "/World",
            "templateAssetPath": f"./{self._frames_dir.name}/{self.path.stem}.######{self._ext}",
            "templateStartTime": float(self._top.startTimeCode),
            "templateEndTime": float(frame),
            "templateStride": 1.0,
            "manifestAssetPath": Sdf.AssetPath(f"./{self._frames_dir.name}/{self._manifest.name}"),
        }})
        self._export_top()
        self._last = frame

    def _validate(self, frame, positions, velocities, ids, material):
        pos = np.ascontiguousarray(positions, dtype=np.float32)
        vel = np.ascontiguousarray(velocities, dtype=np.float32)
        ids = np.ascontiguousarray(ids, dtype=np.int64)
        mat = np.ascontiguousarray(material, dtype=np.int32)
        n = len(pos) if pos.ndim == 2 else -1
        for name, arr, shape in (("positions", pos, (n, 3)), ("velocities", vel, (n, 3)),
                                 ("ids", ids, (n,)), ("material", mat, (n,))):
            if n < 0 or arr.shape != shape:
                raise ValueError(f"frame {frame}: {name} has shape {arr.shape}, expected "
                                 f"{shape if n >= 0 else '(N, 3)'}")
        for name, arr in (("positions", pos), ("velocities", vel)):
            finite = np.isfinite(arr).all(axis=1)
            if not finite.all():
                raise non_finite_frame(frame, name, int(n - finite.sum()), n)
        if n and (mat.min() < 0 or mat.max() >= self._n_mat):
            raise ValueError(f"frame {frame}: material index outside [0, {self._n_mat})")
        return pos, vel, ids, mat

    def _proto_indices(self, frame, mat, phase) -> np.ndarray:
        """Each particle's prototype: its material's, or the one of `prototype_of` for its material and phase."""
        if not self._prototype_of:
            return mat
        ph = None if phase is None else np.ascontiguousarray(phase, dtype=np.int32)
        if ph is None or ph.shape != mat.shape:
            raise ValueError(f"frame {frame}: phase is needed, shape {mat.shape}, for the prototypes of phases")
        proto = mat.copy()
        for k, (m, p) in enumerate(self._prototype_of):
            proto[(mat == m) & (ph == p)] = self._n_mat + k
        return proto

    def _radii(self, frame, radii, n) -> np.ndarray:
        if radii is None:
            return np.full(n, self.radius, np.float32)
        rad = np.ascontiguousarray(radii, dtype=np.float32)
        if rad.shape != (n,):
            raise ValueError(f"frame {frame}: radii has shape {rad.shape}, expected {(n,)}")
        if not (np.isfinite(rad).all() and (rad > 0).all()):
            raise ValueError(f"frame {frame}: radii must be finite and > 0")
        return rad

    @property
    def last_frame(self) -> int | None:
        """The last frame published in the top file (None before the first)."""
        return self._last

    def close(self) -> None:
        # Nothing to flush: every frame was made durable in write_frame. Release a lock we took.
        self._closed = True
        if self._own_claim and self._claim is not None:
            self._claim.__exit__(None, None, None)
            self._claim = None

    def __del__(self):
        try:
            self.close()
        except Exception:  # interpreter shutdown: the lock then reads as stale (pid gone)
            pass

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


def _define_surface(stage) -> None:
    """The mesh prim, its clip attributes declared with no values (they come from the frames)."""
    mesh = UsdGeom.Mesh.Define(stage, SURFACE)
    mesh.CreateSubdivisionSchemeAttr(UsdGeom.Tokens.none)  # a triangle mesh, not a subdivision cage
    mesh.CreateOrientationAttr(UsdGeom.Tokens.rightHanded)  # counter-clockwise seen from outside
    mesh.CreateDoubleSidedAttr(False)  # closed: a renderer refracts in and out through it
    for create in (mesh.CreatePointsAttr, mesh.CreateFaceVertexCountsAttr, mesh.CreateFaceVertexIndicesAttr,
                   mesh.CreateNormalsAttr, mesh.CreateExtentAttr):
        create()
    mesh.SetNormalsInterpolation(UsdGeom.Tokens.vertex)


def _surface_values(surface) -> dict:
    """Clip values of SURFACE for one frame from a SurfaceMesh (None: an empty mesh)."""
    if surface is None:
        pts = nrm = np.zeros((0, 3), np.float32)
        tri = np.zeros((0, 3), np.int32)
    else:
        pts = np.ascontiguousarray(surface.points, np.float32)
        nrm = np.ascontiguousarray(surface.normals, np.float32)
        tri = np.ascontiguousarray(surface.indices, np.int32)
    lo, hi = (pts.min(axis=0), pts.max(axis=0)) if len(pts) else (np.zeros(3), np.zeros(3))
    return {(SURFACE, "points"): Vt.Vec3fArray.FromNumpy(pts), (SURFACE, "normals"): Vt.Vec3fArray.FromNumpy(nrm),
            (SURFACE, "faceVertexCounts"): Vt.IntArray.FromNumpy(np.full(len(tri), 3, np.int32)),
            (SURFACE, "faceVertexIndices"): Vt.IntArray.FromNumpy(tri.reshape(-1)),
            (SURFACE, "extent"): Vt.Vec3fArray([Gf.Vec3f(*map(float, lo)), Gf.Vec3f(*map(float, hi))])}


def read_frames(path) -> dict:
    """Read a file written by StageWriter back into numpy arrays (for tests and tools)."""
    path = str(path)
    cached = Sdf.Layer.Find(path)
    if cached:
        cached.Reload()  # the file is replaced on every frame; don't trust the registry copy
    stage = Usd.Stage.Open(path)
    if not stage:
        raise OSError(f"cannot open {path}")
    root = stage.GetRootLayer()
    start = root.startTimeCode if root.HasStartTimeCode() else None
    end = root.endTimeCode if root.HasEndTimeCode() else None
    inst = UsdGeom.PointInstancer.Get(stage, INSTANCER)
    pts = UsdGeom.Points.Get(stage, POINTS)
    frames = {}
    if start is not None:
        main = inst.GetPositionsAttr() if inst else pts.GetPointsAttr()
        for t in map(int, main.GetTimeSamples()):
            if inst:
                get = lambda a: np.asarray(inst.GetPrim().GetAttribute(a).Get(t))
                f = {"positions": get("positions"), "velocities": get("velocities"),
                     "ids": get("ids"), "proto_indices": get("protoIndices"),
                     "scales": get("scales"), "extent": get("extent")}
            else:  # points-only files: derive the instancer view from widths / materialIndex
                get = lambda a: np.asarray(pts.GetPrim().GetAttribute(a).Get(t))
                half = get("widths") / 2
                f = {"positions": get("points"), "velocities": get("velocities"),
                     "ids": get("ids"), "proto_indices": get("primvars:materialIndex"),
                     "scales": np.repeat(half[:, None], 3, axis=1), "extent": get("extent")}
            frames[t] = f
    return {"fps": stage.GetTimeCodesPerSecond(), "up_axis": UsdGeom.GetStageUpAxis(stage),
            "start": start, "end": end, "frames": frames}
