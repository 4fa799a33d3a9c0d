"""The command line and the example script, end to end: scene file in, USD animation out."""

import os
import pathlib
import signal
import subprocess
import sys
import time

import numpy as np
import pytest

from scenes import SMALL_2D

from warp_mpm_bubbles.cli import main
from warp_mpm_bubbles.io.usd_output import read_frames

ROOT = pathlib.Path(__file__).resolve().parents[1]

def small_scene(tmp_path, frames=3, name="small.toml"):
    path = tmp_path / name
    path.write_text(SMALL_2D.format(out=(tmp_path / "small.usdc").as_posix(), frames=frames))
    return path


def test_check_validates_without_running(capsys):
    assert main(["check", str(ROOT / "examples" / "dam_break.toml")]) == 0
    out = capsys.readouterr().out
    assert "OK" in out and "49,152 particles" in out


def test_bad_scene_is_refused_with_named_key_before_any_output(tmp_path, capsys):
    scene = small_scene(tmp_path)
    scene.write_text(scene.read_text().replace("density = 1000.0", "densty = 1000.0"))
    assert main(["run", str(scene)]) == 2
    err = capsys.readouterr().err
    assert "[materials.water].densty" in err and "did you mean 'density'" in err
    assert not (tmp_path / "small.usdc").exists()


def test_run_writes_every_frame_and_a_summary(tmp_path, capsys):
    scene = small_scene(tmp_path, frames=3)
    out = tmp_path / "override.usdc"
    assert main(["run", str(scene), "--device", "cpu", "--num-frames", "4", "--stage-path", str(out)]) == 0
    frames = read_frames(out)
    assert sorted(frames["frames"]) == [0, 1, 2, 3, 4]
    assert frames["fps"] == 60
    ids0 = frames["frames"][0]["ids"]
    for f in frames["frames"].values():
        np.testing.assert_array_equal(np.sort(f["ids"]), np.sort(ids0))
    err = capsys.readouterr().err
    for stage in ("p2g", "grid", "pressure", "extend", "g2p", "output", "pressure CG", "particles", "steps"):
        assert stage in err
    summary = err[err.index("small: 5 frames"):]
    assert summary.strip() in (tmp_path / "override_frames" / "run.log").read_text()  # kept beside the frames


def test_an_over_long_output_name_is_refused_naming_the_field(tmp_path, capsys):
    """NAME_MAX is 255 bytes here; the frame files add up to 32 to the name (a frame temp)."""
    scene = small_scene(tmp_path)
    long_name = tmp_path / ("a" * 300 + ".usdc")
    assert main(["run", str(scene), "--stage-path", str(long_name), "--quiet"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: --stage-path ") and "shorten the name before its suffix to at most" in err
    scene.write_text(scene.read_text().replace("small.usdc", "b" * 240 + ".usdc"))  # fits alone, not with frames
    assert main(["check", str(scene)]) == 2
    err = capsys.readouterr().err
    assert "[output].path" in err and "at most 223 bytes" in err and "internal error" not in err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["small.toml"]  # nothing written


def run_and_kill(scene, out, min_frames=3):
    """Start `warp-mpm-bubbles run` in a subprocess and SIGKILL it once min_frames are on disk."""
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    proc = subprocess.Popen([sys.executable, "-m", "warp_mpm_bubbles.cli", "run", str(scene), "--quiet"],
                            env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    try:
        deadline = time.time() + 120
        while time.time() < deadline:
            # end is None while the reader races the writer's first publish: not ready yet
            if out.exists() and (read_frames(out)["end"] or -1) >= min_frames:
                break
            assert proc.poll() is None, proc.stderr.read().decode()
            time.sleep(0.2)
        else:
            pytest.fail(f"the run wrote no {min_frames} frames in 120 s")
    finally:
        proc.send_signal(signal.SIGKILL)
        proc.wait()


def test_killed_run_keeps_its_finished_frames(tmp_path):
    scene = small_scene(tmp_path, frames=500)
    out = tmp_path / "small.usdc"
    run_and_kill(scene, out)
    frames = read_frames(out)
    assert frames["end"] >= 3
    assert sorted(frames["frames"]) == list(range(int(frames["end"]) + 1))
    n = len(frames["frames"][0]["ids"])
    for f in frames["frames"].values():
        assert len(f["positions"]) == n and np.isfinite(f["positions"]).all()


def test_killed_run_resumes_to_the_uninterrupted_result(tmp_path):
    frames = 150
    scene = small_scene(tmp_path, frames=frames)
    out = tmp_path / "small.usdc"
    run_and_kill(scene, out, min_frames=3)
    killed_at = int(read_frames(out)["end"])
    assert killed_at < frames, "the run finished before it could be killed; make it longer"
    assert main(["run", str(scene), "--resume", "--quiet"]) == 0
    reference = tmp_path / "reference.usdc"
    assert main(["run", str(scene), "--stage-path", str(reference), "--quiet"]) == 0
    resumed, whole = read_frames(out), read_frames(reference)
    assert sorted(resumed["frames"]) == list(range(frames + 1))
    for f in (killed_at, killed_at + 1, frames):  # bit for bit on the CPU device
        np.testing.assert_array_equal(resumed["frames"][f]["positions"], whole["frames"][f]["positions"])


def test_resume_without_a_checkpoint_is_refused(tmp_path, capsys):
    assert main(["run", str(small_scene(tmp_path)), "--resume"]) == 1
    assert "nothing to resume" in capsys.readouterr().err


def test_dam_break_example_column_falls_and_spreads(tmp_path):
    out = tmp_path / "dam.usdc"
    cmd = [sys.executable, str(ROOT / "examples" / "dam_break.py"), "--device", "cpu", "--num-frames", "4",
           "--stage-path", str(out), "--quiet"]
    subprocess.run(cmd, check=True, env=dict(os.environ, PYTHONPATH=str(ROOT)))
    frames = read_frames(out)["frames"]
    first, last = frames[0]["positions"], frames[4]["positions"]
    assert last[:, 1].max() < first[:, 1].max() - 0.01  # the column's top has fallen (> 1 cell)
    assert last[:, 0].max() > first[:, 0].max() + 0.02  # and its foot has run out along the floor


def test_gas_scene_summary_reports_the_gas_budget(tmp_path, capsys):
    out = tmp_path / "bubble.usdc"
    assert main(["run", str(ROOT / "examples" / "rising_bubble.toml"), "--num-frames", "1", "--stage-path", str(out)]) == 0
    err = capsys.readouterr().err
    assert "gas: 0.0% of its mass vented" in err and "vent" in err.splitlines()[-1]


def test_quality_flag_replaces_the_scenes_settings():
    import argparse

    from warp_mpm_bubbles.cli import add_run_overrides, scene_with_overrides

    parser = argparse.ArgumentParser()
    add_run_overrides(parser)
    scene = scene_with_overrides(ROOT / "examples" / "dam_break.toml", parser.parse_args(["--quality", "reference"]))
    assert scene.solver.quality == "reference" and scene.solver.refine == 2
    assert scene.solver.particles_per_cell == 8  # the preset's 3D value replaces the file's (also 8)
    with pytest.raises(SystemExit):
        parser.parse_args(["--quality", "best"])


# Every example's output (its phases, colliders and effects) is checked in test_examples.py.


def test_a_bad_thread_count_is_refused_before_any_output(tmp_path, capsys, monkeypatch):
    scene = small_scene(tmp_path)
    for value, says in (("two", "not a whole number"), ("0", "set it to 1 or more")):
        monkeypatch.setenv("WARP_MPM_CPU_THREADS", value)
        assert main(["run", str(scene), "--quiet"]) == 2
        err = capsys.readouterr().err
        assert "WARP_MPM_CPU_THREADS" in err and says in err and "Traceback" not in err
        assert not list(tmp_path.glob("*.usd*"))


def test_warp_starts_without_its_native_noise_but_keeps_its_warnings(monkeypatch, capfd):
    """The CUDA driver warning comes from Warp's native library, written straight to descriptor 2
    during wp.init(): silenced unless --verbose; a warning from Warp's Python side still shows."""
    import warp as wp
    from warp._src import logger

    from warp_mpm_bubbles.cli import start_warp

    def init():
        os.write(2, b"Warp CUDA warning: native noise\n")
        logger.log_warning("a warning worth seeing")

    monkeypatch.setattr(wp, "init", init)
    monkeypatch.setattr(wp.config, "log_level", wp.config.log_level)  # start_warp sets it: put it back after
    start_warp()
    err = capfd.readouterr().err
    assert "native noise" not in err and "a warning worth seeing" in err
    start_warp(verbose=True)
    assert "native noise" in capfd.readouterr().err
