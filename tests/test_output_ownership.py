"""Output ownership (issue #14): a run locks its output, replaces an existing one only when asked,
deletes only files the project wrote, leaves one run's frames, and ends a full disk in a message."""

import errno
import io
import json
import os
import socket
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from pxr import Sdf

from scenes import SMALL_2D, tank_2d
from warp_mpm_bubbles.cli import main, run_example
from warp_mpm_bubbles.core.simulation import Simulation, SimulationError
from warp_mpm_bubbles.io import checkpoint as checkpoint_module
from warp_mpm_bubbles.io import runner, usd_output
from warp_mpm_bubbles.io.ownership import (MARKER, ForeignFiles, OutputError, OutputExists, OutputLock,
                                           OutputLocked, OutputWriteError, lock_path)
from warp_mpm_bubbles.io.usd_output import read_frames

ROOT = Path(__file__).resolve().parents[1]
def scene(tmp_path, frames=3, name="t.usdc"):
    return tank_2d(cells=16, out=tmp_path / name).replace_output(frames=frames).validate()


def run(sc, **kw):
    return runner.run_scene(sc, device="cpu", progress=False, **kw)


def run_id(layer_path) -> str:
    layer = Sdf.Layer.OpenAsAnonymous(str(layer_path))
    return layer.customLayerData["warp_mpm_bubbles"]["run_id"]


def assert_one_run(stage, frames):
    """The top layer and every file in _frames/ are one run's, frames 0..frames, nothing else."""
    fdir = stage.with_name(stage.stem + "_frames")
    layers = sorted(fdir.glob(f"{stage.stem}.*.usdc"))
    assert [p.name for p in layers] == [f"{stage.stem}.{f:06d}.usdc" for f in range(frames + 1)]
    top = run_id(stage)
    assert {run_id(p) for p in layers} == {top}
    assert json.loads((fdir / MARKER).read_text())["run_id"] == top
    r = read_frames(stage)
    assert (r["start"], r["end"]) == (0, frames) and sorted(r["frames"]) == list(range(frames + 1))
    assert sorted(p.name for p in fdir.iterdir()) == sorted(
        [MARKER, "checkpoint.npz", "checkpoint.previous.npz", "manifest.usdc", "run.log"]
        + [p.name for p in layers])  # no temp left
    assert not lock_path(stage).exists()
    return top


# ------------------------------------------------------------------------------------------- lock
def test_a_second_run_is_refused_at_once_naming_the_holder(tmp_path, monkeypatch):
    sc = scene(tmp_path)
    monkeypatch.setattr(runner, "Simulation", None)  # refused before any simulation work
    with OutputLock(sc.output.path):  # held by this (live) process
        with pytest.raises(OutputLocked) as err:
            run(sc)
        lock = json.loads(lock_path(sc.output.path).read_text())
    msg = str(err.value)
    for part in (f"pid {os.getpid()}", f"host {socket.gethostname()}", f"running since {lock['started']}",
                 "another run", "--stage-path"):
        assert part in msg
    assert not Path(sc.output.path).exists() and not lock_path(sc.output.path).exists()


def test_a_lock_from_another_host_is_never_taken_over(tmp_path, capsys):
    toml = tmp_path / "own.toml"
    toml.write_text(SMALL_2D.format(out=(tmp_path / "o.usdc").as_posix(), frames=2))
    lock_path(tmp_path / "o.usdc").write_text(json.dumps(
        {"host": "render-node-7", "pid": 4242, "started": "2026-12-01 20:00:00 UTC", "run_id": "x"}))
    assert main(["run", str(toml), "--quiet"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: ") and "pid 4242 on host render-node-7" in err
    assert "cannot be checked from here" in err and "Traceback" not in err
    assert lock_path(tmp_path / "o.usdc").exists() and not (tmp_path / "o.usdc").exists()


@pytest.mark.skipif(not Path("/proc/self").exists(), reason="needs Linux /proc")
def test_an_unwritable_place_is_a_named_error(tmp_path):
    with pytest.raises(OutputError, match="cannot create the lock /proc/self/none/o.usdc.lock: .*writable --stage-path"):
        usd_output.StageWriter("/proc/self/none/o.usdc", fps=24, materials=[("w", (0, 0, 1))], particle_radius=0.01)


def dead_pid() -> int:
    proc = subprocess.Popen([sys.executable, "-c", "pass"])
    proc.wait()
    return proc.pid


@pytest.mark.parametrize("holder", ["dead pid", "reused pid"])
def test_a_stale_lock_is_taken_over_with_a_line_saying_so(tmp_path, holder):
    sc = scene(tmp_path, frames=1)
    # a reused pid: this process's pid, but not the process start time the lock recorded
    pid, start = (dead_pid(), None) if holder == "dead pid" else (os.getpid(), 1)
    lock_path(sc.output.path).write_text(json.dumps(
        {"host": socket.gethostname(), "pid": pid, "proc_start": start,
         "started": "2026-12-01 20:00:00 UTC", "run_id": "old"}))
    log = io.StringIO()
    runner.run_scene(sc, device="cpu", progress=False, log=log)
    assert f"taking over the stale lock {lock_path(sc.output.path)}: pid {pid}" in log.getvalue()
    assert "no longer running" in log.getvalue()
    assert_one_run(Path(sc.output.path), 1)


def test_the_lock_is_released_on_an_interrupt_and_the_run_resumes(tmp_path, monkeypatch):
    sc = scene(tmp_path, frames=4)
    advance = Simulation.advance_frame

    def interrupted(sim, **kw):
        if sim.frame == 2:
            raise KeyboardInterrupt
        advance(sim, **kw)

    monkeypatch.setattr(Simulation, "advance_frame", interrupted)
    with pytest.raises(KeyboardInterrupt):
        run(sc)
    assert not lock_path(sc.output.path).exists()
    assert read_frames(sc.output.path)["end"] == 2
    first = run_id(sc.output.path)
    monkeypatch.setattr(Simulation, "advance_frame", advance)
    with pytest.raises(OutputExists):
        run(sc)
    run(sc, resume=True)
    assert assert_one_run(Path(sc.output.path), 4) == first  # a resumed run is the same run


# -------------------------------------------------------------------------------- existing output
def test_an_existing_output_is_refused_before_any_work_and_replaced_when_asked(tmp_path, monkeypatch):
    sc = scene(tmp_path, frames=2)
    run(sc)
    first, stamp = run_id(sc.output.path), os.stat(sc.output.path).st_mtime_ns
    with monkeypatch.context() as m:
        m.setattr(runner, "Simulation", None)  # would fail if the simulation were built
        with pytest.raises(OutputExists) as err:
            run(sc)
    for choice in ("--overwrite", "--resume", "--stage-path", "3 frames of run " + first, "nothing was changed"):
        assert choice in str(err.value)
    assert os.stat(sc.output.path).st_mtime_ns == stamp and not lock_path(sc.output.path).exists()
    run(sc, overwrite=True)
    assert assert_one_run(Path(sc.output.path), 2) != first
    with pytest.raises(SimulationError, match="exclude each other"):
        run(sc, overwrite=True, resume=True)


def test_overwrite_on_the_command_line_and_every_example_script(tmp_path, capsys):
    toml = tmp_path / "own.toml"
    out = tmp_path / "cli.usdc"
    toml.write_text(SMALL_2D.format(out=out.as_posix(), frames=1))
    assert main(["run", str(toml), "--quiet", "--device", "cpu"]) == 0
    assert run_example(toml, "d", ["--quiet", "--device", "cpu"]) == 2  # the examples share the flags
    err = capsys.readouterr().err
    assert err.startswith("error: ") and "already exists" in err and "--overwrite" in err
    assert run_example(toml, "d", ["--quiet", "--device", "cpu", "--num-frames", "2", "--overwrite"]) == 0
    assert_one_run(out, 2)


@pytest.mark.parametrize("case", ["foreign file in _frames", "folder without marker", "foreign stage file"])
def test_files_the_project_did_not_write_are_never_deleted(tmp_path, case):
    sc = scene(tmp_path, frames=1)
    stage = Path(sc.output.path)
    fdir = stage.with_name("t_frames")
    if case == "foreign file in _frames":
        run(sc)
        user = fdir / "notes.txt"
    elif case == "folder without marker":
        fdir.mkdir()
        user = fdir / "t.000000.usdc"  # a name the project uses, but no marker: not ours
    else:
        user = stage
    user.write_text("the user's work")
    before = sorted(p.name for p in tmp_path.rglob("*"))
    for overwrite in (False, True):
        with pytest.raises(ForeignFiles) as err:
            run(sc, overwrite=overwrite)
        assert user.name in str(err.value) and "never replaced or deleted" in str(err.value)
    assert user.read_text() == "the user's work"
    assert sorted(p.name for p in tmp_path.rglob("*")) == before


def test_resume_keeps_foreign_files_and_never_rewrites_a_foreign_stage(tmp_path):
    sc = scene(tmp_path, frames=1)
    run(sc)
    notes = Path(sc.output.path).with_name("t_frames") / "notes.txt"
    notes.write_text("the user's work")
    run(sc.replace_output(frames=2), resume=True)
    assert notes.read_text() == "the user's work" and read_frames(sc.output.path)["end"] == 2
    Path(sc.output.path).write_text("the user's stage")
    with pytest.raises(ForeignFiles, match="cannot be resumed: it was not written by this project"):
        run(sc.replace_output(frames=3), resume=True)
    assert Path(sc.output.path).read_text() == "the user's stage" and notes.exists()


def test_a_shorter_rerun_leaves_exactly_one_run(tmp_path):
    """The 30-then-10-frames row of the issue, at 6 then 2 frames."""
    sc = scene(tmp_path, frames=6)
    first = assert_one_run(Path(run(sc).stage_path), 6)
    second = assert_one_run(Path(run(sc.replace_output(frames=2), overwrite=True).stage_path), 2)
    assert second != first
    top = Sdf.Layer.OpenAsAnonymous(sc.output.path)
    clips = top.GetPrimAtPath("/World").GetInfo("clips")["default"]
    assert (clips["templateStartTime"], clips["templateEndTime"]) == (0, 2)
    with np.load(Path(sc.output.path).with_name("t_frames") / "checkpoint.npz") as ck:
        assert int(ck["frame"]) == 2


KILL_LEFTOVERS = ("t.000002.tmp-999-abcdef.usdc", "t.000002.tmp-999-abcdef.Xy12Zq",  # ours, USD's temp
                  "checkpoint.tmp-999-abcdef.npz", "t.tmp-999-0a1b2c.usdc")


@pytest.mark.parametrize("how", ["overwrite", "resume"])
def test_temp_files_a_killed_run_left_are_the_projects_own(tmp_path, how):
    sc = scene(tmp_path, frames=2)
    run(sc)
    fdir = Path(sc.output.path).with_name("t_frames")
    for name in KILL_LEFTOVERS:
        (fdir / name).write_bytes(b"half")
    run(sc.replace_output(frames=3), **{how: True})
    assert_one_run(Path(sc.output.path), 3)  # also: no temp left


# ------------------------------------------------------------------------------------ full disk
def test_a_full_disk_during_a_frame_is_a_named_error_keeping_the_finished_frames(tmp_path, monkeypatch):
    sc = scene(tmp_path, frames=5)
    export = usd_output._atomic_export

    def full(layer, path, tmp_dir=None):
        if path.name == "t.000003.usdc":
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(path))
        export(layer, path, tmp_dir)

    monkeypatch.setattr(usd_output, "_atomic_export", full)
    with pytest.raises(OutputWriteError) as err:
        run(sc)
    msg = str(err.value)
    for part in ("t_frames/t.000003.usdc", "no space left on device", " free on the disk holding",
                 "frames up to 2 are finished and kept", "--resume to continue after frame 2"):
        assert part in msg
    assert isinstance(err.value, SimulationError) and err.value.exit_code == 1
    assert sorted(read_frames(sc.output.path)["frames"]) == [0, 1, 2] and not lock_path(sc.output.path).exists()
    monkeypatch.setattr(usd_output, "_atomic_export", export)  # space freed
    run(sc, resume=True)
    assert_one_run(Path(sc.output.path), 5)


def test_a_full_disk_during_a_checkpoint_keeps_the_previous_one(tmp_path, monkeypatch):
    sc = scene(tmp_path, frames=4)
    savez, calls = np.savez, []

    def full(f, **arrays):
        calls.append(1)
        if len(calls) == 3:  # the checkpoint of frame 2
            f.write(b"partial")
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        savez(f, **arrays)

    monkeypatch.setattr(checkpoint_module.np, "savez", full)
    with pytest.raises(OutputWriteError) as err:
        run(sc)
    assert "t_frames/checkpoint.npz: no space left on device" in str(err.value)
    assert "frames up to 2 are finished and kept" in str(err.value)
    assert "continue after frame 1" in str(err.value)  # the checkpoint on disk is frame 1's
    fdir = Path(sc.output.path).with_name("t_frames")
    assert not list(fdir.glob("*.tmp-*"))  # the half-written temp was removed
    with np.load(fdir / "checkpoint.npz") as ck:
        assert int(ck["frame"]) == 1


def test_a_usd_write_error_becomes_an_os_error_naming_the_file(tmp_path):
    """A real failed write (a file size limit: EFBIG, as ENOSPC would) inside USD's exporter."""
    code = ("import resource, signal, sys, numpy as np\n"
            "sys.path.insert(0, 'tests')\n"
            "from _slow_writer import MATERIALS, frame_data\n"
            "from warp_mpm_bubbles.io.usd_output import StageWriter\n"
            "signal.signal(signal.SIGXFSZ, signal.SIG_IGN)\n"
            f"w = StageWriter({str(tmp_path / 's.usdc')!r}, fps=24, materials=MATERIALS, particle_radius=0.01)\n"
            "w.write_frame(0, *frame_data(0, 10))\n"
            "resource.setrlimit(resource.RLIMIT_FSIZE, (20000, resource.RLIM_INFINITY))\n"
            "try:\n"
            "    w.write_frame(1, *frame_data(1, 5000))\n"
            "except OSError as err:\n"
            "    print(err.errno, err.filename)\n")
    out = subprocess.run([sys.executable, "-c", code], cwd=ROOT, env=dict(os.environ, PYTHONPATH=str(ROOT)),
                         capture_output=True, text=True, timeout=120)
    assert out.stdout.split() == [str(errno.EFBIG), str(tmp_path / "s_frames" / "s.000001.usdc")], out.stderr
    assert sorted(p.name for p in (tmp_path / "s_frames").iterdir()) == [MARKER, "manifest.usdc", "s.000000.usdc"]
    assert read_frames(tmp_path / "s.usdc")["end"] == 0


# ---------------------------------------------------------------------------------- concurrency
def test_two_runs_half_a_second_apart_one_completes_the_other_refuses(tmp_path):
    toml = tmp_path / "own.toml"
    out = tmp_path / "race.usdc"
    toml.write_text(SMALL_2D.format(out=out.as_posix(), frames=8))
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    cmd = [sys.executable, "-m", "warp_mpm_bubbles.cli", "run", str(toml), "--quiet", "--device", "cpu"]
    first = subprocess.Popen(cmd, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    time.sleep(0.5)
    second = subprocess.Popen(cmd, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    results = [(p.wait(timeout=300), p.communicate()[1]) for p in (first, second)]
    assert sorted(rc for rc, _ in results) == [0, 2], results
    for rc, err in results:
        assert "Traceback" not in err
        if rc == 2:  # refused: by the lock while the other ran, or the output it had finished
            assert err.startswith("error: ") and ("being written by another run" in err or "already exists" in err)
    assert_one_run(out, 8)
