"""Scene loading, defaults, round trips and one test per class of bad input."""
import copy
import math
import os
from pathlib import Path

import pytest

from warp_mpm_bubbles.scene.model import (
    Box, Cylinder, Domain, Material, Output, Scene, SceneError, SolverSettings, Sphere, WALL_TYPES,
    load_scene,
)

EXAMPLES = Path(__file__).resolve().parent.parent / "examples"

GOOD_TOML = """
name = "tank"
[domain]
size = [0.4, 0.2]
cell_size = 0.02
gravity = [0.0, -9.81]
walls = { x_min = "no_slip", y_max = "open" }
[solver]
particles_per_cell = 4
cfl = 0.5
seed = 3
[materials.water]
kind = "liquid"
density = 1000.0
[materials.oil]
density = 800.0
color = [0.9, 0.7, 0.1]
[[shapes]]
type = "box"
material = "water"
min = [0.0, 0.0]
max = [0.1, 0.1]
[[shapes]]
type = "sphere"
material = "oil"
center = [0.3, 0.1]
radius = 0.05
velocity = [0.0, -1.0]
[[shapes]]
type = "cylinder"
material = "water"
center = [0.2, 0.05]
radius = 0.04
[output]
path = "out/tank.usdc"
fps = 24
frames = 10
"""


def good_dict():
    """The GOOD_TOML scene as a plain dict, for mutation by the bad-input cases."""
    return {
        "name": "tank",
        "domain": {"size": [0.4, 0.2], "cell_size": 0.02, "gravity": [0.0, -9.81],
                   "walls": {"x_min": "no_slip", "y_max": "open"}},
        "solver": {"particles_per_cell": 4, "cfl": 0.5, "seed": 3},
        "materials": {"water": {"kind": "liquid", "density": 1000.0},
                      "oil": {"density": 800.0, "color": [0.9, 0.7, 0.1]}},
        "shapes": [
            {"type": "box", "material": "water", "min": [0.0, 0.0], "max": [0.1, 0.1]},
            {"type": "sphere", "material": "oil", "center": [0.3, 0.1], "radius": 0.05,
             "velocity": [0.0, -1.0]},
            {"type": "cylinder", "material": "water", "center": [0.2, 0.05], "radius": 0.04},
        ],
        "output": {"path": "out/tank.usdc", "fps": 24, "frames": 10},
    }


def python_scene():
    return Scene(
        name="tank",
        domain=Domain(size=(0.4, 0.2), cell_size=0.02, gravity=(0.0, -9.81),
                      walls={"x_min": "no_slip", "y_max": "open"}),
        materials={"water": Material("water"), "oil": Material("oil", density=800.0, color=(0.9, 0.7, 0.1))},
        shapes=[Box("water", (0.0, 0.0), (0.1, 0.1)),
                Sphere("oil", (0.3, 0.1), 0.05, velocity=(0.0, -1.0)),
                Cylinder("water", (0.2, 0.05), 0.04)],
        solver=SolverSettings(particles_per_cell=4, cfl=0.5, seed=3),
        output=Output(path="out/tank.usdc", fps=24, frames=10),
    ).validate()


@pytest.fixture(autouse=True)
def in_tmp(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)  # relative output paths resolve here


def write(tmp_path, text, name="scene.toml"):
    path = tmp_path / name
    path.write_text(text)
    return path


# --- good scenes -------------------------------------------------------------

def test_toml_and_python_api_agree(tmp_path):
    from_file = load_scene(write(tmp_path, GOOD_TOML))
    assert from_file.source.endswith("scene.toml")
    assert from_file.to_dict() == python_scene().to_dict() == Scene.from_dict(good_dict()).to_dict()


def test_round_trip_and_idempotent_validate():
    scene = python_scene()
    d = scene.to_dict()
    assert Scene.from_dict(copy.deepcopy(d)).to_dict() == d
    assert scene.validate().to_dict() == d


def test_defaults_resolved_2d():
    scene = Scene(Domain((0.4, 0.2), 0.02), {"w": Material("w")},
                  [Box("w", (0, 0), (0.1, 0.1)), Cylinder("w", (0.2, 0.1), 0.05)]).validate()
    assert scene.dim == 2
    assert scene.domain.gravity == (0.0, -9.81)
    assert scene.domain.walls == dict.fromkeys(("x_min", "x_max", "y_min", "y_max"), "free_slip")
    assert scene.domain.cells == (20, 10, 1)
    assert scene.solver.particles_per_cell == 4
    assert scene.output.particle_radius == pytest.approx(0.5 * 0.02 / 2)
    assert scene.shapes[0].velocity == (0.0, 0.0)
    assert scene.shapes[1].length == pytest.approx(0.02)  # 2D disk: slab thickness


def test_defaults_resolved_3d():
    scene = Scene(Domain((0.4, 0.2, 0.1), 0.02), {"w": Material("w")},
                  [Cylinder("w", (0.2, 0.1, 0.03), 0.05, axis="z")]).validate()
    assert scene.domain.gravity == (0.0, -9.81, 0.0)
    assert scene.domain.cells == (20, 10, 5)
    assert scene.solver.particles_per_cell == 8
    assert scene.output.particle_radius == pytest.approx(0.5 * 0.02 / 2)
    cyl = scene.shapes[0]
    assert cyl.length == pytest.approx(0.1) and cyl.center[2] == pytest.approx(0.05)  # spans z
    assert cyl.velocity == (0.0, 0.0, 0.0)
    lo, hi = cyl.bounds()
    assert lo[2] == pytest.approx(0.0) and hi[2] == pytest.approx(0.1)


def test_wall_types():
    domain = Domain((0.4, 0.2), 0.02, walls={"x_min": "no_slip", "y_max": "open"})
    assert domain.wall_types == (0, 1, 1, 2, 1, 1)
    assert Domain((0.4, 0.2, 0.2), 0.02, walls="open").wall_types == (WALL_TYPES.index("open"),) * 6


def test_name_defaults_to_file_stem(tmp_path):
    text = GOOD_TOML.replace('name = "tank"\n', "")
    assert load_scene(write(tmp_path, text, "my_scene.toml")).name == "my_scene"


def test_integral_float_accepted_for_int():
    d = good_dict()
    d["solver"]["particles_per_cell"] = 4.0
    assert Scene.from_dict(d).solver.particles_per_cell == 4


def test_replace_output(tmp_path):
    scene = python_scene()
    new = scene.replace_output(path=tmp_path / "a" / "b.usda", frames=3)
    assert (new.output.path, new.output.frames) == (str(tmp_path / "a" / "b.usda"), 3)
    assert scene.output.frames == 10  # original untouched
    with pytest.raises(SceneError, match=r"\[output\].frames"):
        scene.replace_output(frames=0)


def test_missing_parent_directory_is_fine(tmp_path):
    d = good_dict()
    d["output"]["path"] = str(tmp_path / "new" / "deeper" / "x.usdc")
    Scene.from_dict(d)


def test_example_dam_break_loads():
    scene = load_scene(EXAMPLES / "dam_break.toml")
    assert scene.dim == 3 and scene.domain.cells == (64, 32, 16)
    assert scene.solver.particles_per_cell == 8 and scene.output.frames == 48


# --- bad input ---------------------------------------------------------------

def setk(*path, value):
    """Mutation setting d[path...] = value."""
    def mutate(d):
        for k in path[:-1]:
            d = d[k]
        d[path[-1]] = value
    return mutate


def delk(*path):
    def mutate(d):
        for k in path[:-1]:
            d = d[k]
        del d[path[-1]]
    return mutate


NAN, INF = float("nan"), float("inf")

# (id, mutation, substrings the message must contain: key path and offending value)
BAD = [
    ("unknown top key", setk("nme", value="x"), ["unknown key nme", "'x'", "did you mean 'name'"]),
    ("unknown domain key", setk("domain", "cellsize", value=0.1), ["[domain].cellsize", "0.1", "'cell_size'"]),
    ("unknown solver key", setk("solver", "cfll", value=1), ["[solver].cfll", "= 1", "'cfl'"]),
    ("unknown output key", setk("output", "fsp", value=30), ["[output].fsp", "30", "'fps'"]),
    ("unknown material key", setk("materials", "oil", "name", value="o"), ["[materials.oil].name", "'o'"]),
    ("key of other shape type", setk("shapes", 0, "radius", value=0.1), ["[shapes.0].radius", "0.1"]),
    ("missing cell_size", delk("domain", "cell_size"), ["missing required key [domain].cell_size"]),
    ("missing domain", delk("domain"), ["missing required key [domain]"]),
    ("missing shape type", delk("shapes", 1, "type"), ["[shapes.1].type"]),
    ("missing box max", delk("shapes", 0, "max"), ["[shapes.0].max"]),
    ("bad shape type", setk("shapes", 0, "type", value="cube"), ["[shapes.0].type", "'cube'", "'box'"]),
    ("table expected", setk("domain", value=5), ["[domain] = 5", "table"]),
    ("shapes not a list", setk("shapes", value={"a": 1}), ["[shapes]", "[[shapes]]"]),
    ("name not a string", setk("name", value=3), ["name = 3"]),
    ("string for number", setk("domain", "cell_size", value="0.02"), ["[domain].cell_size", "'0.02'", "str"]),
    ("bool for number", setk("materials", "water", "density", value=True),
     ["[materials.water].density", "True", "bool"]),
    ("float for int", setk("solver", "particles_per_cell", value=4.5), ["[solver].particles_per_cell", "4.5"]),
    ("float for int frames", setk("output", "frames", value=2.5), ["[output].frames", "2.5"]),
    ("gravity length", setk("domain", "gravity", value=[0, -9.81, 0]), ["[domain].gravity", "[0, -9.81, 0]", "2D"]),
    ("box min length", setk("shapes", 0, "min", value=[0, 0, 0]), ["[shapes.0].min", "[0, 0, 0]", "2 numbers"]),
    ("size length", setk("domain", "size", value=[0.4]), ["[domain].size", "[0.4]"]),
    ("vector not a list", setk("shapes", 1, "center", value=0.3), ["[shapes.1].center", "0.3"]),
    ("nan number", setk("solver", "cfl", value=NAN), ["[solver].cfl", "nan", "finite"]),
    ("inf in vector", setk("shapes", 1, "velocity", value=[INF, 0.0]), ["[shapes.1].velocity", "inf"]),
    ("nan gravity", setk("domain", "gravity", value=[0.0, NAN]), ["[domain].gravity", "nan"]),
    ("zero size", setk("domain", "size", value=[0.0, 0.2]), ["[domain].size", "0.0", "> 0"]),
    ("negative cell_size", setk("domain", "cell_size", value=-0.02), ["[domain].cell_size", "-0.02", "> 0"]),
    ("zero density", setk("materials", "water", "density", value=0), ["[materials.water].density", "= 0"]),
    ("color out of range", setk("materials", "oil", "color", value=[1.5, 0, 0]), ["[materials.oil].color", "1.5"]),
    ("zero radius", setk("shapes", 1, "radius", value=0.0), ["[shapes.1].radius", "0.0"]),
    ("negative length", setk("shapes", 2, "length", value=-1.0), ["[shapes.2].length", "-1.0"]),
    ("bad cylinder axis", setk("shapes", 2, "axis", value="w"), ["[shapes.2].axis", "'w'"]),
    ("zero fps", setk("output", "fps", value=0), ["[output].fps", "= 0"]),
    ("zero frames", setk("output", "frames", value=0), ["[output].frames", "= 0", ">= 1"]),
    ("box min >= max", setk("shapes", 0, "max", value=[0.1, 0.0]), ["[shapes.0].min", "[0.0, 0.0]", "[0.1, 0.0]"]),
    ("size not whole cells", setk("domain", "size", value=[0.41, 0.2]),
     ["[domain].size", "[0.41, 0.2]", "20.5 cells", "0.4 (20 cells)", "0.42 (21 cells)"]),
    ("too few cells", setk("domain", "cell_size", value=0.1), ["[domain].size", "2 cells", "at least 4"]),
    ("unknown wall type", setk("domain", "walls", value="sticky"), ["[domain].walls", "'sticky'", "'no_slip'"]),
    ("unknown wall type in table", setk("domain", "walls", value={"x_min": "noslip"}),
     ["[domain].walls.x_min", "'noslip'", "did you mean 'no_slip'"]),
    ("unknown wall key", setk("domain", "walls", value={"top": "open"}), ["[domain].walls.top", "'open'", "x_min"]),
    ("z wall in 2D", setk("domain", "walls", value={"z_min": "open"}), ["[domain].walls.z_min", "'open'", "3D"]),
    ("huge domain", setk("domain", "size", value=[6e16, 1.0]), ["[domain].size", "cells", "at most"]),
    ("unknown material kind", setk("materials", "water", "kind", value="soap"),
     ["[materials.water].kind", "'soap'", "'liquid'", "'gas'", "'foam'"]),
    ("foam placed by a shape", setk("materials", "water", "kind", value="foam"),
     ["[shapes.0].material", "'water'", "[effects.foam]"]),
    ("undefined material", setk("shapes", 0, "material", value="oli"), ["[shapes.0].material", "'oli'", "'oil'"]),
    ("no materials", setk("materials", value={}), ["[materials]", "no materials"]),
    ("no shapes", setk("shapes", value=[]), ["[shapes]", "no shapes"]),
    ("shape outside domain", setk("shapes", 0, "max", value=[0.5, 0.1]),
     ["[shapes.0]", "max=[0.5, 0.1]", "not inside the domain", "[0.4, 0.2]"]),
    ("sphere outside domain", setk("shapes", 1, "center", value=[0.38, 0.1]), ["[shapes.1]", "[0.38, 0.1]"]),
    ("bad suffix", setk("output", "path", value="out.obj"), ["[output].path", "'out.obj'", ".usdc"]),
    ("tiny shape", setk("shapes", 1, "radius", value=0.001),
     ["[shapes.1]", "radius=0.001", "seeds no particles", "cell_size"]),
    ("ppc too big", setk("solver", "particles_per_cell", value=65), ["[solver].particles_per_cell", "65", "<= 64"]),
    ("cfl too big", setk("solver", "cfl", value=3), ["[solver].cfl", "3", "<= 2"]),
    ("zero max_dt", setk("solver", "max_dt", value=0.0), ["[solver].max_dt", "0.0"]),
    ("cg tolerance 1", setk("solver", "cg_tolerance", value=1.0), ["[solver].cg_tolerance", "1.0", "< 1"]),
    ("cg iterations 0", setk("solver", "cg_max_iterations", value=0), ["[solver].cg_max_iterations", "0"]),
    ("bad preconditioner", setk("solver", "preconditioner", value="ilu"), ["[solver].preconditioner", "'ilu'"]),
    ("negative volume_relaxation_time", setk("solver", "volume_relaxation_time", value=-1),
     ["[solver].volume_relaxation_time", "-1"]),
    ("negative seed", setk("solver", "seed", value=-1), ["[solver].seed", "-1"]),
    ("bad format", setk("output", "format", value="mesh"), ["[output].format", "'mesh'", "'instancer'"]),
    ("bad up axis", setk("output", "up_axis", value="X"), ["[output].up_axis", "'X'"]),
    ("zero particle radius", setk("output", "particle_radius", value=0), ["[output].particle_radius", "0"]),
    ("bad gas law", setk("materials", "oil", value={"kind": "gas", "eos": "vdw"}),
     ["[materials.oil].eos", "'vdw'", "'isothermal'"]),
    ("eos on a liquid", setk("materials", "oil", "eos", value="isothermal"),
     ["[materials.oil].eos", "only gas materials"]),
    ("gamma not above 1", setk("materials", "oil", value={"kind": "gas", "gamma": 1.0}),
     ["[materials.oil].gamma", "1.0", "> 1"]),
    ("zero ambient pressure", setk("domain", "ambient_pressure", value=0.0), ["[domain].ambient_pressure", "0.0"]),
    ("bad interface", setk("solver", "interface", value="level_set"), ["[solver].interface", "'level_set'", "'sharp'"]),
    ("bad liquid velocity", setk("solver", "liquid_velocity", value="separate"),
     ["[solver].liquid_velocity", "'separate'", "'own'", "'shared'"]),
    ("bad gas films", setk("solver", "gas_films", value="retracted"),
     ["[solver].gas_films", "'retracted'", "'retract'", "'passive'", "did you mean"]),
    ("negative surface tension", setk("materials", "water", "surface_tension", value=-0.07),
     ["[materials.water].surface_tension", "-0.07", ">= 0"]),
    ("surface tension on a gas", setk("materials", "oil", value={"kind": "gas", "surface_tension": 0.07}),
     ["[materials.oil].surface_tension", "belongs to the liquid"]),
    ("negative viscosity", setk("materials", "water", "viscosity", value=-1e-3),
     ["[materials.water].viscosity", "-0.001", ">= 0"]),
]


@pytest.mark.parametrize("mutate, expected", [b[1:] for b in BAD], ids=[b[0] for b in BAD])
def test_bad_input(mutate, expected):
    d = good_dict()
    mutate(d)
    with pytest.raises(SceneError) as err:
        Scene.from_dict(d, source="bad.toml")
    msg = str(err.value)
    assert msg.startswith("bad.toml: ")
    for part in expected:
        assert part in msg, f"{part!r} not in {msg!r}"
    assert err.value.key and err.value.key.split(".")[0] in msg


def test_unknown_key_message_from_file(tmp_path):
    path = write(tmp_path, GOOD_TOML.replace("density = 1000.0", "densty = 1000.0"), "dam.toml")
    with pytest.raises(SceneError) as err:
        load_scene(path)
    assert str(err.value) == (f"{path}: unknown key [materials.water].densty = 1000.0; "
                              "allowed keys: kind, density, color, eos, gamma, surface_tension, viscosity (did you mean 'density'?)")
    assert err.value.key == "[materials.water].densty" and err.value.value == 1000.0


def test_nan_from_toml_file(tmp_path):
    with pytest.raises(SceneError, match=r"scene.toml: \[domain\].cell_size = nan"):
        load_scene(write(tmp_path, GOOD_TOML.replace("cell_size = 0.02", "cell_size = nan")))


def test_z_gravity_for_3d_python_api():
    scene = Scene(Domain((0.4, 0.2, 0.2), 0.02, gravity=(0, -9.81)), {"w": Material("w")},
                  [Box("w", (0, 0, 0), (0.1, 0.1, 0.1))])
    with pytest.raises(SceneError, match=r"<python>: \[domain\].gravity = \[0, -9.81\].*3D"):
        scene.validate()


def test_material_name_must_match_key():
    scene = Scene(Domain((0.4, 0.2), 0.02), {"w": Material("water")}, [Box("w", (0, 0), (0.1, 0.1))])
    with pytest.raises(SceneError, match=r"\[materials.w\].name = 'water'"):
        scene.validate()


def test_output_parent_is_a_file(tmp_path):
    (tmp_path / "file.txt").write_text("x")
    d = good_dict()
    d["output"]["path"] = "file.txt/sub/out.usdc"
    with pytest.raises(SceneError) as err:
        Scene.from_dict(d, source="bad.toml")
    assert "[output].path = 'file.txt/sub/out.usdc'" in str(err.value) and "not a directory" in str(err.value)


def test_output_path_is_a_directory(tmp_path):
    (tmp_path / "d.usdc").mkdir()
    d = good_dict()
    d["output"]["path"] = "d.usdc"
    with pytest.raises(SceneError, match=r"\[output\].path = 'd.usdc': is a directory"):
        Scene.from_dict(d)


@pytest.mark.skipif(os.name != "posix" or os.geteuid() == 0, reason="root can write anywhere")
def test_output_parent_read_only(tmp_path):
    ro = tmp_path / "ro"
    ro.mkdir()
    ro.chmod(0o500)
    try:
        d = good_dict()
        d["output"]["path"] = str(ro / "x" / "out.usdc")
        with pytest.raises(SceneError, match="not writable"):
            Scene.from_dict(d)
    finally:
        ro.chmod(0o700)


@pytest.mark.parametrize("text, line", [('name = "x"\n[domain]\ncell_size = = 0.02\n', 3),
                                        ('name = "x"\n\n[domain]\nsize = [0.4, 0.2\n', 4)])
def test_toml_syntax_error(tmp_path, text, line):
    path = write(tmp_path, text, "broken.toml")
    with pytest.raises(SceneError) as err:
        load_scene(path)
    assert str(err.value).startswith(f"{path}: invalid TOML") and f"line {line}" in str(err.value)


def test_missing_file(tmp_path):
    with pytest.raises(SceneError, match="nope.toml: scene file not found"):
        load_scene(tmp_path / "nope.toml")


def test_scene_error_is_value_error():
    assert issubclass(SceneError, ValueError)
    assert math.isclose(Scene.from_dict(good_dict()).domain.cell_size, 0.02)


def test_gas_material_defaults():
    gas = Material("air", kind="gas")
    Scene(domain=Domain(size=(0.4, 0.2), cell_size=0.02), materials={"air": gas},
          shapes=[Box("air", (0.0, 0.0), (0.1, 0.1))]).validate()
    assert (gas.density, gas.eos, gas.gamma) == (1.2, "isothermal", 1.4)
    assert gas.is_gas and not Material("water").is_gas


def test_quality_presets_fill_unset_settings_and_the_scene_wins():
    from warp_mpm_bubbles.scene.quality import PRESETS

    def scene(**solver):
        return Scene(Domain((0.4, 0.2), 0.02), {"w": Material("w")}, [Box("w", (0, 0), (0.4, 0.1))],
                     solver=SolverSettings(**solver)).validate()

    production = scene()
    assert production.solver.quality == "production"
    assert (production.solver.cfl, production.solver.cg_tolerance, production.solver.refine) == (0.5, 1e-5, 1)
    preview = scene(quality="preview", cfl=0.7)  # the scene's own cfl wins over the preset's
    assert preview.solver.cfl == 0.7 and preview.solver.cg_tolerance == PRESETS["preview"]["cg_tolerance"]
    # --quality replaces the scene's values, the derived particle radius included.
    reference = preview.with_quality("reference")
    assert reference.solver.cfl == PRESETS["reference"]["cfl"] and reference.solver.refine == 2
    assert reference.domain.cells == (40, 20, 1) and reference.domain.dx == pytest.approx(0.01)
    assert reference.domain.cell_size == 0.02  # the scene's geometry stays as written
    assert reference.output.particle_radius == pytest.approx(0.5 * 0.01 / 2)
    assert reference.with_quality("production").domain.cells == (20, 10, 1)
    with pytest.raises(SceneError, match=r"\[solver\].quality = 'ultra'.*'preview'"):
        scene(quality="ultra")


def test_quality_flag_rederives_grid_defaults_of_effects():
    # Sub-grid threshold and entrainment bubble radius default to the grid spacing: --quality
    # reference halves both, exactly as writing quality = "reference" in the file does.
    from warp_mpm_bubbles.scene.model import tomllib  # tomli on Python 3.10

    d = tomllib.loads((EXAMPLES / "plunge.toml").read_text())
    d.setdefault("solver", {})["quality"] = "reference"
    in_file = Scene.from_dict(d)
    flag = load_scene(EXAMPLES / "plunge.toml").with_quality("reference")
    for key, field in (("subgrid_bubbles", "radius"), ("entrainment", "bubble_radius")):
        assert getattr(flag.effects[key], field) == getattr(in_file.effects[key], field)
    assert flag.effects["subgrid_bubbles"].radius == pytest.approx(0.0025)  # dx = 5 mm / 2


def test_foam_takes_no_viscosity_or_surface_tension():
    for key in ("viscosity", "surface_tension"):
        with pytest.raises(SceneError, match=rf"\[materials.foam\].{key}.*foam takes no"):
            Scene(Domain((0.4, 0.2), 0.02), {"w": Material("w"), "foam": Material("foam", kind="foam", **{key: 0.01})},
                  [Box("w", (0, 0), (0.4, 0.1))]).validate()
