"""The runner writes what the simulation holds: the ids, positions, velocities and
materials of every particle, frame by frame, exactly as Simulation.particles_numpy() gives them.
A shifted id breaks a renderer's motion blur without any other symptom, so it is checked here."""

import io

import numpy as np
import warp as wp

from warp_mpm_bubbles import Box, Domain, Material, Output, Scene, Sphere, run_scene
from warp_mpm_bubbles.io.usd_output import read_frames

wp.config.quiet = True


def test_written_frames_hold_the_simulations_particles(tmp_path):
    scene = Scene(domain=Domain(size=(0.08, 0.08), cell_size=0.08 / 16),
                  materials={"water": Material("water"), "air": Material("air", kind="gas")},
                  shapes=[Box("water", (0.0, 0.0), (0.08, 0.05)), Sphere("air", (0.04, 0.02), 0.01)],
                  output=Output(path=str(tmp_path / "run.usdc"), frames=2, fps=60))
    result = run_scene(scene, device="cpu", log=io.StringIO())
    frames = read_frames(str(tmp_path / "run.usdc"))["frames"]
    assert sorted(frames) == [0, 1, 2]
    n0 = len(frames[0]["ids"])
    print(f"runner: {n0} particles written at frame 0, {len(frames[2]['ids'])} at frame 2")
    np.testing.assert_array_equal(frames[0]["ids"], np.arange(n0))  # every particle's id, from 0, in order
    p = result.simulation.particles_numpy()
    last = frames[2]
    np.testing.assert_array_equal(last["ids"], p["ids"])
    np.testing.assert_array_equal(last["proto_indices"], p["material"])
    np.testing.assert_allclose(last["positions"], p["positions"])
    np.testing.assert_allclose(last["velocities"], p["velocities"])
    assert np.abs(p["velocities"]).max() > 0.0  # the bubble moved things: velocities are not trivially zero


def test_the_eta_after_a_resume_counts_only_the_frames_this_process_ran(monkeypatch):
    """Resumed after frame 24 of 30, one frame in 1 s: 5 frames left take 5 s, not 5/25 s."""
    from warp_mpm_bubbles.io import runner

    clock = iter([100.0, 101.0])
    monkeypatch.setattr(runner.time, "perf_counter", lambda: next(clock))
    stream = io.StringIO()
    runner.ProgressBar(30, stream=stream, first=24).update(25, 0.8, 1000)
    assert "elapsed 1s ETA 5s" in stream.getvalue()

