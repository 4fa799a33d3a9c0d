"""Run many scene files through the command line's `main(["run", ...])` in ONE process (Warp's start
and kernel loading cost seconds; a scene of the fuzz costs a fraction of one), one JSON line per scene.

    python tests/run_fuzz_worker.py [--scene-seconds=N] JOBS.json RESULTS.jsonl

JOBS.json is a list of {"scene": path, "argv": [extra flags], "tag": a name the result carries}.
Each result line holds the scene, its tag, the exit code ("hang" when it ran past --scene-seconds),
the captured stdout and stderr, the wall seconds and, for every frame the run wrote, what the test
cannot read from the USD file: a hash of the state, the liquid's rest volume (mass / density: what
entered and stayed), the volume it occupies (Simulation.liquid_volume), the liquid's mass budget
(what left through open walls), with a two-way head the liquid its films hold and its water is
owed and what its foam carried out through open walls, the gas budget's total and volume, what the
emitters have emitted so far and the volume each stream delivered. Measuring does not change the run (the grid that
liquid_volume re-splats is rebuilt every step): the USD it writes matched a plain `run`'s bit for
bit on a scene with gas, tension and an injector. tests/test_run_fuzz.py starts it with a timeout,
so even a hang inside a kernel (where no alarm fires) is caught and named: the first scene
without a result line.
"""

from __future__ import annotations

import contextlib
import hashlib
import io
import json
import signal
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))


class SceneHang(BaseException):
    """Raised by the alarm; a BaseException so the CLI's guard (which turns an Exception into exit 3)
    lets it through."""


def frame_metrics(sim) -> dict:
    """What a frame holds that the USD file does not: rest and occupied liquid volume, gas, emitters."""
    p = sim.particles_numpy()
    mats = list(sim.scene.materials.values())
    density = np.array([m.density for m in mats])
    liquid_material = np.array([m.kind == "liquid" for m in mats])
    liquid = (p["phase"] == 0) & liquid_material[p["material"]]
    rest_each = p["mass"][liquid].astype(np.float64) / density[p["material"][liquid]]
    rest = float(rest_each.sum())
    # liquid flying above an open top (outside the box; no grid splats it, so it occupies no cell)
    hi = np.array(sim.grid.domain_size[:sim.grid.dim])
    x = p["positions"][liquid][:, :sim.grid.dim]
    flying = ((x < 0.0) | (x > hi)).any(1)
    budget = sim.mass_budget()["liquid"]
    emitters = sim.stage("emitters")
    emitted, inflow = (emitters.state.progress, emitters.state.inflow) if emitters else (None, None)
    # A two-way head (effects/foam_head.py) takes its films' liquid out of the water's particles and
    # gives it back as new ones: the liquid its films hold and what its columns' water is owed
    # (signed: negative while the films owe the water liquid not yet taken from it) belong to the
    # liquid's rest volume; water + films + owed is what it keeps constant. One-way foam leaves the
    # water's particles alone, and its films' liquid is no part of it.
    foam = sim.stage("foam")
    head = foam.liquid_budget(sim.ctx) if foam is not None and foam.head is not None else None
    state = hashlib.sha1(p["positions"].tobytes() + p["velocities"].tobytes() + p["ids"].tobytes())
    return {
        "state_sha1": state.hexdigest(),  # the same scene must give the same state (CPU determinism)
        "frame": int(sim.frame), "time": float(sim.time), "particles": int(len(p["ids"])),
        "liquid_rest_volume": rest,
        "liquid_occupied_volume": float(sim.liquid_volume()),
        "liquid_flying_volume": float(rest_each[flying].sum()),
        "liquid_in_head": 0.0 if head is None else head["held"] + head["owed"],
        "liquid_left_in_foam": 0.0 if head is None else head.get("left", 0.0),  # films gone through open walls
        "liquid_left_mass": budget["left"], "liquid_added_mass": budget["added"], "liquid_mass_error": budget["error"],
        "gas_total": float(sim.gas_budget()["total"]) if sim.has_gas else None,
        "gas_volume": float(sim.gas_budget()["volume"]) if sim.has_gas else 0.0,
        "emitted": None if emitted is None else np.asarray(emitted)[:, 1].astype(int).tolist(),
        # per emitter, the rest volume its stream delivered (a blocked nozzle: less than it owed)
        "delivered": None if inflow is None else np.asarray(inflow)[:, 1].tolist(),
        "dx": float(sim.grid.dx),
    }


def run_one(scene: str, argv: list[str], seconds: int) -> dict:
    from warp_mpm_bubbles import cli
    from warp_mpm_bubbles.io import runner

    frames = []
    original = runner.run_scene

    def run_scene(scene_obj, **kw):  # the CLI imports run_scene from the module at call time
        kw["on_frame"] = lambda sim: frames.append(frame_metrics(sim))
        return original(scene_obj, **kw)

    out, err = io.StringIO(), io.StringIO()
    start = time.perf_counter()

    def hang(*_):
        raise SceneHang()

    old = signal.signal(signal.SIGALRM, hang)
    signal.alarm(seconds)
    runner.run_scene = run_scene
    try:
        with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
            try:
                code = cli.main(["run", scene, *argv])
            except SystemExit as exit_:  # argparse
                code = exit_.code
    except SceneHang:
        code = "hang"
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, old)
        runner.run_scene = original
    return {"scene": scene, "argv": argv, "code": code, "stdout": out.getvalue(), "stderr": err.getvalue(),
            "seconds": time.perf_counter() - start, "frames": frames}


def main(args: list[str]) -> int:
    seconds = 120
    if args and args[0].startswith("--scene-seconds="):
        seconds = int(args.pop(0).split("=", 1)[1])
    jobs, results = json.loads(Path(args[0]).read_text()), args[1]
    import warp as wp

    wp.config.quiet = True
    wp.init()
    with open(results, "a") as f:
        for spec in jobs:
            line = run_one(spec["scene"], spec.get("argv", []), seconds)
            line["tag"] = spec.get("tag", "")
            f.write(json.dumps(line) + "\n")
            f.flush()
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
