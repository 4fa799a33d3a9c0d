"""The Python API from its docs (issue #14 item 5): help() lists it, every scene field is documented
with its unit, the effect, emitter and collider classes are exported, docs/api.md's example works."""

import dataclasses
import pathlib
import pydoc
import re

import pytest

import warp_mpm_bubbles
from warp_mpm_bubbles.scene.model import Box, Cylinder, Domain, Material, Output, Scene, SolverSettings, Sphere

ROOT = pathlib.Path(__file__).resolve().parents[1]


def test_help_lists_run_scene_and_simulation():
    text = pydoc.render_doc(warp_mpm_bubbles, renderer=pydoc.plaintext)
    for name in ("run_scene", "Simulation", "load_scene", "Scene", "Collider", "LiquidInflow", "Foam"):
        assert name in warp_mpm_bubbles.__all__
        assert re.search(rf"\b{name}\b", text), name


def test_effect_emitter_and_collider_classes_are_exported():
    from warp_mpm_bubbles.scene import effects

    for name in ("Foam", "SubgridBubbles", "Entrainment", "LiquidInflow", "GasInjector", "Collider"):
        assert getattr(warp_mpm_bubbles, name) is getattr(effects, name)
    with pytest.raises(AttributeError, match="no attribute 'Nope'"):
        warp_mpm_bubbles.Nope  # noqa: B018


@pytest.mark.parametrize("cls", [Domain, Material, Box, Sphere, Cylinder, SolverSettings, Output, Scene])
def test_every_scene_field_is_documented(cls):
    doc = cls.__doc__ or ""
    missing = [f.name for f in dataclasses.fields(cls) if not re.search(rf"\b{f.name}\b", doc)]
    assert not missing, f"{cls.__name__} docstring lacks {missing}"


def test_units_are_stated_where_a_field_has_one():
    for cls, units in ((Domain, ["metres", "m/s^2", "Pa"]), (Material, ["kg/m^3", "N/m", "Pa s"]),
                       (Box, ["m/s", "Pa"]), (Output, ["frames per second", " m,"]), (SolverSettings, [", s "])):
        for unit in units:
            assert unit in cls.__doc__, (cls.__name__, unit)


def test_the_api_pages_scene_example_validates(tmp_path, monkeypatch):
    text = (ROOT / "docs" / "api.md").read_text()
    block = text.split("## Build a scene")[1].split("```python")[1].split("```")[0]
    monkeypatch.chdir(tmp_path)
    namespace = {}
    exec(block, namespace)  # noqa: S102 (our own documentation)
    scene = namespace["scene"].validate()
    assert scene.dim == 2 and scene.effect_names == ["gas", "surface_tension"]
