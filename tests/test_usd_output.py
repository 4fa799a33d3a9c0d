import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from pxr import Usd, UsdGeom

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))  # runnable with plain `pytest`, without installing the package

from warp_mpm_bubbles.io.usd_output import StageWriter, read_frames  # noqa: E402

sys.path.insert(0, str(Path(__file__).parent))
from _slow_writer import frame_data  # noqa: E402

MATERIALS = [("water", (0.1, 0.3, 0.9)), ("air bubble", (1.0, 1.0, 1.0))]
RADIUS = 0.02
COUNTS = {0: 100, 1: 120, 2: 90}


def make_frame(frame, n):
    rng = np.random.default_rng(frame)
    pos = rng.normal(size=(n, 3)).astype(np.float32)
    vel = rng.normal(size=(n, 3)).astype(np.float32)
    ids = rng.permutation(1000)[:n].astype(np.int64)
    mat = rng.integers(0, len(MATERIALS), n).astype(np.int32)
    return pos, vel, ids, mat


def write(path, fmt="instancer", counts=COUNTS, **kw):
    kw = {"fps": 30.0, "up_axis": "Z", **kw}
    data = {f: make_frame(f, n) for f, n in counts.items()}
    with StageWriter(path, materials=MATERIALS, particle_radius=RADIUS, format=fmt, **kw) as w:
        for f, d in data.items():
            w.write_frame(f, *d)
    assert w.seconds > 0
    return data


def expected_extent(pos):
    if not len(pos):
        return np.zeros((2, 3))  # the writer's convention for a frame with no particles
    return np.stack([pos.min(0) - RADIUS, pos.max(0) + RADIUS])


def check_read_frames(path, data):
    r = read_frames(path)
    assert (r["fps"], r["up_axis"], r["start"], r["end"]) == (30.0, "Z", min(data), max(data))
    assert sorted(r["frames"]) == sorted(data)
    for f, (pos, vel, ids, mat) in data.items():
        got = r["frames"][f]
        np.testing.assert_array_equal(got["ids"], ids)
        np.testing.assert_array_equal(got["proto_indices"], mat)
        np.testing.assert_allclose(got["positions"], pos)
        np.testing.assert_allclose(got["velocities"], vel)
        np.testing.assert_allclose(got["scales"], np.full((len(pos), 3), RADIUS))
        np.testing.assert_allclose(got["extent"], expected_extent(pos), rtol=1e-6)


@pytest.mark.parametrize("suffix", [".usdc", ".usda"])
def test_instancer_round_trip(tmp_path, suffix):
    path = tmp_path / "nested" / ("sim" + suffix)  # parent dirs are created
    data = write(path)
    if suffix == ".usda":
        assert path.read_text().startswith("#usda")

    stage = Usd.Stage.Open(str(path))
    assert UsdGeom.GetStageUpAxis(stage) == "Z"
    assert UsdGeom.GetStageMetersPerUnit(stage) == 1.0
    assert stage.GetTimeCodesPerSecond() == 30.0 and stage.GetFramesPerSecond() == 30.0
    assert (stage.GetStartTimeCode(), stage.GetEndTimeCode()) == (0, 2)
    world = stage.GetDefaultPrim()
    assert world.GetPath() == "/World" and world.IsA(UsdGeom.Xform)  # typed, not just "def"
    inst = UsdGeom.PointInstancer.Get(stage, "/World/Particles")
    assert inst
    protos = inst.GetPrototypesRel().GetTargets()
    assert [str(p) for p in protos] == ["/World/Particles/Prototypes/water",
                                        "/World/Particles/Prototypes/air_bubble"]
    for p, (_, color) in zip(protos, MATERIALS):
        sphere = UsdGeom.Sphere(stage.GetPrimAtPath(p))
        assert sphere and sphere.GetRadiusAttr().Get() == 1.0
        np.testing.assert_allclose(sphere.GetDisplayColorAttr().Get()[0], color)
    for f, (pos, vel, ids, mat) in data.items():
        assert len(inst.GetPositionsAttr().Get(f)) == COUNTS[f]
        np.testing.assert_array_equal(np.asarray(inst.GetIdsAttr().Get(f)), ids)
        np.testing.assert_array_equal(np.asarray(inst.GetProtoIndicesAttr().Get(f)), mat)
        np.testing.assert_allclose(np.asarray(inst.GetPositionsAttr().Get(f)), pos)
        np.testing.assert_allclose(np.asarray(inst.GetVelocitiesAttr().Get(f)), vel)
        np.testing.assert_allclose(np.asarray(inst.GetScalesAttr().Get(f)), RADIUS)
        np.testing.assert_allclose(np.asarray(inst.GetExtentAttr().Get(f)), expected_extent(pos), rtol=1e-6)
    assert not stage.GetPrimAtPath("/World/ParticlePoints")
    check_read_frames(path, data)


@pytest.mark.parametrize("fmt", ["points", "both"])
def test_points_round_trip(tmp_path, fmt):
    path = tmp_path / "sim.usdc"
    data = write(path, fmt, up_axis="Y" if fmt == "points" else "Z")
    stage = Usd.Stage.Open(str(path))
    assert bool(stage.GetPrimAtPath("/World/Particles")) == (fmt == "both")
    pts = UsdGeom.Points.Get(stage, "/World/ParticlePoints")
    assert pts
    color = UsdGeom.PrimvarsAPI(pts).GetPrimvar("displayColor")
    mat_pv = UsdGeom.PrimvarsAPI(pts).GetPrimvar("materialIndex")
    assert color.GetInterpolation() == mat_pv.GetInterpolation() == "vertex"
    assert pts.GetWidthsInterpolation() == "vertex"
    colors = np.array([c for _, c in MATERIALS], np.float32)
    for f, (pos, vel, ids, mat) in data.items():
        np.testing.assert_allclose(np.asarray(pts.GetPointsAttr().Get(f)), pos)
        np.testing.assert_allclose(np.asarray(pts.GetVelocitiesAttr().Get(f)), vel)
        np.testing.assert_array_equal(np.asarray(pts.GetIdsAttr().Get(f)), ids)
        np.testing.assert_allclose(np.asarray(pts.GetWidthsAttr().Get(f)), 2 * RADIUS)
        np.testing.assert_allclose(np.asarray(pts.GetExtentAttr().Get(f)), expected_extent(pos), rtol=1e-6)
        np.testing.assert_allclose(np.asarray(color.Get(f)), colors[mat])
        np.testing.assert_array_equal(np.asarray(mat_pv.Get(f)), mat)
    if fmt == "points":
        # read_frames derives the instancer view from the Points prim
        r = read_frames(path)
        assert r["up_axis"] == "Y" and sorted(r["frames"]) == [0, 1, 2]
        np.testing.assert_array_equal(r["frames"][1]["proto_indices"], data[1][3])
        np.testing.assert_allclose(r["frames"][1]["scales"], RADIUS)
    else:
        check_read_frames(path, data)


def test_frame_gaps_empty_frames_and_overwrite(tmp_path):
    path = tmp_path / "sim.usdc"
    write(path, counts={0: 10, 1: 10, 2: 10, 3: 10})
    data = write(path, counts={2: 5, 5: 0, 9: 7}, overwrite=True)  # old frames must disappear
    check_read_frames(path, data)
    assert len(list((tmp_path / "sim_frames").glob("sim.0*.usdc"))) == 3


def test_bad_input(tmp_path):
    pos, vel, ids, mat = make_frame(0, 10)
    w = StageWriter(tmp_path / "x.usdc", fps=24, materials=MATERIALS, particle_radius=RADIUS)
    bad_pos = pos.copy()
    bad_pos[3, 1] = np.nan
    bad_vel = vel.copy()
    bad_vel[0, 0] = np.inf
    cases = [((7, pos[:, :2], vel, ids, mat), "frame 7: positions"),
             ((7, pos, vel[:9], ids, mat), "frame 7: velocities"),
             ((7, pos, vel, ids[:5], mat), "frame 7: ids"),
             ((7, pos, vel, ids, mat[:, None]), "frame 7: material"),
             ((7, bad_pos, vel, ids, mat), "frame 7: positions contains NaN"),
             ((7, pos, bad_vel, ids, mat), "frame 7: velocities contains NaN"),
             ((7, pos, vel, ids, mat + 5), "material index")]
    for args, msg in cases:
        with pytest.raises(ValueError, match=msg):
            w.write_frame(*args)
    w.write_frame(3, pos, vel, ids, mat)
    with pytest.raises(ValueError, match="greater than"):
        w.write_frame(3, pos, vel, ids, mat)
    w.close()
    w.close()  # idempotent
    with pytest.raises(ValueError):
        w.write_frame(4, pos, vel, ids, mat)
    assert sorted(read_frames(tmp_path / "x.usdc")["frames"]) == [3]
    with pytest.raises(ValueError, match="format"):
        StageWriter(tmp_path / "y.usdc", fps=24, materials=MATERIALS, particle_radius=RADIUS, format="mesh")


@pytest.mark.parametrize("sleep", [0.02, 0.0])
def test_kill_leaves_finished_frames_readable(tmp_path, sleep):
    """SIGKILL mid-run (with sleep=0 most likely inside a write): every listed frame is intact."""
    path, base = tmp_path / "kill.usdc", 20000
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    proc = subprocess.Popen([sys.executable, str(Path(__file__).parent / "_slow_writer.py"),
                             str(path), "100000", str(sleep), str(base)], env=env)
    try:
        deadline = time.monotonic() + 30
        while True:
            assert proc.poll() is None, "writer exited early"
            assert time.monotonic() < deadline, "writer too slow"
            if path.exists() and (read_frames(path)["end"] or 0) >= 2:
                break
            time.sleep(0.005)
        time.sleep(0.013)  # land somewhere inside a later frame
    finally:
        proc.send_signal(signal.SIGKILL)
        proc.wait()

    r = read_frames(path)
    assert r["start"] == 0 and r["end"] >= 2
    assert sorted(r["frames"]) == list(range(int(r["end"]) + 1))
    for f, got in r["frames"].items():
        pos, vel, ids, mat = frame_data(f, base)
        np.testing.assert_array_equal(got["ids"], ids)
        np.testing.assert_array_equal(got["proto_indices"], mat)
        np.testing.assert_array_equal(got["positions"], pos)
        np.testing.assert_array_equal(got["velocities"], vel)
