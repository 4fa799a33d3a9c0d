"""Wedges (io/wedge.py): members validated before anything runs, run as Dask tasks on a 2-worker
LocalCluster, equal to separate runs bit for bit, surviving a killed worker, reporting a member
that fails, one wedge per folder, and a wedge.usda whose variants are the members."""

import copy
import functools
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from warp_mpm_bubbles.cli import main
from warp_mpm_bubbles.io.usd_output import read_frames
from warp_mpm_bubbles.io.wedge import WedgeError, WedgeLock, parse_vary, plan_wedge, run_wedge
from scenes import dam_break_2d

CFL = [0.3, 0.5]
TENSION = [0.0, 0.072]
VARY = {"solver.cfl": CFL, "materials.water.surface_tension": TENSION}


def small(out):
    """512 particles in a 32 x 20 grid, 3 frames at 60 fps: about a second a run."""
    scene = dam_break_2d(a=0.1, cells_per_a=8, length=4.0, out=out)
    scene.output.fps, scene.output.frames = 60.0, 3
    return scene.validate()


# ---------------------------------------------------------------------------- before anything runs
def test_vary_values_are_toml_literals():
    assert parse_vary("solver.cfl=0.3,0.5") == ("solver.cfl", [0.3, 0.5])
    assert parse_vary("domain.gravity=[0.0,-9.81],[0.0,-1.62]") == ("domain.gravity", [[0.0, -9.81], [0.0, -1.62]])
    assert parse_vary("solver.quality=preview,'production'") == ("solver.quality", ["preview", "production"])
    with pytest.raises(WedgeError, match="expected KEY=V1,V2"):
        parse_vary("solver.cfl")


def test_every_member_is_validated_before_anything_runs(tmp_path):
    out = tmp_path / "w"
    with pytest.raises(WedgeError) as err:  # member 3 (the product's last) has an impossible cfl
        run_wedge(small(tmp_path / "s.usdc"), {"solver.cfl": [0.5, 5.0], "solver.seed": [0, 1]}, out=out)
    msg = str(err.value)
    assert "wedge member 2 'cfl=5.0_seed=0'" in msg and "[solver].cfl = 5.0" in msg and "<= 2" in msg
    assert not out.exists()  # refused before any folder or run
    with pytest.raises(WedgeError, match=r"materials has no 'wter'.*did you mean 'water'"):
        plan_wedge(small(tmp_path / "s.usdc"), {"materials.wter.density": [900.0]}, out)
    with pytest.raises(WedgeError, match=r"unknown key \[solver\].cfel.*did you mean 'cfl'"):
        plan_wedge(small(tmp_path / "s.usdc"), {"solver.cfel": [0.4]}, out)
    with pytest.raises(WedgeError, match="--zip needs the same number of values"):
        plan_wedge(small(tmp_path / "s.usdc"), {"solver.cfl": [0.3, 0.4], "solver.seed": [1]}, out, zip_members=True)
    with pytest.raises(WedgeError, match="sets each member's output path"):
        plan_wedge(small(tmp_path / "s.usdc"), {"output.path": ["a.usdc"]}, out)
    with pytest.raises(WedgeError, match=r"--frame 4: .* within 0..3"):
        run_wedge(small(tmp_path / "s.usdc"), {"solver.cfl": [0.4]}, out=out, frame=4)
    assert not out.exists()
    theirs = out / "cfl=0.4" / "s.usdc"  # a file the wedge did not write, where a member would write
    theirs.parent.mkdir(parents=True)
    theirs.write_text("not ours")
    with pytest.raises(WedgeError, match=r"wedge member 0 'cfl=0.4': .* holds files this wedge did not write"):
        run_wedge(small(tmp_path / "s.usdc"), {"solver.cfl": [0.4]}, out=out)
    assert theirs.read_text() == "not ours"


def test_members_are_the_product_or_the_zip_named_for_their_values(tmp_path):
    folder, members = plan_wedge(small(tmp_path / "s.usdc"), VARY, tmp_path / "w")
    assert [m.name for m in members] == ["cfl=0.3_surface_tension=0.0", "cfl=0.3_surface_tension=0.072",
                                         "cfl=0.5_surface_tension=0.0", "cfl=0.5_surface_tension=0.072"]
    assert members[3].scene["solver"]["cfl"] == 0.5 and members[3].scene["materials"]["water"]["surface_tension"] == 0.072
    assert members[1].stage == str(folder / "cfl=0.3_surface_tension=0.072" / "s.usdc")
    _, zipped = plan_wedge(small(tmp_path / "s.usdc"), VARY, tmp_path / "w", zip_members=True)
    assert [m.values for m in zipped] == [{"solver.cfl": 0.3, "materials.water.surface_tension": 0.0},
                                          {"solver.cfl": 0.5, "materials.water.surface_tension": 0.072}]
    # A default derived from a varied setting is derived again per member: the particle radius
    _, by_cell = plan_wedge(small(tmp_path / "s.usdc"), {"domain.cell_size": [0.0125, 0.025]}, tmp_path / "w")
    assert "particle_radius" not in by_cell[0].scene["output"]


def toml_scene(tmp_path):
    scene = tmp_path / "s.toml"
    scene.write_text('[domain]\nsize = [0.4, 0.2]\ncell_size = 0.0125\n[materials.water]\n'
                     '[[shapes]]\ntype = "box"\nmaterial = "water"\nmin = [0.0, 0.0]\nmax = [0.1, 0.15]\n'
                     f'[output]\npath = "{(tmp_path / "s.usdc").as_posix()}"\nfps = 60\nframes = 2\n')
    return scene


def test_cli_refuses_a_bad_member_with_exit_code_2(tmp_path, capsys):
    scene = toml_scene(tmp_path)
    assert main(["wedge", str(scene), "--vary", "materials.water.density=1000,-1", "--out", str(tmp_path / "w")]) == 2
    err = capsys.readouterr().err
    assert "wedge member 1 'density=-1'" in err and "[materials.water].density" in err
    assert not (tmp_path / "w").exists()


def test_a_second_wedge_on_a_folder_is_refused_and_a_dead_ones_lock_is_taken_over(tmp_path):
    folder = tmp_path / "w"
    with WedgeLock(folder):
        with pytest.raises(WedgeError, match=rf"{folder} is in use by another wedge \(host .*, pid {os.getpid()}"):
            run_wedge(small(tmp_path / "s.usdc"), {"solver.cfl": [0.4]}, out=folder)
        with pytest.raises(WedgeError, match="in use by another wedge"):
            WedgeLock(folder).__enter__()
    assert not (folder / ".wedge.lock").exists()  # released
    assert sorted(p.name for p in folder.iterdir()) == []  # the refused wedge wrote nothing
    dead = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True, text=True)
    lock = WedgeLock(folder)
    (folder / ".wedge.lock").write_text(f'{{"host": "{lock.owner["host"]}", "pid": {int(dead.stdout)}, "started": 0}}')
    with lock:  # its process is gone: stale
        assert (folder / ".wedge.lock").read_text().count(str(os.getpid())) == 1


# ---------------------------------------------------------------------------- on a 2-worker LocalCluster
@pytest.fixture(scope="module")
def client():
    distributed = pytest.importorskip("distributed")
    import cloudpickle

    cloudpickle.register_pickle_by_value(sys.modules[__name__])  # the fault hooks below, for the workers
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None) as c:
        with distributed.Client(c) as cl:
            yield cl


@pytest.fixture(scope="module")
def references(tmp_path_factory):
    """The four members run one by one in this process, built with the Python API (not the wedge's
    dict path), so equal outputs also prove each member got its values."""
    import warp as wp
    from warp_mpm_bubbles.io.runner import run_scene

    wp.config.log_level = getattr(wp, "LOG_WARNING", 30)
    base = tmp_path_factory.mktemp("refs")
    refs = {}
    for cfl in CFL:
        for sigma in TENSION:
            scene = copy.deepcopy(small(base / "x.usdc"))
            scene.solver.cfl = cfl
            scene.materials["water"].surface_tension = sigma
            scene = scene.replace_output(path=base / f"{cfl}_{sigma}.usdc")
            run = run_scene(scene, device="cpu", progress=False)
            refs[(cfl, sigma)] = {"frames": read_frames(scene.output.path)["frames"], "steps": run.simulation.stats.steps,
                                  "cg": run.simulation.stats.cg_iterations}
    last = {k: r["frames"][3]["positions"] for k, r in refs.items()}
    for a in last:  # every variation changes the result, so matching the right one means something
        for b in last:
            assert a == b or not np.array_equal(last[a], last[b])
    return refs


def assert_matches(result, references):
    for m, r in zip(result.members, result.results):
        ref = references[(m.values["solver.cfl"], m.values["materials.water.surface_tension"])]
        got = read_frames(m.stage)["frames"]
        assert sorted(got) == [0, 1, 2, 3]
        for f in got:  # bit for bit, every frame
            np.testing.assert_array_equal(got[f]["positions"], ref["frames"][f]["positions"])
            np.testing.assert_array_equal(got[f]["velocities"], ref["frames"][f]["velocities"])
        assert r["steps"] == ref["steps"]


@pytest.mark.slow
def test_a_wedge_equals_separate_runs_bit_for_bit(tmp_path, client, references):
    result = run_wedge(small(tmp_path / "s.usdc"), VARY, out=tmp_path / "w", scheduler=client, device="cpu",
                       progress=False)
    assert result.ok and [r["status"] for r in result.results] == ["ok"] * 4
    assert_matches(result, references)
    for m, r in zip(result.members, result.results):  # a fresh run: CG effort as in the separate run
        assert r["cg_iterations"] == references[(m.values["solver.cfl"], m.values["materials.water.surface_tension"])]["cg"]
        assert r["attempts"] == 1 and r["resumed"] is False
    assert len({r["worker"] for r in result.results}) == 2  # both workers took members
    rows = (tmp_path / "w" / "summary.csv").read_text().splitlines()
    assert rows[0].startswith("member,values,status,wall_s,cpu_s,steps,cg_iterations")
    assert len(rows) == 5 and all(",ok," in row for row in rows[1:])
    assert (tmp_path / "w" / "summary.md").read_text().count("| ok |") == 4
    png = (tmp_path / "w" / "contact_sheet.png").read_bytes()
    assert png[:8] == b"\x89PNG\r\n\x1a\n" and len(png) > 10_000
    assert not (tmp_path / "w" / ".wedge.lock").exists()
    check_wedge_stage(result, references)


def check_wedge_stage(result, references):
    """wedge.usda opens; each variant selection composes that member's particles, every frame."""
    from pxr import Usd, UsdGeom

    stage = Usd.Stage.Open(str(result.files["stage"]))
    world = stage.GetPrimAtPath("/World")
    vset = world.GetVariantSets().GetVariantSet("wedge")
    assert len(vset.GetVariantNames()) == 4
    assert (stage.GetStartTimeCode(), stage.GetEndTimeCode(), stage.GetTimeCodesPerSecond()) == (0, 3, 60)
    for m, variant in zip(result.members, ["cfl_0_3_surface_tension_0_0", "cfl_0_3_surface_tension_0_072",
                                           "cfl_0_5_surface_tension_0_0", "cfl_0_5_surface_tension_0_072"]):
        assert vset.SetVariantSelection(variant)
        positions = UsdGeom.PointInstancer.Get(stage, "/World/Particles").GetPositionsAttr()
        ref = references[(m.values["solver.cfl"], m.values["materials.water.surface_tension"])]["frames"]
        for f in (0, 3):
            np.testing.assert_array_equal(np.asarray(positions.Get(f)), ref[f]["positions"])


def kill_worker_after_first_frame(target, spec):
    """Test hook, in the worker: on the member's first attempt, kill this worker process right
    after frame 1 and its checkpoint are on disk (as a lost machine or an OOM kill would)."""
    if spec["index"] != target:
        return None
    marker = Path(spec["scene"]["output"]["path"]).parent / "killed-once"
    if marker.exists():
        return None
    from warp_mpm_bubbles.io import runner

    save = runner.save_checkpoint

    def save_then_die(sim, path):
        save(sim, path)
        if sim.frame >= 1:
            marker.touch()
            os._exit(1)

    runner.save_checkpoint = save_then_die
    return lambda: setattr(runner, "save_checkpoint", save)


@pytest.mark.slow
def test_a_killed_worker_is_replaced_and_its_member_resumes_to_the_same_output(tmp_path, client, references):
    hook = functools.partial(kill_worker_after_first_frame, 1)
    result = run_wedge(small(tmp_path / "s.usdc"), VARY, out=tmp_path / "w", scheduler=client, device="cpu",
                       progress=False, before_member=hook)
    assert (Path(result.members[1].stage).parent / "killed-once").exists()  # the kill happened
    assert [r["status"] for r in result.results] == ["ok"] * 4
    assert result.results[1]["attempts"] == 2 and result.results[1]["resumed"] is True
    assert [r["attempts"] for i, r in enumerate(result.results) if i != 1] == [1, 1, 1]
    assert "resuming" in (Path(result.members[1].stage).parent / "member.log").read_text()
    assert_matches(result, references)


def nan_after_first_frame(target, spec):
    """Test hook: the member's velocities turn NaN after frame 1, as a diverged step leaves them."""
    if spec["index"] != target:
        return None
    from warp_mpm_bubbles.io import runner

    save = runner.save_checkpoint

    def save_then_poison(sim, path):
        save(sim, path)
        if sim.frame == 1:
            v = sim.particles.v
            v.assign(np.full((v.shape[0], 3), np.nan, np.float32))

    runner.save_checkpoint = save_then_poison
    return lambda: setattr(runner, "save_checkpoint", save)


@pytest.mark.slow
def test_a_failing_member_is_reported_and_the_others_finish(tmp_path, client, references):
    result = run_wedge(small(tmp_path / "s.usdc"), VARY, out=tmp_path / "w", scheduler=client, device="cpu",
                       progress=False, zip_members=True, before_member=functools.partial(nan_after_first_frame, 0))
    failed, fine = result.results
    assert not result.ok
    assert failed["status"] == "failed" and "non-finite position or velocity" in failed["message"]
    assert failed["attempts"] == 1  # bad physics is reported, not retried
    assert fine["status"] == "ok"
    ref = references[(0.5, 0.072)]["frames"]
    np.testing.assert_array_equal(read_frames(result.members[1].stage)["frames"][3]["positions"], ref[3]["positions"])
    summary = (tmp_path / "w" / "summary.md").read_text()
    assert "1/2 members finished" in summary and "| failed |" in summary and "non-finite" in summary
    assert sorted(read_frames(result.members[0].stage)["frames"]) == [0, 1]  # what it wrote before failing


@pytest.mark.slow
def test_cli_wedge_on_a_running_scheduler_and_a_rerun_picks_up_the_finished_members(tmp_path, client, capsys):
    args = ["wedge", str(toml_scene(tmp_path)), "--vary", "solver.cfl=0.3,0.5", "--vary", "solver.seed=0,1", "--zip",
            "--out", str(tmp_path / "w"), "--scheduler", client.scheduler.address, "--device", "cpu", "--quiet"]
    assert main(args) == 0
    assert "2/2 members finished" in capsys.readouterr().out
    stage = tmp_path / "w" / "cfl=0.5_seed=1" / "s.usdc"
    first = read_frames(stage)["frames"]
    assert main(args) == 0  # the same wedge again: each member resumes from its final checkpoint
    rows = (tmp_path / "w" / "summary.csv").read_text().splitlines()[1:]
    assert [row.split(",")[0] for row in rows] == ["cfl=0.3_seed=0", "cfl=0.5_seed=1"]
    assert all(",ok," in row and ",1,True,cpu," in row for row in rows)  # attempts 1, resumed
    again = read_frames(stage)["frames"]
    assert sorted(again) == [0, 1, 2]
    np.testing.assert_array_equal(again[2]["positions"], first[2]["positions"])
