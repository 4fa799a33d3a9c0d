"""A fuzz of whole runs: small generated scenes (tests/run_fuzz_scenes.py: 2D and 3D, every wall type,
liquid and gas shapes, emitters, foam, sub-grid bubbles, colliders, now and then a bad value) go
through `warp-mpm-bubbles run` (the CLI's main, many scenes in one worker process:
tests/run_fuzz_worker.py), and every run is held to what a user may expect of it:

- exit 0, 1 or 2; never 3 (a bug), a traceback, or a hang (an alarm per scene, and a timeout on the
  worker for a hang no alarm interrupts);
- exit 2: one `error:` line naming a key (`[shapes.0].radius`) or the cause, and no output created;
  a scene given a bad value must be refused under that value's key;
- exit 1: an `error:` line naming the key to change; the frames already written are whole (the file
  opens, the frames are the run's first ones, each has every attribute);
- exit 0: every frame asked for; every position finite and inside the domain; every speed under
  speed_bound (gravity, pressure, emitters, colliders, tension, the volume correction); the liquid's
  rest volume (with a two-way head, its films' liquid and what its water is owed counted in) equal
  to what the shapes seeded plus what the streams delivered (the emitters' ledger,
  at most what their layers owe: a blocked nozzle delivers less; check_delivered), and no
  more than the box holds; the room it occupies not squeezed below its rest volume (COMPRESSION);
  liquid and gas together within the box (FILL_TOLERANCE); the gas budget's total constant (growing
  only by what injectors add);
- every REPEAT_EVERY-th scene also runs again (the same state in every frame: CPU determinism) and
  once for one frame, then --resume to the end (the uninterrupted run's state from frame 2 on).

Open walls are outflows: liquid that left through them (Simulation.mass_budget) is taken from what
must remain, and the mass budget must close; liquid thrown through an open top flies above the box
(the only place a particle may be outside it) and falls back.

Size: CI_SCENES (200) scenes, with every tenth run three times more: 24-33 s with Warp's kernels
cached on two cores, 46 s compiling every kernel module first (an empty WARP_CACHE_PATH), up to about
70 s while other jobs load the machine; 1000 scenes took 192 s. The `slow` test runs the next
SLOW_SCENES (200; WARP_MPM_BUBBLES_RUN_FUZZ_SCENES sets it, e.g. 1000 for a longer hunt). A failure lists every failing scene with its reasons; the scene files
stay under pytest's tmp directory, and run_fuzz_scenes.generate(index, path) makes scene `index`
again. test_scenes_the_fuzz_found holds the failures it found, reduced to a few lines each, to the
same checks.
"""

from __future__ import annotations

import json
import math
import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from run_fuzz_scenes import HARD_SCENES, generate
from warp_mpm_bubbles.scene.effects import GasInjector, LiquidInflow
from warp_mpm_bubbles.scene.model import load_scene

HERE = Path(__file__).resolve().parent
CI_SCENES = 200  # its cost: the module docstring
# The slow test runs the next SLOW_SCENES scenes (disjoint from CI's); more for a longer hunt.
SLOW_SCENES = int(os.environ.get("WARP_MPM_BUBBLES_RUN_FUZZ_SCENES", "200"))
# A scene costs well under a second (about 10 s when it compiles a kernel module): past this, a hang.
SCENE_SECONDS = int(os.environ.get("WARP_MPM_BUBBLES_RUN_FUZZ_SCENE_SECONDS", "120"))
KEY = re.compile(r"\[[A-Za-z_]+(\.[A-Za-z0-9_]+)?\](\.[A-Za-z_]+)*")  # [domain].size, [shapes.1].radius, [effects.foam]
# Positions: the transfers clamp particles to [1e-4 dx, size - 1e-4 dx]; float32 rounding of a
# coordinate under 1 m is below 1e-7 m, so 1e-6 of the domain's size allows only rounding.
POSITION_TOLERANCE = 1e-6
# Rest volume (mass / density of the liquid particles): masses are float32, summed in float64, so
# the total is exact to a few 1e-7; 1e-5 allows only rounding, never a lost or created particle.
REST_VOLUME_TOLERANCE = 1e-5
# Occupied volume (Simulation.liquid_volume: sum of min(phi, 1) dx^3) is below the rest volume only
# where particles crowd a cell (phi > 1). Measured over 268 generated runs: 0.976-1.000 of the rest
# volume at frame 0 (jittered seeding; median 0.989); in closed boxes with nothing entering, at least
# 0.948 in any frame (a column collapsing at 4.4 g, preview quality), except where a collider was
# driven into a full box (0.43). Squeezed 10% (twice the worst drift seen) is compressed water.
COMPRESSION = 0.1
# Liquid and resolved gas together (rest volume + the gas's vol0 J) cannot exceed the box. A box
# filled by its shapes holds them to the float rounding of the seeded volumes; the gas's J follows
# its own law, tracked in float32 and relaxed by the volume correction like the liquid (about 1%
# drift in the README's dam break): 2% above the box is a fluid squeezed into it.
FILL_TOLERANCE = 0.02
# A gas injector pushes water aside to make room for each bubble; the pushed water is crowded until
# the volume correction relaxes it (its tau, 10 ms), so a run that injects faster than that holds
# liquid and gas above the box for a while: measured 1.031 and 1.041 of the box at the first frame
# (scenes 103 and 107: 220 and 110 bubbles/s, each 5-6% of the box), within it by the next. 5% is
# the fill guard's bound (io/fill.py); feeding the bubbles to the pressure solve would remove it.
FILL_TOLERANCE_INJECTING = 0.05


# --------------------------------------------------------------------------------------- bounds
def speed_bound(scene, t: float) -> tuple[float, dict]:
    """The fastest any particle may move at time t, with its terms (m/s). Each is the most one cause
    can give; they are added as if all acted on the same particle in the same direction:

    - initial: the fastest shape's speed (the pressure solve only redistributes it);
    - gravity: free fall, |g| t, or what falling the domain's height gives, sqrt(2 |g| H) (Torricelli:
      a collapsing column's toe is pushed by the head above it, faster than free fall at first),
      doubled for gas: a bubble's added mass is half the liquid it displaces (3D), so it rises at up to
      twice the speed its buoyancy would give a body of that liquid;
    - pressure: a gas shape's gauge pressure drives the liquid at Bernoulli's sqrt(2 |p| / rho);
    - emitters: the fastest stream's speed or injected bubble's velocity;
    - colliders: twice the fastest collider's speed (the potential flow past a cylinder peaks at 2 U);
    - capillary: the grid's fastest capillary wave, sqrt(pi sigma / (rho dx)) (wavelength 2 dx);
    - correction: the volume correction undoes a cell's over-fill within its relaxation time tau,
      so it moves particles at most dx / tau.

    Measured over 715 frames of 320 generated runs: the fastest particle reached at most 0.75 of
    it. Without the Torricelli term and the gas's doubling (v0 + |g| t + emitters + 2 colliders +
    pressure + capillary + correction), 7 frames of 6 runs exceed, by up to 1.47x: colliders
    squeezing liquid (a glass driven into a full box, two glasses into each other), gas injected
    faster than the box lets the liquid out, a strip falling at 4 g onto an open floor.
    So the bound catches a blow-up or a thrown particle, not a speed off by a factor under 2
    (speeds scaled by 3 in the output fail 7 of 120 scenes that passed; by 50, 30 of 40).
    """
    d, mats = scene.domain, scene.materials.values()
    g = math.hypot(*d.gravity)
    up = int(np.argmax(np.abs(d.gravity))) if g > 0 else 0
    rho = min(m.density for m in mats if m.kind == "liquid")
    sigma = max(m.surface_tension for m in mats)
    has_gas = any(m.is_gas for m in mats)
    gauge = max((abs(s.pressure) for s in scene.shapes if s.pressure), default=0.0)
    tau = scene.solver.volume_relaxation(d.dx)
    terms = {
        "initial": max((math.hypot(*s.velocity) for s in scene.shapes), default=0.0),
        "gravity": (2.0 if has_gas else 1.0) * max(g * t, math.sqrt(2.0 * g * d.size[up])),
        "pressure": math.sqrt(2.0 * gauge / rho),
        "emitters": max((e.speed if isinstance(e, LiquidInflow) else math.hypot(*e.velocity)
                         for e in scene.emitters), default=0.0),
        "colliders": 2.0 * max((c.speed_between(0.0, t) for c in scene.colliders), default=0.0),
        "capillary": math.sqrt(math.pi * sigma / (rho * d.dx)),
        "correction": d.dx / tau if tau > 0 else 0.0,
    }
    return sum(terms.values()), terms


def stream_volume(scene, i: int, layers: int, dx: float) -> float:
    """The rest volume emitter i's stream owes for `layers` layers (effects/emitters.py: a layer of a
    stream of radius r is 2 r h dx in 2D (the slab is one cell thick), pi r^2 h in 3D, h the particle
    spacing); a nozzle whose cells are full delivers less."""
    e = scene.emitters[i]
    h = dx / scene.solver.particles_per_cell ** (1.0 / scene.dim)
    area = 2.0 * e.radius * dx if scene.dim == 2 else math.pi * e.radius**2
    return layers * area * h


def liquid_entered(scene, emitted: list[int] | None, dx: float) -> float:
    """The rest volume the streams owed, from the layers each emitted: what entered where none was blocked."""
    return sum(stream_volume(scene, i, emitted[i] if emitted else 0, dx)
               for i, e in enumerate(scene.emitters) if isinstance(e, LiquidInflow))


def check_delivered(scene, m) -> tuple[float, list[str]]:
    """(the rest volume the streams delivered by frame m, by the emitters' ledger; the problems): each
    stream delivers at most what its layers owe (a blocked nozzle less, never more)."""
    if m.get("delivered") is None:
        return liquid_entered(scene, m["emitted"], m["dx"]), []
    problems = []
    for i, e in enumerate(scene.emitters):
        owed = stream_volume(scene, i, m["emitted"][i], m["dx"]) if isinstance(e, LiquidInflow) else 0.0
        if m["delivered"][i] > owed * (1.0 + 1e-9) + 1e-300:
            problems.append(f"frame {m['frame']}: emitter {i} delivered {m['delivered'][i]:.6g} m^3, more than "
                            f"the {owed:.6g} m^3 its {m['emitted'][i]} layers owe")
    return sum(m["delivered"]), problems


def expected_layers(scene, i: int, t: float, dx: float) -> float:
    """A stream emits one layer per particle spacing h it flows: by time t, speed * active time / h,
    give or take one (the step that crosses a layer boundary)."""
    e = scene.emitters[i]
    h = dx / scene.solver.particles_per_cell ** (1.0 / scene.dim)
    stop = math.inf if e.stop is None else e.stop
    return e.speed * max(0.0, min(t, stop) - e.start) / h


# ------------------------------------------------------------------------------------- checks
def check_refusal(result, bad_key, out_dir: Path) -> list[str]:
    """Exit 2: one error line naming a key (a bad value: its key) or the cause; nothing written."""
    problems = []
    err = result["stderr"]
    if "error:" not in err:
        problems.append(f"exit 2 without an 'error:' line: {err[:200]!r}")
    if bad_key and bad_key not in err:
        problems.append(f"refused, but not under the bad value's key {bad_key}: {err[:300]!r}")
    if not bad_key and not KEY.search(err) and "no fluid to simulate" not in err:
        problems.append(f"exit 2 naming no key and no known cause: {err[:300]!r}")
    if out_dir.exists():  # the scene's output folder does not exist before the run
        left = sorted(p.name for p in out_dir.iterdir())
        problems.append(f"exit 2, yet the output folder {'holds ' + str(left) if left else 'was created (empty)'}: "
                        f"a refusal must create nothing")
    return problems


def read_usd(path):
    from warp_mpm_bubbles.io.usd_output import read_frames

    return read_frames(path)


def check_stopped(result, scene) -> list[str]:
    """Exit 1: the message says what stopped; the frames written so far are whole."""
    problems = []
    if "error:" not in result["stderr"]:
        problems.append(f"exit 1 without an 'error:' line: {result['stderr'][:200]!r}")
    elif not KEY.search(result["stderr"]):  # a stop names the setting to change ([solver].cfl, ...)
        problems.append(f"exit 1 naming no key to change: {result['stderr'][-300:]!r}")
    path = Path(scene.output.path)
    if path.exists():
        try:
            data = read_usd(path)
        except Exception as err:  # noqa: BLE001 (any failure to read is the finding)
            return problems + [f"exit 1 left an output that does not open: {type(err).__name__}: {err}"]
        if sorted(data["frames"]) != list(range(len(data["frames"]))):
            problems.append(f"exit 1 left frames {sorted(data['frames'])}: not the run's first ones in order")
        for t, f in data["frames"].items():
            n = len(f["ids"])
            if any(f[k] is None or len(f[k]) != n for k in ("positions", "velocities", "proto_indices")):
                problems.append(f"exit 1 left frame {t} partial: {[(k, None if f[k] is None else len(f[k])) for k in f]}")
    return problems


def check_frames(scene, data, frames_meta) -> list[str]:
    """Exit 0: every frame, positions finite and inside, speeds under the bound."""
    problems = []
    want = list(range(scene.output.frames + 1))
    if sorted(data["frames"]) != want:
        return [f"frames written {sorted(data['frames'])}, asked for {want}"]
    size = np.array(list(scene.domain.size) + ([scene.domain.dx] if scene.dim == 2 else []))
    tol = POSITION_TOLERANCE * size.max()
    for t in want:
        f = data["frames"][t]
        x, v = np.asarray(f["positions"], float), np.asarray(f["velocities"], float)
        if not (np.isfinite(x).all() and np.isfinite(v).all()):
            problems.append(f"frame {t}: {(~np.isfinite(x).all(1)).sum()} positions and "
                            f"{(~np.isfinite(v).all(1)).sum()} velocities not finite")
            continue
        outside = ((x < -tol) | (x > size + tol)).any(1) if len(x) else np.zeros(0, bool)
        outside &= ~above_open_top(scene, x, size, tol)  # a splash flying above an open top
        if outside.any():
            problems.append(f"frame {t}: {outside.sum()} particles outside the domain 0..{size.tolist()}, e.g. "
                            f"{x[outside][0].tolist()}")
        bound, terms = speed_bound(scene, t / scene.output.fps)
        speed = np.linalg.norm(v, axis=1).max() if len(v) else 0.0
        if speed > bound:
            used = ", ".join(f"{k} {val:.3g}" for k, val in terms.items() if val)
            problems.append(f"frame {t}: a particle moves at {speed:.3g} m/s, above the bound {bound:.3g} ({used})")
    return problems


def above_open_top(scene, x, size, tol) -> np.ndarray:
    """Which of the positions x lie above the domain's open top (the wall against gravity), and
    inside it on every other axis: liquid flying there falls back in (core/grid.py AIRBORNE)."""
    g = np.array(list(scene.domain.gravity) + [0.0] * (3 - scene.dim))
    if not len(x) or not g.any():
        return np.zeros(len(x), bool)
    axis = int(np.argmax(np.abs(g[:scene.dim])))
    top = ("x", "y", "z")[axis] + ("_max" if g[axis] < 0 else "_min")
    if scene.domain.walls.get(top) != "open":
        return np.zeros(len(x), bool)
    above = x[:, axis] > size[axis] + tol if g[axis] < 0 else x[:, axis] < -tol
    others = [a for a in range(scene.dim) if a != axis]
    inside_others = ((x[:, others] >= -tol) & (x[:, others] <= size[others] + tol)).all(1)
    return above & inside_others


def check_volumes(scene, frames_meta) -> list[str]:
    """Exit 0: the liquid's rest volume is what was seeded plus what entered; its occupied volume is
    not squeezed below it; the gas budget's total holds (injectors only add to it)."""
    problems = []
    first = frames_meta[0]
    dx = first["dx"]
    injects = any(isinstance(e, GasInjector) for e in scene.emitters)
    box = math.prod(scene.domain.size) * (dx if scene.dim == 2 else 1.0)  # 2D: a slab one cell thick
    densities = {mat.density for mat in scene.materials.values() if mat.kind == "liquid"}
    cells = [round(s / dx) for s in scene.domain.size]
    up = int(np.argmax(np.abs(scene.domain.gravity))) if any(scene.domain.gravity) else 0
    columns = math.prod(cells) // cells[up]  # a two-way head's columns (it needs gravity)
    for m in frames_meta:
        # The mass ledger closes to the float64 sums' rounding: added = held + left.
        if abs(m["liquid_mass_error"]) > 1e-9 * max(m["liquid_added_mass"], 1e-300):
            problems.append(f"frame {m['frame']}: the liquid's mass budget is off by {m['liquid_mass_error']:.3g} kg")
        entered, over = check_delivered(scene, m)
        problems += over
        # what left through open walls, as rest volume (by mass when all liquids share one density)
        left = m["liquid_left_mass"] / next(iter(densities)) if len(densities) == 1 else 0.0
        left += m["liquid_left_in_foam"]  # a head's foam blown out through an open wall, with its films
        want = first["liquid_rest_volume"] + first["liquid_in_head"] + entered - left
        rest = m["liquid_rest_volume"]
        # A two-way head's films hold liquid taken from the water, and its columns are owed what
        # drained and burst until it is made into water particles again (the worker's
        # liquid_in_head, signed): the liquid is its particles' plus that. The particles alone are
        # what fills the box and occupies cells (the films' liquid is in the foam, above the water):
        # held against the particles and the head's liquid, the occupancy read 0.31-0.90 in the
        # head scenes of the first 400 (0.95-1.00 against the particles).
        kept = rest + m["liquid_in_head"]
        # The head gives back (as water, or in foam blown out through an open wall) no more than it
        # took from the water: what it holds and is owed, taken - made - left in foam, stays
        # positive, short of the debts a column keeps below one water particle (take_water takes
        # whole particles: a column's films owe its water less than one until they owe a whole one).
        # Measured over the 214 head scenes of the first 3000: at worst 0.18 of this allowance
        # (scene 15); films made over dry columns (before they vented) took it to 1.7 there.
        short = columns * dx**3 / scene.solver.particles_per_cell
        if m["liquid_in_head"] < -short * (1.0 + 1e-6):
            problems.append(f"frame {m['frame']}: the head holds and is owed {m['liquid_in_head']:.6g} m^3 of "
                            f"liquid, below the {-short:.3g} its columns' part-particle debts allow: its films "
                            f"hold liquid no water gave")
        if (len(densities) == 1 or not m["liquid_left_mass"]) and \
                abs(kept - want) > REST_VOLUME_TOLERANCE * max(first["liquid_rest_volume"] + entered, 1e-300):
            head = f" (particles {rest:.6g}, head {m['liquid_in_head']:+.6g})" if m["liquid_in_head"] else ""
            problems.append(f"frame {m['frame']}: liquid rest volume {kept:.6g}{head}, but seeded + entered is "
                            f"{want:.6g} ({100 * (kept / want - 1) if want else math.inf:+.3g}%)")
        for i, e in enumerate(scene.emitters):
            if isinstance(e, LiquidInflow) and m["emitted"] is not None:
                expect = expected_layers(scene, i, m["time"], dx)
                if abs(m["emitted"][i] - expect) > 1.0 + 1e-6 * expect:
                    problems.append(f"frame {m['frame']}: emitter {i} emitted {m['emitted'][i]} layers by "
                                    f"t = {m['time']:.4g} s, expected {expect:.1f} (speed x time / spacing)")
        # A box with no way in holds its seeded liquid to rounding; a stream into a full box with an
        # open wall overfills it while the surplus is on its way out (the volume correction's tau:
        # measured 0.8-1.3% within a frame, scenes 242, 335, 346, 352), as a fluid's drift.
        over = REST_VOLUME_TOLERANCE if not scene.emitters else FILL_TOLERANCE
        if rest > box * (1.0 + over):
            problems.append(f"frame {m['frame']}: the liquid's rest volume is {rest / box:.3f} of the domain's: "
                            f"more water than the box holds, squeezed in")
        elif rest + m["gas_volume"] > box * (1.0 + (FILL_TOLERANCE_INJECTING if injects else FILL_TOLERANCE)):
            problems.append(f"frame {m['frame']}: liquid ({rest / box:.3f}) and gas ({m['gas_volume'] / box:.3f}) "
                            f"fill more than the domain's volume")
        occupied = m["liquid_occupied_volume"]
        rest -= m["liquid_flying_volume"]  # no cell holds liquid flying above an open top
        if rest > 0 and occupied < (1.0 - COMPRESSION) * rest:
            problems.append(f"frame {m['frame']}: the liquid occupies {occupied / rest:.3f} of its rest volume "
                            f"(compressed by more than {COMPRESSION:.0%})")
        if rest > 0 and occupied > rest * (1.0 + REST_VOLUME_TOLERANCE):
            problems.append(f"frame {m['frame']}: the liquid occupies {occupied / rest:.4f} of its rest volume: grew")
        gas0, gas = first["gas_total"], m["gas_total"]
        if gas0 is not None and gas is not None:
            if (gas < gas0 * (1 - 1e-6)) or (not injects and gas > gas0 * (1 + 1e-6)):
                problems.append(f"frame {m['frame']}: gas budget total {gas:.6g} kg, first frame {gas0:.6g} kg "
                                f"({'injectors only add' if injects else 'conserved'})")
    return problems


def check_run(bad_key, result, out_dir: Path) -> list[str]:
    """Everything a run owes its user, as a list of problems (empty: fine)."""
    code, err, out = result["code"], result["stderr"], result["stdout"]
    problems = []
    if "Traceback" in err + out:
        problems.append("a traceback in the output")
    if code not in (0, 1, 2):
        return problems + [f"exit {code}: {err.strip()[:400]}"]
    if bad_key is not None and code != 2:
        return problems + [f"a bad value under {bad_key} was not refused (exit {code})"]
    if code == 2:
        return problems + check_refusal(result, bad_key, out_dir)
    scene = load_scene(result["scene"])
    if code == 1:
        return problems + check_stopped(result, scene)
    try:
        data = read_usd(scene.output.path)
    except Exception as exc:  # noqa: BLE001
        return problems + [f"exit 0 but the output does not open: {type(exc).__name__}: {exc}"]
    return problems + check_frames(scene, data, result["frames"]) + check_volumes(scene, result["frames"])


def check_repeats(main, again, resumed) -> list[str]:
    """The same scene run again (to another path) gives the same state in every frame; run for one
    frame and resumed to the end, it gives the uninterrupted run's state from the resumed frames on."""
    problems = []
    want = {m["frame"]: m["state_sha1"] for m in main["frames"]}
    if again["code"] != 0:
        problems.append(f"run again, exit {again['code']}: {again['stderr'].strip()[-200:]}")
    elif {m["frame"]: m["state_sha1"] for m in again["frames"]} != want:
        differ = [m["frame"] for m in again["frames"] if want.get(m["frame"]) != m["state_sha1"]]
        problems.append(f"run again, the state differs in frames {differ}: not deterministic")
    first, rest = resumed
    if first["code"] != 0 or rest["code"] != 0:
        problems.append(f"run for one frame then resumed: exits {first['code']}, {rest['code']}: "
                        f"{(first['stderr'] + rest['stderr']).strip()[-200:]}")
    else:
        differ = [m["frame"] for m in rest["frames"] if want.get(m["frame"]) != m["state_sha1"]]
        if differ or not rest["frames"]:
            problems.append(f"resumed after frame 1, the state differs from the uninterrupted run's in frames "
                            f"{differ or 'all (none written)'}")
    return problems


# --------------------------------------------------------------------------------------- driver
REPEAT_EVERY = 10  # every 10th scene also runs again, and once more interrupted and resumed


def jobs_for(i: int, scene_dir: Path, bad_key) -> list[dict]:
    scene = str(scene_dir / "scene.toml")
    argv = ["--device", "cpu"] + (["--quiet"] if i % 2 else [])  # half print progress and the summary
    jobs = [{"scene": scene, "argv": argv, "tag": "main"}]
    if i % REPEAT_EVERY == 0 and bad_key is None:
        other = lambda name: ["--stage-path", (scene_dir / name / "fuzz.usdc").as_posix()]  # noqa: E731
        jobs += [{"scene": scene, "argv": argv + other("again"), "tag": "again"},
                 {"scene": scene, "argv": argv + other("resumed") + ["--num-frames", "1"], "tag": "first"},
                 {"scene": scene, "argv": argv + other("resumed") + ["--resume"], "tag": "rest"}]
    return jobs


def run_fuzz(indices, tmp_path: Path, timeout: float):
    """Generate, run (one worker process) and check the scenes; returns {index: problems} of the
    failures and the main runs' results by index."""
    jobs, bad_keys = [], {}
    for i in indices:
        scene_dir = tmp_path / f"s{i:03d}"
        scene_dir.mkdir()
        text, bad_keys[i] = generate(i, (scene_dir / "out" / "fuzz.usdc").as_posix())
        (scene_dir / "scene.toml").write_text(text)
        jobs += jobs_for(i, scene_dir, bad_keys[i])
    (tmp_path / "jobs.json").write_text(json.dumps(jobs))
    results_path = tmp_path / "results.jsonl"
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(HERE.parent), os.environ.get("PYTHONPATH", "")]))
    cmd = [sys.executable, str(HERE / "run_fuzz_worker.py"), f"--scene-seconds={SCENE_SECONDS}",
           str(tmp_path / "jobs.json"), str(results_path)]
    hung = None
    try:
        subprocess.run(cmd, timeout=timeout, env=env, capture_output=True, text=True, check=True)
    except subprocess.TimeoutExpired:
        hung = "the worker ran past its timeout"
    except subprocess.CalledProcessError as err:
        hung = f"the worker died (exit {err.returncode}): {err.stderr[-600:]}"
    tagged = {}
    if results_path.exists():
        for line in results_path.read_text().splitlines():
            r = json.loads(line)
            tagged[int(Path(r["scene"]).parent.name[1:]), r["tag"]] = r
    results = {i: r for (i, tag), r in tagged.items() if tag == "main"}
    failures = {}
    for i in indices:
        mine = {tag: r for (j, tag), r in tagged.items() if j == i}
        if len(mine) < len(jobs_for(i, tmp_path / f"s{i:03d}", bad_keys[i])):
            failures[i] = [f"no result: {hung or 'missing'} (this scene was running or not reached)"]
            break  # the scenes after it never ran
        hangs = [tag for tag, r in mine.items() if r["code"] == "hang"]
        if hangs:
            failures[i] = [f"still running after {SCENE_SECONDS} s ({', '.join(hangs)} run): a hang"]
            continue
        problems = check_run(bad_keys[i], mine["main"], tmp_path / f"s{i:03d}" / "out")
        if "again" in mine and mine["main"]["code"] == 0:
            problems += check_repeats(mine["main"], mine["again"], (mine["first"], mine["rest"]))
        if problems:
            failures[i] = problems
    return failures, results


def report(failures, tmp_path) -> str:
    lines = [f"{len(failures)} scenes failed (scene files under {tmp_path}/sNNN/scene.toml; "
             f"run_fuzz_scenes.generate(N, path) makes scene N):"]
    for i, problems in sorted(failures.items()):
        lines.append(f"  scene {i}: " + "; ".join(problems[:3]) + (f" (+{len(problems) - 3} more)"
                                                                   if len(problems) > 3 else ""))
    return "\n".join(lines)


# Holes the fuzz found that are not mended yet, each failing for the one reason given (any other
# problem in them still fails the test, and so does one of them passing: then take it off).
# 320 (zero gravity, a stream meeting a wall 33 degrees off head-on, foam from an injector's
# bubbles): foam riding the grid beside the wall takes the speed of the face where the stream's
# water first runs along it, 1.6 times the stream's (1.67 m/s against the bound's 1.57). Not the
# volume correction (the same with it off). A front meeting a wall at 33 degrees wets it along a
# line running at U / sin 33 = 1.85 U, and impact jets grow with the resolution (a stream alone:
# fastest face 1.95, 2.82, 3.58 U at 8, 16, 32 cells across; its liquid alone passes the bound
# after 5 frames, 1.77 m/s against 1.5): the bound's U for a stream does not hold where it strikes
# a wall, and no resolution-free bound follows from the impact.
#
# Beyond both ranges, not mended: 958 (an air stone at 5.5 g blowing a cavity of half the box in
# a 13 x 14 cell pool in 2 frames, under a pour): the liquid occupies 0.888 of its rest volume by
# frame 3 (0.833 without the foam head), crowded to phi 1.3-1.8 in one-cell films on the walls
# beside the gas. Not the push (0.84 with none), the pour, the foam or the gas's eos; none
# without the injector (0.97), 0.93 at 1 g; a 2 ms volume relaxation delays it by a frame.
# In 400-1999 the full-tank and gas-lid fixes mended 611, 773, 1045, 1067, 1412, 1422, 1853, 1979.
# Laying a stream only into cells not yet full (the emitters' CROWDED_FILL 1.0, was 1.2) mended 435
# (0.853 -> 0.911), 935 (1.021 -> 1.015) and 1403 (1.026 -> 1.011): run_fuzz_scenes.HARD_SCENES has
# them reduced. 1403's reduced form at 2 m/s instead of 1.49 holds 1.021 of the box (scene 1403 at
# 0.5 / 1 / 1.49 / 2 m/s: 1.005 / 1.019 / 1.026 / 1.029 at 1.2): the stream fills the box faster
# than its open walls let the displaced water out, a fill that grows with the inflow rate;
# FILL_TOLERANCE does not hold for any rate. Still failing (2026-12-07; over 200-1199 with the
# correction moving positions by default the same three and no other: 565 at 0.890 with no fast
# particle, 780 (smoothed, positions) at 0.879, 958 (drawn to move velocities) at 0.884):
# 780: the stream alone (gas, foam, collider, gravity off one at a time: still 0.85-0.90), fired
# from 1.5 cells off the no-slip floor's corner into it, stopping at 27 ms:
#   [domain] size = [0.08, 0.1], cell_size = 0.01, walls = { x_max = "no_slip", y_min = "no_slip" }
#   [materials.water] viscosity = 1.0;  [materials.air] kind = "gas" over y > 0.0536 (a box)
#   [[emitters]] liquid_inflow, center = [0.014984, 0.013074], direction = [-1.5777, -1.8082],
#   radius = 0.01988, speed = 1.39976, stop = 0.027014;  [solver] quality = "preview"; 60 fps, 2 frames
# occupies 0.895 at frame 2 (0.853 before the fix above; scene 780 itself 0.868, was 0.847). The
# crowding sits in the two cells next to the corner (phi 1.2-1.4) and grows after the stream stops
# (excess 0.41 -> 0.97 cells, frame 1 -> 2, without the gas): the impact against the walls, not the
# laying. In scene 780 without its foam and collider: no viscosity 0.880; no gas 0.900; no gas and
# free-slip walls 0.919 (passing); tau 2 ms, without viscosity, before the fix: 0.886. The gas box
# over it shrinks to 0.24 then 0 of the box's volume in the resolved gas (vented, closed box): not
# looked at.
# 565: a viscous (1 Pa s) pool 4.5 cells deep in a closed 16 x 10 cell box with a gas sphere, a
# stream poured in, and an air stone at 159 bubbles/s of radius 7 mm (each 3.8% of the box, six box
# volumes a second); it needs all four (no stream, no sphere, no viscosity, 80 bubbles/s: each
# passes). The fast particles are gas at the pool's surface two cells from the closed x_max wall,
# 4.2 m/s along it (bound 3.13, correction 0.5 of it); the liquid occupies 0.891. Volume relaxation
# time off / 5 / 10 / 20 / 40 ms: fastest 2.5 / 3.1 / 4.2 / 2.1 / 1.6 m/s (off: against a bound of
# 2.63); 2 ms: within the bound and 0.951: the injector's push crowds faster than tau relaxes, as in
# FILL_TOLERANCE_INJECTING. CROWDED_FILL does not change it. Scene 565 itself is its reduced form.
# Tried for all three (2026-12-08): a cell beside a wall reads 5/6 full when full (the B-spline's
# share beyond the wall has no particles), so its band's 1.1 is a crowding of 1.32. Folding the
# ghost layer's splat back into the cells beside the walls, so that they read 1, made all three
# worse: 565 occupied 0.859 with a particle at 4.1 m/s, 780 0.802, 958 0.865 with 15.3 m/s. Not kept.
# Reading a wall cell's fill over its 5/6 per solid neighbour in the correction instead (the splat
# unchanged): with the band of 0.1 it mends 780 and 2188 (below) and turns 565's and 958's
# compression into speeds past the bound (3.32, 15.2 m/s), but the resting head's floor pressure
# reads +14.8 / +13.6% at 16 / 32 columns (+11.0 / +3.6% now) and the vortex loses more than the
# transfers (tests/test_foam_head.py, test_volume_shift.py fail): the walls' noise, about 0.07 of a full
# cell there, kicks past the band. A wall band of 0.3 keeps those tests but mends only 2188; moving
# such cells by the shift (as enclosed ones) mends only 780 and the floor pressure reads -4.5% at 32.
# Scenes 1200-3999 (2026-12-08, 2,800 not run before): 3247 failed and is mended (HARD_SCENES, a
# foam head's water given back under an open floor); five more fail in the classes above, not
# mended: 2188 and 3547 (a stream into a no-slip floor: occupied 0.879, 0.885), 2448 (a stream and
# an injector at 208 bubbles/s: 0.881), 2783 (an injector at 147 bubbles/s of 1.5 cells' radius,
# 6.6 box volumes a second into a 7 x 7 x 6 cell box under a stream: a particle at 7.2 m/s against
# the bound's 4.7).
# A quarter of the scenes read the smoothed fill ([solver].volume_fill, a draw of its own): over
# 0-1199 no scene fails that did not before; 780 (smoothed) occupies 0.876, 958 (smoothed) 0.884.
# A quarter moved positions ([solver].volume_correction_moves, a draw of its own) while the default
# moved velocities: over 0-1199 only 327 failed that did not before, and 958 (which draws both) was
# worse: its liquid occupied 0.762 of its rest volume at frame 3 (0.884 moving velocities): the
# shift pushed its films' liquid into the compressible gas beside them, which does not give way as
# it does to the solve. So only enclosed cells move positions; surface cells ask the solve, under
# the band. With that the default (2026-12-07), and the draw now picks "velocities": 958 (which
# draws it) reads 0.884 as before, 0.897 moving positions. 327 (3D, 8 x 7 x 6 cells of 5 mm, gravity
# tilted 30 degrees, a stream falling at 0.94 m/s onto an incompressible air sphere of 2 cells'
# radius, foam), whose resolved gas reached 2-3.8 m/s within frame 1 and ended it above the bound
# moving positions everywhere, passes moving positions as now (and moving velocities, which it
# draws: its frame 1 ends after the gas has slowed).
KNOWN = {320: "above the bound"}


def assert_clean(indices, failures, results, tmp_path):
    assert len(results) == len(indices) or failures
    known = {i for i in list(failures) if i in KNOWN and all(KNOWN[i] in p for p in failures[i])}
    for i in known:
        del failures[i]
    assert not failures, report(failures, tmp_path)
    mended = [i for i in KNOWN if i in indices and i not in known]
    assert not mended, f"scenes {mended} of KNOWN pass now: take them off the list"


def test_generated_runs_exit_cleanly_and_stay_physical(tmp_path):
    indices = range(CI_SCENES)
    assert_clean(indices, *run_fuzz(indices, tmp_path, timeout=600), tmp_path)


@pytest.mark.slow
def test_generated_runs_exit_cleanly_and_stay_physical_at_full_size(tmp_path):
    indices = range(CI_SCENES, CI_SCENES + SLOW_SCENES)
    assert_clean(indices, *run_fuzz(indices, tmp_path, timeout=3600), tmp_path)


@pytest.mark.parametrize("name", list(HARD_SCENES))
def test_scenes_the_fuzz_found(tmp_path, name):
    """The generated failures reduced to a few lines each (run_fuzz_scenes.HARD_SCENES says what each
    found), run in this process and held to the same checks, and to the exit codes a correct run of
    that scene may give."""
    from run_fuzz_worker import run_one

    text, exits = HARD_SCENES[name]
    out_dir = tmp_path / "out"
    path = tmp_path / f"{name}.toml"
    path.write_text(text.format(out=(out_dir / f"{name}.usdc").as_posix()))
    result = run_one(str(path), ["--device", "cpu", "--quiet"], SCENE_SECONDS)
    problems = check_run(None, result, out_dir)
    if result["code"] in (0, 1, 2) and result["code"] not in exits:
        problems.append(f"exit {result['code']}, but this scene should give one of {exits}: "
                        f"{result['stderr'].strip()[-300:]}")
    assert not problems, f"{name}:\n" + "\n".join(problems)
