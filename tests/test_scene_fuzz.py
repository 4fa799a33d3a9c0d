"""Generated malformed scenes (issue #5): whatever is wrong, the answer is a SceneError naming a key,
never a traceback from deeper in the code."""

import copy

from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st

from test_scene import good_dict
from warp_mpm_bubbles.scene.model import Scene, SceneError

# Values of every kind a TOML file (or a careless Python caller) can produce.
JUNK = st.one_of(
    st.none(), st.booleans(), st.integers(-10**6, 10**6),
    st.floats(allow_nan=True, allow_infinity=True), st.text(max_size=12),
    st.lists(st.one_of(st.floats(allow_nan=True, allow_infinity=True), st.integers(), st.text(max_size=4)),
             max_size=5),
    st.dictionaries(st.text(max_size=8), st.integers(), max_size=3),
)


def paths(d, prefix=()):
    """Every key path in a nested dict/list scene."""
    items = d.items() if isinstance(d, dict) else enumerate(d) if isinstance(d, list) else ()
    for k, v in items:
        yield prefix + (k,)
        yield from paths(v, prefix + (k,))


ALL_PATHS = sorted(paths(good_dict()), key=str)


def mutate(d, path, action, value):
    parent = d
    for k in path[:-1]:
        parent = parent[k]
    key = path[-1]
    if action == "delete" and isinstance(parent, dict):
        del parent[key]
    elif action == "rename" and isinstance(parent, dict):
        parent[str(value)[:8] + "_x"] = parent.pop(key)
    else:
        parent[key] = value


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.lists(st.tuples(st.sampled_from(ALL_PATHS), st.sampled_from(["set", "delete", "rename"]), JUNK),
                min_size=1, max_size=3))
# found by this test (2026-12-05): a domain so large that its cell count overflowed (an infinite one
# raised OverflowError in the whole-number check, a finite one in the total's message)
@example(mutations=[(("domain", "size", 0), "set", 3.595386269724632e+306)])
@example(mutations=[(("domain", "size", 0), "set", 3.595386269724632e+305)])
def test_malformed_scenes_get_a_named_error(tmp_path_factory, mutations):
    d = copy.deepcopy(good_dict())
    d["output"]["path"] = str(tmp_path_factory.getbasetemp() / "fuzz.usdc")
    for path, action, value in mutations:
        try:
            mutate(d, path, action, value)
        except (KeyError, IndexError, TypeError):
            pass  # an earlier mutation removed or retyped this path's parent
    try:
        Scene.from_dict(d, source="fuzz.toml")
    except SceneError as err:
        assert str(err).startswith("fuzz.toml: ")


@settings(max_examples=200, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.lists(st.tuples(st.integers(0, 10**4), st.sampled_from(["drop", "insert"]), st.text(max_size=10)),
                min_size=1, max_size=4))
def test_edited_scene_files_get_a_named_error(tmp_path_factory, edits):
    from test_scene import GOOD_TOML

    from warp_mpm_bubbles.scene.model import load_scene

    lines = GOOD_TOML.replace('"out/tank.usdc"', '"fuzz_out/tank.usdc"').splitlines()
    for position, action, text in edits:
        i = position % len(lines)
        if action == "drop":
            del lines[i]
        else:
            lines.insert(i, text)
    path = tmp_path_factory.getbasetemp() / "edited.toml"
    path.write_text("\n".join(lines))
    try:
        load_scene(path)
    except SceneError as err:
        assert str(err).startswith(str(path))
