"""--resume continues only what can be continued: a changed setting is refused by name (old and new
value) before any work, a damaged checkpoint is a named error saying what is intact and how to go
on, and the run log in the output folder keeps the result and the error that stopped a run."""

import copy
import io
import os
import shutil
from pathlib import Path

import numpy as np
import pytest

from scenes import SMALL_2D
from warp_mpm_bubbles import Box, Domain, Material, Output, Scene
from warp_mpm_bubbles.cli import main
from warp_mpm_bubbles.io import runner
from warp_mpm_bubbles.io.checkpoint import CheckpointDamaged, ResumeRefused
from warp_mpm_bubbles.io.guards import FrameTooLongError
from warp_mpm_bubbles.io.usd_output import read_frames


def tiny(path, frames=2):
    """96 water particles in a 16 x 8 tank: a frame costs milliseconds."""
    return Scene(domain=Domain(size=(0.2, 0.1), cell_size=0.0125), materials={"water": Material("water")},
                 shapes=[Box("water", (0.0, 0.0), (0.05, 0.075))],
                 output=Output(path=str(path), frames=frames, fps=60), name="tiny").validate()


def run(scene, **kw):
    return runner.run_scene(scene, device="cpu", progress=False, **kw)


def snapshot(stage: Path) -> dict:
    """Every file of an output with its bytes: a refused run must leave them all as they were."""
    fdir = stage.with_name(stage.stem + "_frames")
    return {p.name: p.read_bytes() for p in [stage, *sorted(fdir.iterdir())]}


@pytest.fixture(scope="module")
def finished(tmp_path_factory):
    """A finished 2-frame output, shared: the refusals below change nothing in it."""
    stage = tmp_path_factory.mktemp("resume") / "tiny.usdc"
    scene = tiny(stage)
    run(scene)
    return scene, stage


def changed(scene, edit):
    new = copy.deepcopy(scene)
    edit(new)
    return new.validate()


CHANGES = {  # what a user might change between a run and its --resume: key, old, new (as JSON)
    "fps": (lambda s: setattr(s.output, "fps", 30.0), "[output].fps", "60.0", "30.0"),
    "format": (lambda s: setattr(s.output, "format", "points"), "[output].format", '"instancer"', '"points"'),
    "radius": (lambda s: setattr(s.output, "particle_radius", 0.004), "[output].particle_radius", "0.003125", "0.004"),
    "surface": (lambda s: setattr(s.output, "surface", True), "[output].surface", "false", "true"),
    "prototype": (lambda s: setattr(s.materials["water"], "color", (1.0, 0.0, 0.0)),
                  "[materials.water].color", "[0.2, 0.45, 0.9]", "[1.0, 0.0, 0.0]"),
    "shape": (lambda s: setattr(s.shapes[0], "max", (0.05, 0.05)), "[shapes.0].max", "[0.05, 0.075]", "[0.05, 0.05]"),
    "solver": (lambda s: setattr(s.solver, "cfl", 0.4), "[solver].cfl", "0.5", "0.4"),
}


def no_simulation(*args, **kwargs):
    pytest.fail("refused only after building the simulation: a refusal comes before any work")


@pytest.mark.parametrize("what", list(CHANGES))
def test_a_changed_setting_is_refused_by_name_and_nothing_changes(finished, monkeypatch, what):
    scene, stage = finished
    edit, key, old, new = CHANGES[what]
    before = snapshot(stage)
    monkeypatch.setattr(runner, "Simulation", no_simulation)
    with pytest.raises(ResumeRefused) as err:
        run(changed(scene, edit).replace_output(frames=4), resume=True)
    assert err.value.exit_code == 2
    assert f"{key}: {old} -> {new}" in str(err.value), str(err.value)
    assert "changed since its frames 0-2 were written" in str(err.value) and "--overwrite" in str(err.value)
    assert snapshot(stage) == before


def test_the_command_line_refuses_a_changed_fps_with_exit_2(tmp_path, capsys):
    path = tmp_path / "s.toml"
    path.write_text(SMALL_2D.format(out=(tmp_path / "s.usdc").as_posix(), frames=2))
    assert main(["run", str(path), "--quiet"]) == 0
    path.write_text(path.read_text().replace("fps = 60", "fps = 30"))
    assert main(["run", str(path), "--resume", "--num-frames", "4", "--quiet"]) == 2
    err = capsys.readouterr().err
    assert "[output].fps: 60.0 -> 30.0" in err and "internal error" not in err
    assert read_frames(tmp_path / "s.usdc")["end"] == 2  # nothing was appended


def test_a_longer_run_resumes_and_a_shorter_one_is_refused(tmp_path):
    stage = tmp_path / "tiny.usdc"
    run(tiny(stage, frames=3))
    with pytest.raises(ResumeRefused, match=r"\[output\].frames \(--num-frames\) = 2 ends before .* after frame 3"):
        run(tiny(stage, frames=2), resume=True)
    run(tiny(stage, frames=5), resume=True)
    whole = tmp_path / "whole.usdc"
    run(tiny(whole, frames=5))
    a, b = read_frames(stage)["frames"], read_frames(whole)["frames"]
    assert sorted(a) == list(range(6))
    np.testing.assert_array_equal(a[5]["positions"], b[5]["positions"])  # as if never stopped


def damage(path: Path, how: str):
    data = bytearray(path.read_bytes())
    if how == "truncated":
        data = data[: len(data) // 2]
    else:  # one flipped byte inside the first stored array: only its CRC tells
        data[200] ^= 0xFF
    path.write_bytes(bytes(data))


@pytest.mark.parametrize("how", ["truncated", "flipped byte"])
def test_a_damaged_checkpoint_names_the_intact_frames_and_the_way_on(tmp_path, monkeypatch, how):
    stage = tmp_path / "tiny.usdc"
    run(tiny(stage, frames=3))
    fdir = tmp_path / "tiny_frames"
    last = read_frames(stage)["frames"][3]["positions"]
    damage(fdir / "checkpoint.npz", how)
    with monkeypatch.context() as m, pytest.raises(CheckpointDamaged) as err:
        m.setattr(runner, "Simulation", no_simulation)
        run(tiny(stage, frames=3), resume=True)
    msg = str(err.value)
    assert err.value.exit_code == 2
    for part in ("checkpoint.npz: it is damaged", "frames 0-3 in", "are intact",
                 "checkpoint.previous.npz (after frame 2) is intact", "move checkpoint.npz out of",
                 "--resume to continue after frame 2"):
        assert part in msg, msg
    shutil.move(fdir / "checkpoint.npz", tmp_path / "damaged.npz")  # the message's advice
    run(tiny(stage, frames=3), resume=True)
    frames = read_frames(stage)["frames"]
    assert sorted(frames) == [0, 1, 2, 3]
    np.testing.assert_array_equal(frames[3]["positions"], last)  # frame 3 computed again, the same


def test_with_no_intact_checkpoint_left_the_message_says_start_over(tmp_path):
    stage = tmp_path / "tiny.usdc"
    run(tiny(stage, frames=2))
    fdir = tmp_path / "tiny_frames"
    for name in ("checkpoint.npz", "checkpoint.previous.npz"):
        damage(fdir / name, "truncated")
    with pytest.raises(CheckpointDamaged, match="No intact checkpoint is left.*--overwrite to start over"):
        run(tiny(stage, frames=2), resume=True)


def test_a_checkpoint_without_the_settings_record_is_refused(tmp_path):
    """An older checkpoint recorded only the simulation's settings: its output ones cannot be compared."""
    stage = tmp_path / "tiny.usdc"
    run(tiny(stage, frames=2))
    path = tmp_path / "tiny_frames" / "checkpoint.npz"
    with np.load(path) as data:
        old = {k: data[k] for k in data.files if k not in ("scene", "scene_sha256")}
    np.savez(path, **old)
    with pytest.raises(ResumeRefused, match="older warp_mpm_bubbles that did not record the output settings"):
        run(tiny(stage, frames=3), resume=True)


def test_a_kill_between_the_checkpoints_renames_resumes_from_the_previous_one(tmp_path):
    stage = tmp_path / "tiny.usdc"
    run(tiny(stage, frames=2))
    os.unlink(tmp_path / "tiny_frames" / "checkpoint.npz")  # moved aside, the new one not yet in place
    log = io.StringIO()
    runner.run_scene(tiny(stage, frames=3), device="cpu", log=log, resume=True)
    assert "resuming tiny after frame 1" in log.getvalue()
    assert sorted(read_frames(stage)["frames"]) == [0, 1, 2, 3]


def collapse_after_frame(n):
    """on_frame hook: once frame n is written, the step limit collapses a few steps into the next
    frame, as a gas shape at an absurd pressure makes it do, so the in-frame guard stops the run."""
    def hook(sim):
        if sim.frame != n:
            return
        honest, calls = sim.dt_limits, []

        def limits():
            calls.append(1)
            return honest() if len(calls) < 3 else {"gas_expansion": 1e-9}
        sim.dt_limits = limits
    return hook


def test_a_stopped_run_names_the_frame_it_was_computing_and_logs_it(tmp_path):
    stage = tmp_path / "tiny.usdc"
    with pytest.raises(FrameTooLongError) as err:
        runner.run_scene(tiny(stage, frames=4), device="cpu", log=io.StringIO(), on_frame=collapse_after_frame(1))
    msg = str(err.value)
    assert msg.startswith("frame 2: ") and "the run stopped computing frame 2 of 4: frames 0-1 are written" in msg
    assert sorted(read_frames(stage)["frames"]) == [0, 1]
    log = (tmp_path / "tiny_frames" / "run.log").read_text()
    assert "started: tiny" in log and "error: frame 2: " in log and "stopped computing frame 2" in log


def test_the_run_log_keeps_the_summary_even_when_quiet(tmp_path):
    stage = tmp_path / "tiny.usdc"
    run(tiny(stage, frames=2))
    run(tiny(stage, frames=3), resume=True)
    log = (tmp_path / "tiny_frames" / "run.log").read_text()
    assert "started: tiny" in log and "resumed after frame 2" in log
    assert "tiny: 3 frames to" in log and "tiny: 4 frames to" in log and "pressure CG" in log
