"""Issue #14's table, one test per row (items 2-5): every user error ends in a named error and an
exit code, never a traceback; frames that would need too many steps stop before they start."""

import io
import math
import os
import pathlib

import numpy as np
import pytest

from warp_mpm_bubbles import cli
from warp_mpm_bubbles.cli import main
from warp_mpm_bubbles.scene import limits
from warp_mpm_bubbles.scene.model import (
    Box, Domain, Material, Output, Scene, SceneError, SolverSettings, Sphere, load_scene,
)

ROOT = pathlib.Path(__file__).resolve().parents[1]

SMALL = """
name = "small"
[domain]
size = [0.4, 0.2]
cell_size = 0.0125
{domain}
[materials.water]
density = 1000.0
{water}
[[shapes]]
type = "box"
material = "water"
min = [0.0, 0.0]
max = [0.1, 0.15]
{shape}
[output]
path = "{out}"
fps = {fps}
frames = 2
{extra}
"""


def scene_file(tmp_path, domain="", water="", shape="", fps=60, extra="", out=None, name="s.toml"):
    path = tmp_path / name
    out = out or (tmp_path / "s.usdc").as_posix()
    path.write_text(SMALL.format(domain=domain, water=water, shape=shape, fps=fps, extra=extra, out=out))
    return path


def run_cli(capsys, *argv):
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    assert "Traceback" not in out + err
    return code, out, err


# ------------------------------------------------------------------------------ missing device
def test_missing_gpu_lists_the_devices_and_what_a_gpu_run_needs(tmp_path, capsys):
    import warp as wp

    scene = scene_file(tmp_path)
    code, _, err = run_cli(capsys, "run", scene, "--device", "cuda:99", "--quiet")
    assert code == 2
    assert "device 'cuda:99' is not available" in err and "Warp sees cpu" in err
    if not wp.is_cuda_available():  # this machine: the README's own `--device cuda:0` example
        code, _, err = run_cli(capsys, "run", scene, "--device", "cuda:0", "--quiet")
        assert code == 2 and "NVIDIA driver" in err and "warp-lang" in err and "--device cpu" in err
    assert not (tmp_path / "s.usdc").exists()  # refused before any work
    code, _, err = run_cli(capsys, "check", scene, "--device", "nonsense")
    assert code == 2 and "'nonsense' is not available" in err


def test_check_device_returns_the_device_or_a_named_error():
    from warp_mpm_bubbles.io.devices import DeviceError, check_device

    assert str(check_device("cpu")) == "cpu"
    with pytest.raises(DeviceError, match="Warp sees"):
        check_device("cuda:99")


# --------------------------------------------------------------------- colliders over all water
def test_collider_covering_all_the_water_is_refused_in_check_and_run(tmp_path, capsys):
    collider = '[[colliders]]\ntype = "box"\ncenter = [0.1, 0.1]\nsize = [0.3, 0.3]'
    scene = scene_file(tmp_path, extra=collider)
    for command in (("check", scene), ("run", scene, "--device", "cpu", "--quiet")):
        code, _, err = run_cli(capsys, *command)
        assert code == 2 and "the colliders cover all 384 seeded particles" in err
    # half covered: fine
    half = scene_file(tmp_path, extra=collider.replace("size = [0.3, 0.3]", "size = [0.1, 0.1]"), name="h.toml")
    assert run_cli(capsys, "check", half)[0] == 0


def test_numpy_collider_test_agrees_with_the_kernel(tmp_path):
    # The static check is a numpy twin of effects/colliders.signed_distance: they must agree.
    from warp_mpm_bubbles import Collider
    from warp_mpm_bubbles.core.simulation import Simulation

    colliders = [Collider("sphere", center=(0.05, 0.05), radius=0.03),
                 Collider("box", center=(0.3, 0.1), size=(0.05, 0.08)),
                 Collider("cylinder", center=(0.2, 0.05), radius=0.02, axis="x", length=0.06),
                 Collider("glass", center=(0.15, 0.0), radius=0.04, height=0.1, wall_thickness=0.0125)]
    scene = Scene(Domain((0.4, 0.2), 0.0125), {"water": Material("water")}, [Box("water", (0.0, 0.0), (0.4, 0.2))],
                  output=Output(path=str(tmp_path / "c.usdc")), colliders=colliders).validate()
    sim = Simulation(scene, "cpu")
    pts = np.random.default_rng(0).random((4000, 3)) * [0.4, 0.2, 0.0] + [0, 0, 0.5 * 0.0125]
    kernel = sim.stage("colliders").inside(sim.ctx, pts)
    ours = np.zeros(len(pts), bool)
    for c in scene.colliders:
        ours |= limits.inside_collider(c, pts, 2)
    assert 0.1 < kernel.mean() < 0.6  # the test points meet every collider
    assert (kernel == ours).mean() > 0.998  # points on a boundary (float32 vs float64) may differ


def test_guard_names_a_simulation_with_no_particles(tmp_path):
    from warp_mpm_bubbles.io.guards import NoFluidError, check_fluid_left

    class Empty:
        num_particles = 0
        scene = Scene(Domain((0.4, 0.2), 0.0125), {"water": Material("water")}, [Box("water", (0, 0), (0.1, 0.1))],
                      output=Output(path=str(tmp_path / "e.usdc")), source="e.toml")

    Empty.scene.colliders = [object()]
    with pytest.raises(NoFluidError, match=r"e.toml: no fluid to simulate: the colliders cover"):
        check_fluid_left(Empty())


# ---------------------------------------------------------------------------------------- memory
def test_estimates_match_the_seeding(tmp_path):
    # dam_break seeds 49,152 particles; the estimate from the shapes' volumes is that exactly
    # (an axis-aligned box), and a sphere's within the seeding noise.
    scene = load_scene(ROOT / "examples" / "dam_break.toml")
    assert limits.estimate_particles(scene) == 49_152
    ball = Scene(Domain((0.4, 0.4, 0.4), 0.01), {"w": Material("w")}, [Sphere("w", (0.2, 0.2, 0.2), 0.1)],
                 output=Output(path=str(tmp_path / "b.usdc"))).validate()
    from warp_mpm_bubbles.core.seeding import seed_particles

    real = len(seed_particles(ball)["positions"])
    assert abs(limits.estimate_particles(ball) / real - 1) < 0.01
    est = limits.estimate_memory(scene)
    # 49,152 particles x 104 B and 66 x 34 x 18 cells x ~35 arrays x 4 B, x1.25 headroom:
    # measured RSS growth of Simulation() is 0.45-0.75 of device + host estimates (README note)
    assert 6.0e6 < est["particles"] < 7.0e6 and 7.0e6 < est["grid"] < 9.0e6


BILLION = """
[domain]
size = [{size}]
cell_size = 0.001
[materials.water]
[[shapes]]
type = "box"
material = "water"
min = [0.0, 0.0, 0.0]
max = [{top}]
[output]
path = "{out}"
"""


@pytest.mark.parametrize("size,top,what", [
    # the 1e9 cells (long in x: validation samples one y-z slab of cells, kept small here)
    ("10.0, 0.1, 1.0", "0.01, 0.1, 0.2", f"{10_002 * 102 * 1_002:,} grid cells"),
    ("0.6, 0.4, 0.1", "0.6, 0.4, 0.05", "96,000,000 particles"),  # its 0.001 m cells giving 96 M particles
], ids=["1e9_cells", "96M_particles"])
def test_scene_beyond_the_machines_memory_is_refused_before_seeding(tmp_path, capsys, monkeypatch, size, top, what):
    path = tmp_path / "big.toml"
    path.write_text(BILLION.format(size=size, top=top, out=(tmp_path / "big.usdc").as_posix()))
    monkeypatch.setattr(limits, "host_available", lambda: 16 * 10**9)  # a 16 GB machine, whatever this one has
    monkeypatch.setattr("warp_mpm_bubbles.core.seeding.seed_particles",
                        lambda *a: pytest.fail("seeded a scene that does not fit"))
    for command in (("check", path), ("run", path, "--device", "cpu", "--quiet")):
        code, _, err = run_cli(capsys, *command)
        assert code == 2, err
        assert "of host memory but 16 GB is available" in err and what in err
        assert "coarser [domain].cell_size" in err and "particles_per_cell" in err


def test_device_memory_is_checked_against_the_gpu(tmp_path):
    scene = load_scene(ROOT / "examples" / "dam_break.toml")
    with pytest.raises(limits.MemoryLimitError, match=r"of cuda:0 memory but 0.01 GB is available"):
        limits.check_memory(scene, host_bytes=10**12, device_bytes=10**7, device_name="cuda:0")
    assert limits.check_memory(scene, host_bytes=10**12, device_bytes=10**10, device_name="cuda:0")["count"] == 49_152


# --------------------------------------------------------------------------- non-physical values
def setk(text, old, new):
    return text.replace(old, new)


@pytest.mark.parametrize("change,key,words", [
    (dict(shape="velocity = [1e38, 0.0]"), "[shapes.0].velocity", "exceeds 1000 m/s"),
    (dict(shape="velocity = [0.0, 1e300]"), "[shapes.0].velocity", "speed of sound"),
    (dict(domain="gravity = [0.0, -1e30]"), "[domain].gravity", "exceeds 1000 m/s^2"),
    (dict(fps="1e-6"), "[output].fps", ">= 0.01"),
    (dict(fps="1e6"), "[output].fps", "<= 100000"),
    (dict(water="viscosity = 1e6"), "[materials.water].viscosity", "<= 1000 (1000 Pa s"),
    (dict(water="surface_tension = 50.0"), "[materials.water].surface_tension", "<= 3"),
    (dict(extra="[materials.oil]\ndensity = 1e9"), "[materials.oil].density", "osmium"),
    (dict(extra='[solver]\nvolume_correction = 0.3'), "[solver].volume_correction", "volume_relaxation_time"),
    (dict(extra='[solver]\nvolume_relaxation_time = 1e-6'), "[solver].volume_relaxation_time", "seeding noise"),
    (dict(extra='[solver]\nvolume_correction_speed = 100.0'), "[solver].volume_correction_speed", "seeding noise"),
    (dict(extra='[solver]\nvolume_correction_speed = 1.0\nvolume_relaxation_time = 0.01'),
     "[solver].volume_correction_speed", "not both"),
    # in bounds, but the first frame would need 2e5 steps: the static step check names the term
    (dict(water="viscosity = 500.0", fps="0.1", extra='[effects.viscosity]\nsolver = "explicit"'),
     "[materials].viscosity", "the viscous limit"),
    (dict(extra='[solver]\nmax_dt = 1e-9'), "[solver].max_dt", "the max_dt limit"),
    (dict(extra='[[colliders]]\ntype = "sphere"\ncenter = [0.3, 0.1]\nradius = 0.02\nvelocity = [0.0, 1.0]\n'
                'acceleration = [0.0, 1e5]\nstop = 1.0'), "[colliders.0]", "moves at up to"),
], ids=["velocity_1e38", "velocity_1e300", "gravity_1e30", "fps_1e-6", "fps_1e6", "viscosity_1e6",
        "tension_50", "density_1e9", "volume_correction", "volume_relaxation_1e-6", "correction_speed_100",
        "speed_and_time", "viscous_steps", "max_dt_steps",
        "collider_speed"])
def test_non_physical_magnitudes_are_refused_with_the_reason(tmp_path, capsys, change, key, words):
    code, out, err = run_cli(capsys, "check", scene_file(tmp_path, **change))
    assert code == 2 and out == ""
    assert key in err and words in err, err


def test_every_example_and_the_extremes_inside_the_bounds_validate(tmp_path):
    for path in sorted((ROOT / "examples").glob("*.toml")):
        load_scene(path)
    # at the bounds themselves
    Scene(Domain((0.4, 0.2), 0.0125, gravity=(0.0, -1000.0)), {"w": Material("w", viscosity=1.0)},
          [Box("w", (0, 0), (0.1, 0.1), velocity=(1000.0, 0.0))],
          output=Output(path=str(tmp_path / "x.usdc"), fps=1e5, frames=1_000_000)).validate()


def test_num_frames_must_be_a_bounded_whole_number(tmp_path, capsys):
    scene = scene_file(tmp_path)
    for bad in ("1e20", "0", "-3", "2.5", "ten", "1000001"):
        with pytest.raises(SystemExit) as exit_:
            main(["run", str(scene), "--num-frames", bad])
        assert exit_.value.code == 2
        err = capsys.readouterr().err
        assert "--num-frames" in err and "1,000,000" in err and "Traceback" not in err
    with pytest.raises(SceneError, match=r"\[output\].frames = 100000000000000000000: .*<= 1000000"):
        load_scene(scene).replace_output(frames=10**20)


# ---------------------------------------------------------------------------- unwritable output
@pytest.mark.skipif(not os.path.isdir("/proc/self"), reason="needs /proc")
def test_output_under_proc_is_refused_in_check(tmp_path, capsys):
    # as root os.access says yes; the check now creates a scratch file to find out
    for target in ("/proc/out.usdc", "/proc/no/such/dir/out.usdc"):
        code, _, err = run_cli(capsys, "check", scene_file(tmp_path, out=target))
        assert code == 2 and "[output].path" in err and "cannot write it" in err
    code, _, err = run_cli(capsys, "run", scene_file(tmp_path), "--stage-path", "/proc/x.usdc", "--quiet")
    assert code == 2 and "cannot write it" in err


def test_the_writability_probe_leaves_nothing_behind(tmp_path):
    load_scene(scene_file(tmp_path, out=(tmp_path / "d" / "o.usdc").as_posix()))
    assert sorted(p.name for p in tmp_path.iterdir()) == ["s.toml"]


# --------------------------------------------------------------------------------------- preview
@pytest.fixture(scope="module")
def written(tmp_path_factory):
    from warp_mpm_bubbles.io.usd_output import StageWriter

    path = tmp_path_factory.mktemp("preview") / "anim.usdc"
    pos = np.random.default_rng(1).random((50, 3)).astype(np.float32)
    with StageWriter(path, fps=24, materials=[("water", (0.2, 0.4, 1.0))], particle_radius=0.01) as w:
        for f in range(3):
            w.write_frame(f, pos + 0.01 * f, np.zeros_like(pos), np.arange(50, dtype=np.int64), np.zeros(50, np.int32))
    return path


@pytest.mark.parametrize("argv,words", [
    (["{stage}", "--frames", "0,x"], "'x' is not a frame number"),
    (["{stage}", "--frames", "-1"], "is not a frame number"),
    (["{stage}", "--frames", "1.5"], "is not a frame number"),
    (["{stage}", "--frames", "0,7"], "--frames: 7 not in"),
    (["{tmp}/missing.usdc"], "no such file"),
    (["{scene}"], "this is a scene file"),
    (["{tmp}"], "not a file"),
    (["{text}"], "cannot read it as a USD animation"),
    (["{stage}", "--png", "{tmp}/no/dir/x.png"], "does not exist"),
    (["{stage}", "--png", "{tmp}/x.exe"], "expected a file name ending in .png"),
], ids=["frames_junk", "frames_negative", "frames_float", "frames_absent", "missing", "toml", "directory",
        "not_usd", "png_dir", "png_suffix"])
def test_every_preview_argument_gets_a_clear_error(tmp_path, capsys, written, argv, words):
    pytest.importorskip("matplotlib")
    (tmp_path / "junk.usda").write_text("this is not USD")
    fill = dict(stage=written, tmp=tmp_path, scene=ROOT / "examples" / "dam_break.toml", text=tmp_path / "junk.usda")
    code, _, err = run_cli(capsys, "preview", *[a.format(**fill) for a in argv])
    assert code == 2 and words in err, err


def test_preview_of_a_good_file_writes_the_png(tmp_path, capsys, written):
    pytest.importorskip("matplotlib")
    code, out, _ = run_cli(capsys, "preview", written, "--frames", "0,2", "--png", tmp_path / "p.png")
    assert code == 0 and (tmp_path / "p.png").stat().st_size > 1000


# ------------------------------------------------------------------------------------ bugs
def test_an_unexpected_exception_is_reported_as_a_bug_in_one_line(tmp_path, capsys, monkeypatch):
    def broken(args):
        raise ZeroDivisionError("float division by zero")

    monkeypatch.setattr(cli, "_main", broken)
    monkeypatch.delenv(cli.DEBUG_ENV, raising=False)
    code, out, err = run_cli(capsys, "check", scene_file(tmp_path))
    assert code == 3
    lines = err.strip().splitlines()
    assert len(lines) == 1 and "a bug in warp_mpm_bubbles" in lines[0] and "ZeroDivisionError" in lines[0]
    assert "issue tracker" in lines[0] and cli.DEBUG_ENV in lines[0]
    monkeypatch.setenv(cli.DEBUG_ENV, "1")
    assert main(["check", str(scene_file(tmp_path))]) == 3
    assert "Traceback" in capsys.readouterr().err


# ------------------------------------------------------------------------------ no silent hangs
class FakeSim:
    def __init__(self, limits_, fps=30.0, max_steps=100_000, frame=4):
        self.scene = Scene(Domain((0.4, 0.2), 0.0125), {"w": Material("w")}, [Box("w", (0, 0), (0.1, 0.1))],
                           solver=SolverSettings(max_steps_per_frame=max_steps), output=Output(fps=fps))
        self.frame = frame
        self._limits = limits_

    def dt_limits(self):
        return self._limits


@pytest.mark.parametrize("name", ["cfl", "capillary", "viscous", "gas_expansion", "max_dt"])
def test_a_frame_needing_too_many_steps_stops_before_it_starts(name):
    from warp_mpm_bubbles.io.guards import FrameTooLongError, frame_step_guard

    limits_ = {"cfl": 1e-3, "capillary": 1e-3, "viscous": 1e-3, "gas_expansion": 1e-3, "max_dt": 1e-3}
    limits_[name] = 1e-9  # 1/30 s / 1e-9 s = 3.3e7 steps
    with pytest.raises(FrameTooLongError) as err:
        frame_step_guard(FakeSim(limits_))
    msg = str(err.value)
    assert msg.startswith("frame 5: ") and f"the {name} limit" in msg and "3.33e+07 steps" in msg
    assert "max_steps_per_frame = 100,000" in msg and err.value.limit == name
    assert limits.STEP_FIXES[name][1] in msg
    # the same frame at the default limits: 33 steps, and a stated lower cap
    assert frame_step_guard(FakeSim({"cfl": 1e-3})) == pytest.approx(1 / 30 / 1e-3)
    with pytest.raises(FrameTooLongError):
        frame_step_guard(FakeSim({"cfl": 1e-3}), max_steps_per_frame=10)
    # mid-frame: what is left of the frame counts (1e-3 s left at 1e-9 s steps: 1e6 steps)
    assert frame_step_guard(FakeSim({"cfl": 1e-3}), remaining=0.01) == pytest.approx(10)
    with pytest.raises(FrameTooLongError, match="1e\\+06 steps"):
        frame_step_guard(FakeSim({"cfl": 1e-9}), remaining=1e-3)


def test_the_guard_falls_back_to_stable_dt():
    from warp_mpm_bubbles.io.guards import FrameTooLongError, frame_step_guard

    class Old(FakeSim):
        dt_limits = None

        def stable_dt(self):
            return 1e-12

    with pytest.raises(FrameTooLongError, match="the cfl limit"):
        frame_step_guard(Old({}))


def test_heartbeat_every_interval_on_a_pipe_and_never_on_a_terminal():
    from warp_mpm_bubbles.io.guards import Heartbeat

    now = [0.0]
    pipe = io.StringIO()
    beat = Heartbeat(pipe, interval_s=30, clock=lambda: now[0])
    written = []
    for step in range(1, 200):  # 199 steps, 1 s each
        now[0] += 1.0
        written.append(beat.tick(frame=3, steps=step, dt=2.5e-4, seconds=now[0]))
    assert sum(written) == 6 and [i + 1 for i, w in enumerate(written) if w] == [30, 60, 90, 120, 150, 180]
    assert pipe.getvalue().splitlines()[0] == "heartbeat: computing frame 3, 30 steps, dt 0.00025 s, 30 s elapsed"

    class Tty(io.StringIO):
        def isatty(self):
            return True

    tty = Tty()
    beat = Heartbeat(tty, interval_s=30, clock=lambda: now[0])
    now[0] += 1e4
    assert not beat.tick(1, 1, 1e-3, 1e4) and tty.getvalue() == ""


def test_step_limits_match_the_simulations_stable_dt(tmp_path):
    # The static estimate uses the formulas of Simulation.stable_dt at t = 0: they must agree.
    from warp_mpm_bubbles.core.simulation import Simulation

    scene = Scene(Domain((0.2, 0.1), 0.0125), {"w": Material("w", viscosity=0.5, surface_tension=0.072)},
                  [Box("w", (0, 0), (0.1, 0.05), velocity=(2.0, 0.0))], output=Output(path=str(tmp_path / "l.usdc")))
    static = min(limits.step_limits(scene.validate()).values())
    assert math.isclose(static, Simulation(scene, "cpu").stable_dt(), rel_tol=1e-5)


def test_a_huge_cross_section_is_refused_before_validation_samples_it(tmp_path, monkeypatch):
    # 4 x 16384 x 16384 cells (within the 2^30 cap): one slab of samples would be 1e11 bytes
    monkeypatch.setattr(limits, "host_available", lambda: 16 * 10**9)
    scene = Scene(Domain((0.004, 16.384, 16.384), 0.001), {"w": Material("w")},
                  [Box("w", (0, 0, 0), (0.004, 0.01, 0.01))], output=Output(path=str(tmp_path / "s.usdc")))
    with pytest.raises(limits.MemoryLimitError, match=r"needs about 1\d\d GB of host memory to sample one slab"):
        scene.validate()
