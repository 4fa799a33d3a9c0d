"""Checkpoints: the whole simulation state after a finished frame, so `run --resume` continues a
killed run and reaches what an uninterrupted run would (bit for bit on the CPU device).

Only what a step reads from the previous one is saved: every per-particle array (effects add
theirs), the pressure (the solver's warm start), the vented gas, the host values of the core and
of each stage (`Simulation.state_arrays`: the next id, emitter progress, ...), the clock and the last maximum speed (it sets the next time step). Grid arrays are
rebuilt by every step and are not saved.

Each checkpoint also records the scene that wrote it (every setting, the output's included, but the
frame count), so a resume under any other setting is refused naming the field: the frames already
written were made with the old one, and a file that mixes two frame rates, formats or radii is
wrong without any error. The previous checkpoint is kept beside the newest one
(checkpoint.previous.npz): if the newest is damaged after the fact (a disk error, a copy cut short),
the run can still go on from the one before it.
"""

from __future__ import annotations

import hashlib
import json
import os
import zipfile
from pathlib import Path

import numpy as np

from ..core.simulation import SimulationError
from ..core.state import GRID_CHECKPOINT
from .ownership import frame_number, frames_dir

_NOT_SET = "(not set)"


class ResumeRefused(SimulationError):
    """--resume cannot continue this output as asked; nothing was changed."""

    exit_code = 2  # a refusal before any work, like a bad scene


class CheckpointDamaged(ResumeRefused):
    """The checkpoint file cannot be read back whole (truncated, corrupted)."""


def checkpoint_path(stage_path) -> Path:
    """The checkpoint lives with the frames: <stem>_frames/checkpoint.npz."""
    return frames_dir(stage_path) / "checkpoint.npz"


def previous_path(path) -> Path:
    """The checkpoint before `path` (one frame older), kept until a newer one is complete."""
    path = Path(path)
    return path.with_name(f"{path.stem}.previous{path.suffix}")


def scene_record(scene) -> dict:
    """Every setting that shapes the output, as plain data: the whole scene but the frame count
    (a longer run may resume) and the output's folder (the output may have been moved)."""
    d = scene.to_dict()
    d["output"].pop("frames", None)
    d["output"]["path"] = Path(str(d["output"]["path"])).name
    return json.loads(json.dumps(d, sort_keys=True, default=str))


def save_checkpoint(sim, path) -> None:
    """Write atomically (temporary file, fsync, rename), moving the checkpoint it replaces to
    previous_path(path) first: a kill at any moment leaves an intact checkpoint. The temp name is
    this process's own; a failed write (a full disk) removes it and raises OSError naming `path`,
    keeping the previous checkpoint."""
    from .ownership import temp_path

    path = Path(path)
    tmp = temp_path(path)
    record = json.dumps(scene_record(sim.scene), sort_keys=True)
    try:
        with open(tmp, "wb") as f:
            particles = sim.particles
            np.savez(f, **{f"particle_{name}": particles.numpy(name) for name in particles.fields},
                     **{name: getattr(sim.fields, name).numpy() for name in GRID_CHECKPOINT},
                     **{f"host_{name}": value for name, value in sim.state_arrays().items()},
                     time=sim.time, frame=sim.frame, max_speed=sim.max_particle_speed, steps=sim.stats.steps,
                     scene=record, scene_sha256=hashlib.sha256(record.encode()).hexdigest())
            f.flush()
            os.fsync(f.fileno())
        if path.exists():  # between these renames only the previous one exists: resume finds it
            os.replace(path, previous_path(path))
        os.replace(tmp, path)
    except OSError as err:
        tmp.unlink(missing_ok=True)
        if err.filename is None or Path(err.filename) == tmp:
            err.filename = str(path)
        raise


def _read_header(path: Path) -> tuple[int, dict | None]:
    """The frame a checkpoint resumes after and the scene it recorded (None: an older checkpoint
    without one), after checking every stored array against its CRC; raises the reading error."""
    with zipfile.ZipFile(path) as z:
        bad = z.testzip()
        if bad is not None:
            raise zipfile.BadZipFile(f"{bad} fails its CRC check")
    with np.load(path) as data:
        record = json.loads(str(data["scene"])) if "scene" in data.files else None
        return int(data["frame"]), record


_READ_ERRORS = (OSError, ValueError, EOFError, KeyError, zipfile.BadZipFile)


def _damaged(path: Path, err: Exception, stage_path) -> CheckpointDamaged:
    """What is intact and how to go on, for a checkpoint that cannot be read."""
    path = Path(path)
    stem = Path(stage_path).stem
    on_disk = sorted(n for n in (frame_number(e.name, stem) for e in path.parent.iterdir()) if n is not None) \
        if path.parent.is_dir() else []
    frames = f"frames {on_disk[0]}-{on_disk[-1]} in {path.parent} are intact (each frame file is written whole " \
             f"before its checkpoint)" if on_disk else f"no frame files are in {path.parent}"
    msg = f"cannot resume from {path}: it is damaged ({type(err).__name__}: {err}); {frames}"
    prev = previous_path(path)
    try:
        prev_frame = _read_header(prev)[0] if prev.exists() and prev != path else None
    except _READ_ERRORS:
        prev_frame = None
    if prev_frame is not None:
        return CheckpointDamaged(f"{msg}. The previous checkpoint {prev.name} (after frame {prev_frame}) is "
                                 f"intact: move {path.name} out of {path.parent} and run the same command with "
                                 f"--resume to continue after frame {prev_frame} (later frames are computed again)")
    return CheckpointDamaged(f"{msg}. No intact checkpoint is left to continue from: run with --overwrite to "
                             f"start over, or with another --stage-path to keep these frames")


def _flatten(value, table: str = "", out: dict | None = None) -> dict:
    """{'[output].fps': 30.0, '[shapes.1].radius': 0.01, 'name': ...}: each setting by the key a
    scene file spells it with."""
    out = {} if out is None else out
    items = value.items() if isinstance(value, dict) else enumerate(value)
    for k, v in items:
        sub = f"{table}.{k}" if table else str(k)
        if isinstance(v, dict) or (isinstance(v, list) and v and all(isinstance(x, dict) for x in v)):
            _flatten(v, sub, out)
        else:
            out[f"[{table}].{k}" if table else str(k)] = v
    return out


def _show(v) -> str:
    return _NOT_SET if v is _NOT_SET else json.dumps(v)


# Settings added since checkpoints were first written, each with the value that gives what older
# versions did (bit for bit): a checkpoint that does not record one ran with that value.
ADDED_SETTINGS = {"[solver].volume_fill": "cell", "[solver].volume_correction_moves": "velocities"}


def check_same_settings(old: dict | None, scene, path, after: int) -> None:
    """Refuse (ResumeRefused) a resume whose scene differs from the one that wrote the checkpoint
    at `path` (after frame `after`), naming each changed field with its old and new value."""
    if old is None:
        raise ResumeRefused(f"cannot resume from {path}: it was written by an older warp_mpm_bubbles that did "
                            f"not record the output settings ([output].fps, format, particle_radius, ...), so a "
                            f"changed one could not be caught; run without --resume (with --overwrite) to start over")
    a, b = {**ADDED_SETTINGS, **_flatten(old)}, _flatten(scene_record(scene))
    changed = [(k, a.get(k, _NOT_SET), b.get(k, _NOT_SET)) for k in sorted(set(a) | set(b))
               if a.get(k, _NOT_SET) != b.get(k, _NOT_SET)]
    if not changed:
        return
    shown = "; ".join(f"{k}: {_show(was)} -> {_show(now)}" for k, was, now in changed[:8])
    more = f"; and {len(changed) - 8} more" if len(changed) > 8 else ""
    raise ResumeRefused(
        f"cannot resume {scene.output.path}: {len(changed)} setting{'s' * (len(changed) != 1)} changed since "
        f"its frames 0-{after} were written: {shown}{more}. A resumed run must go on with the settings that "
        f"wrote its first frames (a file mixing two would be wrong without any error): put the old "
        f"value{'s' * (len(changed) != 1)} back, or run without --resume (with --overwrite) to start over with "
        f"the new ones. Only [output].frames (--num-frames) may grow")


def resumable_checkpoint(scene, stage_path) -> Path:
    """The checkpoint `run --resume` continues from, checked before any work: readable whole, written
    by this very scene (every setting but the frame count), and not past the last frame asked for.
    Falls back to the previous checkpoint when the newest is missing (a kill between the renames)."""
    path = checkpoint_path(stage_path)
    if not path.exists():
        if not previous_path(path).exists():
            raise SimulationError(f"nothing to resume: no checkpoint at {path}; run without --resume")
        path = previous_path(path)
    try:
        after, record = _read_header(path)
    except _READ_ERRORS as err:
        raise _damaged(path, err, stage_path) from None
    check_same_settings(record, scene, path, after)
    if after > scene.output.frames:
        raise ResumeRefused(f"[output].frames (--num-frames) = {scene.output.frames} ends before the checkpoint "
                            f"{path}, which is after frame {after}: give --num-frames {after} or more to resume, "
                            f"or run without --resume (with --overwrite) to start over")
    return path


def load_checkpoint(sim, path) -> None:
    """Restore a checkpoint into a freshly built Simulation of the same scene (ResumeRefused when
    any setting differs; CheckpointDamaged when the file cannot be read)."""
    try:
        with np.load(path) as data:
            record = json.loads(str(data["scene"])) if "scene" in data.files else None
            check_same_settings(record, sim.scene, path, int(data["frame"]))
            _restore(sim, data)
    except _READ_ERRORS as err:
        raise _damaged(Path(path), err, sim.scene.output.path) from None


def _restore(sim, data) -> None:
    n = data["particle_x"].shape[0]  # emitters add particles, compaction removes retired ones
    particles = sim.particles
    particles.reserve(n)
    particles.count = n
    for name in particles.fields:
        if f"particle_{name}" in data.files:
            getattr(particles, name)[:n].assign(data[f"particle_{name}"])
        else:  # a stage's field an older checkpoint lacks (cavity_gas): zero, its fresh default
            getattr(particles, name)[:n].zero_()
        if n < particles.capacity:  # beyond the count stays zero (appends rely on it)
            getattr(particles, name)[n:].zero_()
    for name in GRID_CHECKPOINT:
        if name in data.files:
            getattr(sim.fields, name).assign(data[name])
        else:  # a field an older checkpoint lacks (correction_potential): zero, its fresh value
            getattr(sim.fields, name).zero_()
    # The core's and the stages' host values by name (an older checkpoint's missing ones keep their fresh value).
    sim.load_state({name[len("host_"):]: data[name] for name in data.files if name.startswith("host_")})
    sim.time, sim.frame = float(data["time"]), int(data["frame"])
    sim.max_particle_speed = float(data["max_speed"])
    sim.stats.steps = int(data["steps"])
