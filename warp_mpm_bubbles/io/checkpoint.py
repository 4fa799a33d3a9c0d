"""Checkpoints: the whole simulation state after a finished frame, so `run --resume` continues a
killed run and reaches what an uninterrupted run would (bit for bit on the CPU device).

Only what a step reads from the previous one is saved: every per-particle array (effects add
theirs), the pressure (the solver's warm start), the vented gas, the effects' host state (emitter
progress), the clock and the last maximum speed (it sets the next time step). Grid arrays are
rebuilt by every step and are not saved.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np

from ..core.state import GRID_CHECKPOINT



def checkpoint_path(stage_path) -> Path:
    """The checkpoint lives with the frames: <stem>_frames/checkpoint.npz."""
    stage_path = Path(stage_path)
    return stage_path.with_name(stage_path.stem + "_frames") / "checkpoint.npz"


def _fingerprint(scene) -> str:
    """Everything that shapes the simulation; the output settings (frames, path) may differ."""
    d = scene.to_dict()
    d.pop("output", None)
    return json.dumps(d, sort_keys=True, default=str)


def save_checkpoint(sim, path) -> None:
    """Write atomically (temporary file, fsync, rename): a kill leaves the previous checkpoint.
    The temp name is this process's own; a failed write (a full disk) removes it and raises
    OSError naming `path`, keeping the previous checkpoint."""
    from .ownership import temp_path

    path = Path(path)
    tmp = temp_path(path)
    try:
        with open(tmp, "wb") as f:
            particles = sim.particles
            np.savez(f, **{f"particle_{name}": particles.numpy(name) for name in particles.fields},
                     **{name: getattr(sim.fields, name).numpy() for name in GRID_CHECKPOINT},
                     **{f"host_{name}": value for name, value in sim.host_state.items()},
                     time=sim.time, frame=sim.frame, max_speed=sim.max_particle_speed, steps=sim.stats.steps,
                     fingerprint=_fingerprint(sim.scene))
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except OSError as err:
        tmp.unlink(missing_ok=True)
        if err.filename is None or Path(err.filename) == tmp:
            err.filename = str(path)
        raise


def load_checkpoint(sim, path) -> None:
    """Restore a checkpoint into a freshly built Simulation of the same scene."""
    from ..core.simulation import SimulationError

    with np.load(path) as data:
        if str(data["fingerprint"]) != _fingerprint(sim.scene):
            raise SimulationError(f"{path} was written by a different scene (domain, materials, shapes or "
                                  f"solver settings changed); run without --resume to start over")
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
            getattr(sim.fields, name).assign(data[name])
        for name in sim.host_state:
            if f"host_{name}" in data.files:  # else (an older checkpoint) the fresh default
                sim.host_state[name] = data[f"host_{name}"].copy()
        sim.time, sim.frame = float(data["time"]), int(data["frame"])
        sim.max_particle_speed = float(data["max_speed"])
        sim.stats.steps = int(data["steps"])
