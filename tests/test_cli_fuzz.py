"""Fuzzing grown from scene files (test_scene_fuzz.py) to the command line and to extreme magnitudes
(issue #14): generated argument lists, in-bounds extremes and out-of-bounds values. Whatever the
input, the answer is an exit code in {0, 1, 2} or a SceneError naming a key: never a traceback,
never a hang (each case runs under an alarm far above its cost)."""

import contextlib
import math
import os
import pathlib
import signal
import subprocess
import sys

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from warp_mpm_bubbles.cli import main
from warp_mpm_bubbles.io.preview import PreviewError, parse_frames
from warp_mpm_bubbles.scene import limits
from warp_mpm_bubbles.scene.model import Box, Domain, Material, Output, Scene, SceneError, SolverSettings, Sphere

ROOT = pathlib.Path(__file__).resolve().parents[1]
CASE_SECONDS = 60  # a case costs milliseconds; only a hang reaches this
SCALE = float(os.environ.get("WARP_MPM_BUBBLES_FUZZ_SCALE", "1"))  # e.g. 10 for a longer hunt
FAST = settings(deadline=None, suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture])


@contextlib.contextmanager
def bounded(seconds=CASE_SECONDS):
    """Fail a case that hangs instead of hanging the suite (SIGALRM: Unix, main thread)."""
    if not hasattr(signal, "SIGALRM"):
        yield
        return

    def hang(*_):
        raise AssertionError(f"case still running after {seconds} s: a hang")

    old = signal.signal(signal.SIGALRM, hang)
    signal.alarm(seconds)
    try:
        yield
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, old)


SCENE = """
name = "fuzz"
[domain]
size = [0.2, 0.1]
cell_size = 0.0125
[materials.water]
[[shapes]]
type = "box"
material = "water"
min = [0.0, 0.0]
max = [0.1, 0.05]
[output]
path = "{out}"
frames = 2
"""


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    d = tmp_path_factory.mktemp("cli_fuzz")
    good = d / "good.toml"
    good.write_text(SCENE.format(out=(d / "good.usdc").as_posix()))
    (d / "broken.toml").write_text("[domain\nsize = ")
    (d / "junk.usdc").write_text("not usd")
    return {"good": str(good), "broken": str(d / "broken.toml"), "missing": str(d / "missing.toml"),
            "dir": str(d), "junk": str(d / "junk.usdc"), "stage": str(d / "out" / "x.usdc")}


@pytest.fixture
def no_simulation(monkeypatch):
    """A valid `run` stops at run_scene: the fuzz tests the arguments, not the physics."""
    calls = []
    monkeypatch.setattr("warp_mpm_bubbles.io.runner.run_scene", lambda scene, **kw: calls.append((scene, kw)))
    return calls


TEXT = st.text(alphabet=st.characters(blacklist_categories=("Cs",), blacklist_characters="\x00"), max_size=12)
NUMBERS = st.one_of(st.integers(-10**25, 10**25).map(str), st.floats(allow_nan=True).map(repr),
                    st.sampled_from(["1e20", "0", "-1", "1", "3", "1000000", "1000001", " 2", "0x10", "1_0"]))
DEVICES = st.one_of(st.sampled_from(["cpu", "cuda", "cuda:0", "cuda:1", "gpu", "CPU", "", " ", "cuda:-1"]), TEXT)
OPTIONS = st.one_of(
    st.tuples(st.just("--num-frames"), NUMBERS),
    st.tuples(st.just("--device"), DEVICES),
    st.tuples(st.just("--quality"), st.one_of(st.sampled_from(["preview", "production", "reference"]), TEXT)),
    st.tuples(st.just("--stage-path"), st.one_of(st.sampled_from(["{stage}", "/proc/x.usdc", "x.txt", "{dir}"]),
                                                  TEXT)),
    st.tuples(st.sampled_from(["--quiet", "--resume", "--bogus", "-h"])),
)


def fill(arg, files):
    return arg.format(**files) if arg.startswith("{") and arg.endswith("}") and arg[1:-1] in files else arg


@settings(FAST, max_examples=int(400 * SCALE))
@given(command=st.sampled_from(["run", "check", "preview", "bogus", None]),
       scene=st.one_of(st.sampled_from(["{good}", "{broken}", "{missing}", "{dir}", "{junk}"]), TEXT),
       options=st.lists(OPTIONS, max_size=4))
def test_generated_command_lines_never_give_a_traceback(files, no_simulation, capsys, command, scene, options):
    argv = ([command] if command else []) + [fill(scene, files)]
    for opt in options:
        argv += [fill(a, files) for a in opt]
    with bounded():
        try:
            code = main(argv)
        except SystemExit as exit_:  # argparse: usage errors (2) and --help (0)
            code = exit_.code
    out, err = capsys.readouterr()
    assert "Traceback" not in out + err
    assert code in (0, 1, 2), (argv, code, err)
    if code == 2 and command in ("run", "check") and err:
        assert "error:" in err


@settings(FAST, max_examples=int(200 * SCALE))
@given(text=st.one_of(TEXT, st.lists(st.integers(-5, 10**12).map(str), max_size=5).map(",".join)))
def test_generated_preview_frames_parse_or_get_a_named_error(text):
    try:
        frames = parse_frames(text)
    except PreviewError as err:
        assert str(err).startswith("--frames ")
    else:
        assert frames is None or all(isinstance(f, int) and f >= 0 for f in frames)


# ------------------------------------------------------------------------- magnitudes
def scene_with(speed=0.0, gravity=-9.81, fps=30.0, viscosity=0.0, tension=0.0, density=1000.0, ambient=101325.0,
               gas_density=None, max_dt=None, cfl=0.5, out="/tmp/unused.usdc", cells=8):
    mats = {"water": Material("water", density=density, viscosity=viscosity, surface_tension=tension)}
    shapes = [Box("water", (0.0, 0.0), (0.05, 0.05), velocity=(speed, 0.0))]
    if gas_density is not None:
        mats["air"] = Material("air", kind="gas", density=gas_density)
        shapes.append(Sphere("air", (0.05, 0.025), 0.015))
    return Scene(Domain((0.1, 0.1), 0.1 / cells, gravity=(0.0, gravity), ambient_pressure=ambient), mats, shapes,
                 solver=SolverSettings(max_dt=max_dt, cfl=cfl, particles_per_cell=4),
                 output=Output(path=out, fps=fps, frames=1))


def in_bounds(lo, hi, log=True):
    """Values across [lo, hi], dense at both ends (log-uniform when log)."""
    if log:
        return st.floats(math.log10(lo), math.log10(hi)).map(lambda e: min(max(10.0**e, lo), hi))
    return st.floats(lo, hi)


EXTREME = dict(
    speed=st.one_of(in_bounds(-1e3, 1e3, log=False), st.sampled_from([0.0, 1e3, -1e3, 5e-324])),
    gravity=st.one_of(in_bounds(-1e3, 1e3, log=False), st.sampled_from([0.0, -1e3, 1e3])),
    fps=in_bounds(limits.MIN_FPS, limits.MAX_FPS),
    viscosity=st.one_of(st.just(0.0), in_bounds(1e-9, limits.MAX_VISCOSITY)),
    tension=st.one_of(st.just(0.0), in_bounds(1e-9, limits.MAX_SURFACE_TENSION)),
    density=in_bounds(limits.MIN_DENSITY, limits.MAX_DENSITY),
    ambient=in_bounds(limits.MIN_AMBIENT, limits.MAX_PRESSURE),
    gas_density=st.one_of(st.none(), in_bounds(limits.MIN_DENSITY, limits.MAX_DENSITY)),
    max_dt=st.one_of(st.none(), in_bounds(1e-12, 1e3)),
    cfl=in_bounds(1e-6, 2.0),
)


@settings(FAST, max_examples=int(300 * SCALE))
@given(**EXTREME)
def test_extreme_values_inside_the_bounds_validate_or_name_the_step_limit(tmp_path_factory, **values):
    out = str(tmp_path_factory.getbasetemp() / "extreme.usdc")
    with bounded():
        try:
            scene = scene_with(out=out, **values).validate()
        except SceneError as err:  # only the steps-per-frame check may refuse in-bounds values
            assert "steps per frame" in err.allowed and "limit)" in str(err), str(err)
            return
    # validated: its first frame is within the step cap by the same formulas the run uses
    steps = (1.0 / scene.output.fps) / min(limits.step_limits(scene).values())
    assert steps <= scene.solver.max_steps_per_frame


OUT_OF_BOUNDS = st.one_of(
    st.tuples(st.just("speed"), st.floats(1.0001e3, 1e308)),
    st.tuples(st.just("gravity"), st.floats(1.0001e3, 1e308).map(lambda g: -g)),
    st.tuples(st.just("fps"), st.one_of(st.floats(1e-300, 0.0099), st.floats(1.0001e5, 1e308))),
    st.tuples(st.just("viscosity"), st.floats(1.0001e3, 1e308)),
    st.tuples(st.just("tension"), st.floats(3.0001, 1e308)),
    st.tuples(st.just("density"), st.one_of(st.floats(1e-300, 0.00099), st.floats(1.0001e5, 1e308))),
    st.tuples(st.just("ambient"), st.one_of(st.floats(1e-300, 0.99), st.floats(1.0001e9, 1e308))),
)
KEYS = {"speed": "[shapes.0].velocity", "gravity": "[domain].gravity", "fps": "[output].fps",
        "viscosity": "[materials.water].viscosity", "tension": "[materials.water].surface_tension",
        "density": "[materials.water].density", "ambient": "[domain].ambient_pressure"}


@settings(FAST, max_examples=int(300 * SCALE))
@given(case=OUT_OF_BOUNDS)
def test_values_beyond_the_bounds_are_refused_with_their_key_and_reason(tmp_path_factory, case):
    name, value = case
    with bounded(), pytest.raises(SceneError) as err:
        scene_with(out=str(tmp_path_factory.getbasetemp() / "oob.usdc"), **{name: value}).validate()
    assert err.value.key.startswith(KEYS[name]), str(err.value)
    assert any(bound.why in str(err.value) for bound in limits.LIMITS.values()), str(err.value)  # and why


# A handful of in-bounds extremes taken one step on a tiny grid: finite, or a SimulationError.
ONE_STEP = [dict(speed=1e3), dict(gravity=-1e3), dict(fps=1e5), dict(viscosity=1.0, fps=1e3),
            dict(tension=3.0, fps=1e3), dict(density=1e-3, gas_density=1e5), dict(ambient=1.0, gas_density=1e-3)]


@pytest.mark.parametrize("values", ONE_STEP, ids=lambda v: ",".join(f"{k}={v[k]:g}" for k in v))
def test_in_bounds_extremes_take_a_step(tmp_path, values):
    import numpy as np

    from warp_mpm_bubbles.core.simulation import Simulation, SimulationError

    scene = scene_with(out=str(tmp_path / "s.usdc"), **values).validate()
    sim = Simulation(scene, "cpu")
    with bounded():
        try:
            sim.step(min(sim.stable_dt(), 1.0 / scene.output.fps))
        except SimulationError as err:  # a named stop is an acceptable answer; a traceback is not
            assert "step" in str(err)
            return
    assert np.isfinite(sim.particles_numpy()["positions"]).all()


# A few real processes: the entry point as a user runs it.
@pytest.mark.parametrize("argv,code,words", [
    (["run", "{good}", "--num-frames", "1e20"], 2, "--num-frames"),
    (["run", "{good}", "--device", "cuda:99", "--quiet"], 2, "Warp sees"),
    (["preview", "{good}"], 2, "this is a scene file"),
    (["check", "{missing}"], 2, "scene file not found"),
], ids=["num_frames", "device", "preview_toml", "missing"])
def test_the_installed_entry_point_gives_one_line_errors(files, argv, code, words):
    env = {"PYTHONPATH": str(ROOT), "PATH": "/usr/bin:/bin"}
    env.update({k: v for k, v in os.environ.items() if k.startswith("WARP_CACHE")})
    proc = subprocess.run([sys.executable, "-m", "warp_mpm_bubbles.cli", *[fill(a, files) for a in argv]],
                          capture_output=True, text=True, timeout=300, env=env)
    assert proc.returncode == code and words in proc.stderr
    assert "Traceback" not in proc.stdout + proc.stderr
