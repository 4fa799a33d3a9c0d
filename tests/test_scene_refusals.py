"""Every scene a user writes runs right or is refused by name: a closed domain poured over full
(refused by check, and stopped by the fill guard where check cannot predict it), a fast emitter's
time step, gas-only scenes, and the input refusals (a byte-order mark, material names differing
by case, an absurd particle_radius, a collider outside the domain, a gauge pressure the run
cannot take)."""

import math

import numpy as np
import pytest
import warp as wp

from warp_mpm_bubbles.cli import main
from warp_mpm_bubbles.core.simulation import Simulation
from warp_mpm_bubbles.effects import emitters
from warp_mpm_bubbles.io.fill import MAX_FILL, DomainFullError, check_domain_fill, domain_fill
from warp_mpm_bubbles.scene.model import SceneError, load_scene

wp.config.quiet = True

# A closed 16 x 16 cell box with a one-cell layer of water and a 4 cm nozzle pouring at 2 m/s:
# 0.08 m^2/s into 0.04 m^2, full after 14 frames at 30 fps (the user's 45 frames: 3x over).
POUR = """
[domain]
size = [0.2, 0.2]
cell_size = 0.0125
walls = {walls}
[materials.water]
[[shapes]]
type = "box"
material = "water"
min = [0.0, 0.0]
max = [0.2, 0.0125]
[[emitters]]
type = "liquid_inflow"
material = "water"
center = [0.1, 0.18]
direction = [0.0, -1.0]
radius = 0.02
speed = {speed}
{emitter}
[output]
path = "{out}"
fps = 30
frames = {frames}
{extra}
"""


def write(tmp_path, text, name="s.toml", **kw):
    path = tmp_path / name
    path.write_text(text.format(out=(tmp_path / "s.usdc").as_posix(), **kw))
    return path


def pour(tmp_path, frames=45, speed=2.0, walls='"free_slip"', emitter="", extra=""):
    return write(tmp_path, POUR, frames=frames, speed=speed, walls=walls, emitter=emitter, extra=extra)


def run_cli(capsys, *argv):
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    assert "Traceback" not in out + err
    return code, out + err


# ---------------------------------------------------------------------- a domain that fills up
def test_a_pour_over_a_closed_box_is_refused_by_the_emitter_with_the_volumes_and_fixes(tmp_path, capsys):
    code, text = run_cli(capsys, "check", pour(tmp_path))
    assert code == 2
    # 0.08 m^2/s for 1.5 s on top of 0.0025 m^2 seeded, into 0.04 m^2: 3.06 times over
    for words in ("[emitters.0]", "pours 0.12 m^2", "0.0025 m^2", "holds 0.04 m^2", "3.06 times",
                  "[domain].size", "open", "[emitters.0].stop <= 0.468 s", "[output].frames <= 14", "speed"):
        assert words in text, words
    assert not (tmp_path / "s.usdc").exists()


@pytest.mark.parametrize("change", [dict(frames=14), dict(emitter="stop = 0.468"),
                                   dict(walls='{ y_min = "open" }'), dict(walls='{ x_max = "open" }')])
def test_the_fixes_the_refusal_names_are_accepted(tmp_path, change):
    load_scene(pour(tmp_path, **change))  # 14 frames fill the box to 0.994 of its room: accepted


def test_an_open_top_does_not_drain_the_pour(tmp_path):
    # Liquid past an open top flies above the domain and falls back in: the box must hold it all.
    with pytest.raises(SceneError, match=r"not the top.*y_min = \"open\""):
        load_scene(pour(tmp_path, walls='{ y_max = "open" }'))


def test_a_collider_takes_room_from_the_pour(tmp_path):
    # 12 frames fit the empty box (0.0025 + 0.032 of 0.04 m^2) but not beside a 0.1 x 0.1 m block
    load_scene(pour(tmp_path, frames=12))
    block = '[[colliders]]\ntype = "box"\ncenter = [0.05, 0.1]\nsize = [0.1, 0.1]'
    with pytest.raises(SceneError, match=r"\[emitters.0\].*0.01 of colliders") as err:
        load_scene(pour(tmp_path, frames=12, extra=block))
    assert err.value.key == "[emitters.0]"


def gas_layer(eos: str, x_max: float = 0.2) -> str:
    """An air layer under the closed lid, 5 cm deep (0.01 m^2), across x_max of the box's 0.2 m."""
    return (f'[materials.air]\nkind = "gas"\neos = "{eos}"\n[[shapes]]\ntype = "box"\nmaterial = "air"\n'
            f"min = [0.0, 0.15]\nmax = [{x_max}, 0.2]\n")


@pytest.mark.parametrize("eos, frames, refused", [("incompressible", 12, True), ("isothermal", 12, False),
                                                  ("isothermal", 14, True), ("adiabatic", 14, True)])
def test_a_pour_under_a_gas_lid_counts_the_gas_that_stays(tmp_path, eos, frames, refused):
    # 12 frames pour 0.032 m^2 onto 0.0025 seeded: 0.0345 of 0.04 fits alone, not beside the lid's
    # 0.01 m^2 of incompressible gas (0.0445), but beside isothermal gas halved by Boyle's law at
    # 1 atmosphere gauge (0.005: 0.0395). 14 frames (0.0398) leave no room for either; adiabatic
    # air (gamma 1.4) compresses less. The run fuzz's scene 1412: liquid and gas 1.045 of the box.
    path = pour(tmp_path, frames=frames, extra=gas_layer(eos))
    if not refused:
        load_scene(path)
        return
    with pytest.raises(SceneError) as err:
        load_scene(path)
    assert err.value.key == "[emitters.0]"
    for words in ("no open wall", "cover its top", "no open air to vent to", "0.01 m^2 of gas", "holds 0.04 m^2",
                  "open", "[emitters.0].st", "speed"):
        assert words in str(err.value), words
    assert ("incompressible" if eos == "incompressible" else "Boyle") in str(err.value)


@pytest.mark.parametrize("extra", [gas_layer("incompressible", x_max=0.15),  # open air beside it: the gas vents
                                   gas_layer("incompressible") + '[domain.walls]\ny_min = "open"\n'])  # it drains
def test_gas_that_can_leave_does_not_hold_room_from_the_pour(tmp_path, extra):
    if "domain.walls" in extra:  # the domain's walls are a table of their own here
        text = POUR.replace("walls = {walls}\n", "")
        load_scene(write(tmp_path, text, frames=12, speed=2.0, emitter="", extra=extra))
    else:
        load_scene(pour(tmp_path, frames=12, extra=extra))


def test_the_999_m_per_s_emitter_is_refused_before_it_runs(tmp_path, capsys):
    code, text = run_cli(capsys, "check", pour(tmp_path, frames=2, speed=999.0))
    assert code == 2 and "[emitters.0]" in text and "66.7 times" in text


# ----------------------------------------------------------------------- the runtime fill guard
def test_the_fill_guard_passes_a_full_box_and_stops_an_overfull_one(tmp_path, monkeypatch):
    # Validated for the 14 frames that fit, then stepped past them as nothing predictable would allow
    # (the guard is what catches a pour check cannot foresee). The stream lays every layer whatever
    # its cells hold: a nozzle that skips crowded cells (effects/emitters.py) is held back by the
    # splashes reaching it here, and the guard is the backstop for what that does not stop.
    monkeypatch.setattr(emitters, "CROWDED_FILL", math.inf)
    sim = Simulation(load_scene(pour(tmp_path, frames=14)), "cpu")
    fills = [check_domain_fill(sim)]
    for _ in range(14):
        sim.advance_frame()
        fills.append(check_domain_fill(sim))
    # The fill grows by the pour per frame (0.08 m^2/s / 30 fps over 0.04 m^2 = 1/15), to the brim
    assert fills[0] == pytest.approx(0.0625)
    assert np.diff(fills) == pytest.approx(1 / 15, abs=0.01)
    assert 0.98 < fills[-1] <= 1.0
    with pytest.raises(DomainFullError) as err:
        for _ in range(2):  # 1.056, then 1.125
            sim.advance_frame()
            check_domain_fill(sim)
    msg = str(err.value)
    assert err.value.fill > MAX_FILL and f"frame {sim.frame}" in msg and "[emitters.0]" in msg
    assert "[domain].size" in msg and "open" in msg and "stop" in msg


def test_the_fill_guard_counts_the_liquid_flying_above_an_open_top(tmp_path):
    # The same pour under an open top: a third of the liquid is airborne at a time, all of it falls
    # back in, and the box overfills as before (1.056 at frame 15, 1.125 at 16)
    sim = Simulation(load_scene(pour(tmp_path, frames=14, walls='{ y_max = "open" }')), "cpu")
    for _ in range(14):
        sim.advance_frame()
    assert check_domain_fill(sim) > 0.98
    with pytest.raises(DomainFullError):
        for _ in range(2):
            sim.advance_frame()
            check_domain_fill(sim)


def test_a_box_seeded_full_reads_full_and_passes(tmp_path):
    shapes = '[[shapes]]\ntype = "box"\nmaterial = "water"\nmin = [0.0, 0.0]\nmax = [0.2, 0.2]'
    sim = Simulation(load_scene(write(tmp_path, FULL, shapes=shapes)), "cpu")
    for _ in range(2):
        sim.advance_frame()
        assert check_domain_fill(sim) == pytest.approx(1.0, abs=1e-6)


FULL = """
[domain]
size = [0.2, 0.2]
cell_size = 0.0125
[materials.water]
{shapes}
[output]
path = "{out}"
frames = 2
"""


def test_the_fill_counts_solid_cells_out_of_the_room(tmp_path):
    block = '[[colliders]]\ntype = "box"\ncenter = [0.05, 0.1]\nsize = [0.1, 0.1]'
    sim = Simulation(load_scene(pour(tmp_path, frames=2, extra=block)), "cpu")
    sim.advance_frame()
    # The block covers 8 x 8 of the 16 x 16 cells: 192 are room for the seeded layer and the pour
    water = sim.particles.numpy("vol0").astype(np.float64).sum()
    assert domain_fill(sim) == pytest.approx(water / (192 * 0.0125**3), rel=1e-6)


# ------------------------------------------------------------------------------ a fast emitter
def test_a_fast_emitter_takes_the_step_its_stream_needs(tmp_path):
    # An open floor lets the stream leave, so check accepts it: the step must carry 200 m/s, since
    # the emitter's speed enters the CFL limit before any particle has it.
    sim = Simulation(load_scene(pour(tmp_path, frames=1, speed=200.0, walls='{ y_min = "open" }')), "cpu")
    cfl = sim.scene.solver.cfl * sim.grid.dx
    n0, elapsed = sim.num_particles, 0.0
    for _ in range(4):
        limits = sim.dt_limits()
        assert min(limits, key=limits.get) == "cfl" and limits["cfl"] * 200.0 <= cfl
        sim.step(sim.stable_dt())
        elapsed += sim.stats.dt_history[-1]
    x = sim.particles_numpy()["positions"][n0:]
    assert len(x) >= 3 * 6  # a layer (6 particles across the nozzle) a step, about
    # No particle ahead of the stream's front: each moved at most cfl cells a step (the layers'
    # jitter, a quarter of the spacing, aside).
    assert (0.18 - x[:, 1]).max() <= 200.0 * elapsed + 0.25 * sim.grid.dx / 2


# ------------------------------------------------------------------------------- gas-only scenes
GAS = """
[domain]
size = [0.2, 0.2]
cell_size = 0.0125
[materials.air]
kind = "gas"
{shapes}
[output]
path = "{out}"
frames = 2
"""


def test_a_gas_alone_in_open_air_leaves(tmp_path):
    shapes = '[[shapes]]\ntype = "sphere"\nmaterial = "air"\ncenter = [0.1, 0.1]\nradius = 0.04'
    sim = Simulation(load_scene(write(tmp_path, GAS, shapes=shapes)), "cpu")
    mass = sim.gas_budget()["inside"]
    for _ in range(2):  # the steps after the last gas particle left run on nothing
        sim.advance_frame()
    budget = sim.gas_budget()
    assert sim.particles_numpy()["positions"].shape[0] == 0
    assert budget["vented"] == pytest.approx(mass, rel=1e-6)


def test_a_gas_filling_a_closed_box_breathes_to_one_pressure(tmp_path):
    # Air at rest fills the box; a 0.1 m square inside starts 20 kPa above it. Isothermal: the two
    # share the box at one pressure, p = p_atm * (rest volume) / (box volume).
    shapes = ('[[shapes]]\ntype = "box"\nmaterial = "air"\nmin = [0.0, 0.0]\nmax = [0.2, 0.2]\n'
              '[[shapes]]\ntype = "box"\nmaterial = "air"\nmin = [0.05, 0.05]\nmax = [0.15, 0.15]\npressure = 20000.0')
    sim = Simulation(load_scene(write(tmp_path, GAS, shapes=shapes)), "cpu")
    p_atm, slab = 101325.0, 0.0125
    rest = sim.particles.numpy("vol0").astype(np.float64).sum()  # the inner square's 1.2 times its volume
    expected = p_atm * rest / (0.04 * slab) - p_atm  # 5,000 Pa for the shapes' exact volumes
    sim.advance_frame()
    p = sim.pressure_numpy()
    # one pressure within 1% across the box; its level within 5% (0.25% of the gas's volume: the
    # particles' volumes sum to the box's within that)
    assert p.max() - p.min() < 0.01 * expected
    assert p.mean() == pytest.approx(expected, rel=0.05)
    assert sim.gas_budget()["vented"] == 0.0


# ---------------------------------------------------------------------------------- input
def test_a_byte_order_mark_is_read(tmp_path):
    plain = pour(tmp_path, frames=2)
    marked = tmp_path / "bom.toml"
    marked.write_bytes(b"\xef\xbb\xbf" + plain.read_bytes())
    a, b = load_scene(plain), load_scene(marked)
    b.name = a.name
    assert a.to_dict() == b.to_dict()


def test_material_names_differing_by_case_are_refused(tmp_path):
    with pytest.raises(SceneError) as err:
        load_scene(pour(tmp_path, frames=2, extra='[materials.Water]'))
    assert "[materials.Water]" in str(err.value) and "[materials.water]" in str(err.value)
    assert "case" in str(err.value) and "rename" in str(err.value)


@pytest.mark.parametrize("radius, words", [(1e9, ["<= 0.1", "wider than the domain"]),
                                           (1e-9, [">= 3.125e-06", "unit mistake"])])
def test_an_absurd_particle_radius_is_refused(tmp_path, radius, words):
    with pytest.raises(SceneError) as err:
        load_scene(pour(tmp_path, frames=2, extra=f"particle_radius = {radius}"))
    assert err.value.key == "[output].particle_radius"
    for w in words:
        assert w in str(err.value)
    load_scene(pour(tmp_path, frames=2, extra="particle_radius = 0.05"))  # big spheres: the user's choice


COLLIDER = '[[colliders]]\ntype = "{type}"\ncenter = {center}\n{more}'


@pytest.mark.parametrize("type, center, more, outside", [
    ("sphere", "[1.0, 0.1]", "radius = 0.05", True),
    ("box", "[0.1, -0.3]", "size = [0.1, 0.5]", True),  # its top edge at -0.05
    ("glass", "[0.1, -0.1]", "radius = 0.05\nheight = 0.099\nwall_thickness = 0.0125", True),
    ("glass", "[0.1, -0.1]", "radius = 0.05\nheight = 0.11\nwall_thickness = 0.0125", False),  # its rim inside
    ("sphere", "[-0.5, 0.1]", "radius = 0.05\nvelocity = [1.0, 0.0]", False),  # rolls in at 0.45 s
    ("sphere", "[-0.5, 0.1]", "radius = 0.05\nvelocity = [1.0, 0.0]\nstop = 0.3", True),  # stops short
])
def test_a_collider_wholly_outside_the_domain_is_refused(tmp_path, type, center, more, outside):
    text = pour(tmp_path, frames=30, speed=0.2, extra=COLLIDER.format(type=type, center=center, more=more))
    if not outside:
        load_scene(text)
        return
    with pytest.raises(SceneError) as err:
        load_scene(text)
    assert err.value.key == "[colliders.0].center" and "wholly outside the domain" in str(err.value)


BUBBLE = """
[domain]
size = [0.2, 0.2]
cell_size = 0.0125
[materials.water]
{water}
[materials.air]
kind = "gas"
[[shapes]]
type = "box"
material = "water"
min = [0.0, 0.0]
max = [0.2, 0.15]
[[shapes]]
type = "sphere"
material = "air"
center = [0.1, 0.07]
radius = 0.03
pressure = {pressure}
[output]
path = "{out}"
frames = 2
"""


@pytest.mark.parametrize("pressure, water, refused", [
    (1e9, "", True), (5e8, "", True), (1.9e8, "", False),
    (1.9e8, "density = 500.0", True),  # a lighter liquid moves faster: 9.9e7 Pa at most
    (1e9, "density = 13500.0", False),  # mercury: the 1e9 Pa bound of every pressure applies
])
def test_a_gauge_pressure_that_drives_the_liquid_past_mach_0_3_is_refused(tmp_path, pressure, water, refused):
    path = write(tmp_path, BUBBLE, pressure=pressure, water=water)
    if not refused:
        load_scene(path)
        return
    with pytest.raises(SceneError) as err:
        load_scene(path)
    assert err.value.key == "[shapes.1].pressure" and "Mach 0.3" in str(err.value)


@pytest.mark.parametrize("center, direction, refused", [
    ("[0.01, 0.18]", "[0.0, -1.0]", True),  # a 4 cm nozzle 1 cm from the left wall, across x: past it
    ("[0.02, 0.18]", "[0.0, -1.0]", False),  # its edge on the wall
    ("[0.01, 0.18]", "[-1.0, 0.0]", False),  # pointing at the wall, the nozzle runs along y: inside
    ("[0.1, 0.19]", "[1.0, 0.0]", True),  # across y, 1 cm under the top: past it
])
def test_a_nozzle_reaching_past_a_wall_is_refused(tmp_path, capsys, center, direction, refused):
    # Liquid laid past a wall was clamped onto it: the wall's cells crowded (the fuzz found water
    # squeezed to 0.83 of its volume in a 3D box) and the stream brought less than speed x area.
    text = POUR.replace("center = [0.1, 0.18]", f"center = {center}").replace("direction = [0.0, -1.0]",
                                                                             f"direction = {direction}")
    path = write(tmp_path, text, frames=2, speed=1.0, walls='"open"', emitter="", extra="")
    code, out = run_cli(capsys, "check", path)
    assert code == (2 if refused else 0), out
    if refused:
        assert "[emitters.0].radius" in out and "past the domain" in out
