"""What an emitter may pour into a closed domain, checked before any work starts.

An emitter adds liquid at a fixed rate whatever is already there; the liquid is incompressible,
so a closed domain (no `open` wall but the top, above which liquid falls back in) that receives
more liquid than it has room for ends with the water packed several times over its density (a
2 m/s stream for 45 frames into a 16 x 16 cell box: 3,130 particles where 1,024 fill it).
`check_pour` refuses such a scene by the emitter's key.

What is counted, all per metre of slab in 2D (m^2) and in m^3 in 3D:
- the room: the domain minus the colliders where they stand at t = 0 (a moving collider keeps its
  volume while it stays in the domain; the inside of a glass counts as room);
- the liquid the shapes seed (later shapes overwriting earlier ones, none inside a collider);
- what each liquid_inflow pours: its volume rate (nozzle area x speed) over its active time, from
  `start` to `stop` or to the end of the last frame.
Gas is not counted there: above the liquid it vents to the open air. `check_injection` refuses gas
injected into a closed domain the shapes fill (no open air to vent to) beyond what compressing the
gas there can take in (Boyle's law, up to MAX_INJECTED_GAUGE).

The volumes are measured on a lattice of at most LATTICE_POINTS points (the cell centres when the
grid is no bigger), the same lattice for the shapes and the room, so a box filled to the brim by
shapes and emitters together compares equal, and passes.
"""
from __future__ import annotations

import math

import numpy as np

from .checks import SceneError, _g
from .effects import GasInjector
from .limits import inside_collider, max_gauge_pressure

# The most a closed domain's gas may be compressed to take injected gas in, as a gauge pressure over the
# ambient one. Measured in a closed 2D box (water below 7 cm, an air layer above, bubbles injected at
# the bottom): the gas keeps its room and Boyle's pressure at 1.15 times ambient (0.3% drift in
# 0.1 s) and 1.6 times (2.4%), but at 2.5 times it went on collapsing after the injection stopped
# (21% of its volume in 0.1 s), its particles' pressures 7 times apart.
MAX_INJECTED_GAUGE = 1.0
LATTICE_POINTS = 2**20  # 25 MB of float64 points in 3D; a 1024 x 1024 grid of cells is measured exactly


def _lattice_counts(domain) -> np.ndarray:
    """The lattice's points along each axis: the scene's cells (refine aside), fewer past LATTICE_POINTS."""
    n = np.array([round(s / domain.cell_size) for s in domain.size])
    if n.prod() > LATTICE_POINTS:
        n = np.maximum(1, np.floor(n * (LATTICE_POINTS / n.prod()) ** (1.0 / len(n)))).astype(int)
    return n


def _lattice(domain):
    """Points at the centres of a regular lattice over the domain, and the volume each stands for."""
    size, n = np.asarray(domain.size, float), _lattice_counts(domain)
    axes = [(np.arange(k) + 0.5) * s / k for k, s in zip(n, size)]
    points = np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, len(n))
    return points, float(np.prod(size / n))


def _lattice_owners(scene):
    """(points, cell, solid, owner): the domain's lattice (_lattice), which points the colliders cover
    at t = 0, and the index of the shape that seeds each point (later shapes win; -1: none)."""
    points, cell = _lattice(scene.domain)
    solid = np.zeros(len(points), bool)
    for col in scene.colliders:
        solid |= inside_collider(col, points, scene.dim)
    owner = np.full(len(points), -1)
    for i, shape in enumerate(scene.shapes):
        owner = np.where(shape.contains(points), i, owner)
    return points, cell, solid, owner


def room_and_seeded_liquid(scene) -> tuple[float, float, float]:
    """(room, solid, seeded liquid): the domain's volume minus the colliders', the colliders' share of
    the domain, and the liquid the shapes seed outside them (m^3 in 3D, m^2 per metre of slab in 2D)."""
    points, cell, solid, owner = _lattice_owners(scene)
    liquid_shape = np.array([scene.materials[s.material].kind == "liquid" for s in scene.shapes] + [False])
    liquid = liquid_shape[owner] & ~solid  # owner -1 (no shape) picks the trailing False
    total = len(points) * cell
    return total - solid.sum() * cell, solid.sum() * cell, liquid.sum() * cell


def poured_volume(emitter, t_end: float) -> float:
    """The liquid an emitter brings from its start to min(stop, t_end)."""
    stop = t_end if emitter.stop is None else min(emitter.stop, t_end)
    return emitter.volume_rate * max(0.0, stop - emitter.start)


def _pours(scene, frames: int) -> float:
    t_end = frames / scene.output.fps
    return sum(poured_volume(e, t_end) for e in scene.emitters if hasattr(e, "volume_rate"))


def _most_frames(scene, room: float, seeded: float) -> int:
    """The most frames (0 if none) whose pour still fits: the pour grows with the frames."""
    lo, hi = 0, scene.output.frames
    while lo < hi:
        mid = (lo + hi + 1) // 2
        if seeded + _pours(scene, mid) <= room:
            lo = mid
        else:
            hi = mid - 1
    return lo


def _example_wall(domain) -> str:
    """The floor (the wall opposite the top) or, without gravity, x_max."""
    top = top_wall(domain)
    return top[:2] + ("min" if top.endswith("max") else "max") if top else "x_max"


def _down(x: float) -> float:
    """x rounded down to 3 significant digits (a bound the user can type that still holds)."""
    if x <= 0.0:
        return x
    scale = 10.0 ** (math.floor(math.log10(x)) - 2)
    return math.floor(x / scale) * scale


def top_wall(domain) -> str | None:
    """The wall against gravity ("y_max" under the default gravity), None without gravity."""
    g = np.asarray(domain.gravity, float)
    if not g.any():
        return None
    a = int(np.argmax(np.abs(g)))
    return f"{'xyz'[a]}_{'max' if g[a] < 0.0 else 'min'}"


def draining_walls(domain) -> list[str]:
    """The open walls the liquid can leave through: all but the top, above which liquid flies and
    falls back in (core/transfer_kernels.py, open_wall_exit)."""
    walls = domain.walls if isinstance(domain.walls, dict) else {}
    return [k for k, v in walls.items() if v == "open" and k != top_wall(domain)]


def _lidded(scene, points, solid, owner) -> bool:
    """Whether the shapes and colliders cover the layer of lattice points under the top (without
    gravity: every layer along the walls) in a domain with no open wall: no open air where the gas
    could vent (core/voids.py: the open air starts in the top layer), so the gas stays."""
    walls = scene.domain.walls
    if any(w == "open" for w in (walls.values() if isinstance(walls, dict) else [walls])):
        return False
    size = np.asarray(scene.domain.size, float)
    step = size / _lattice_counts(scene.domain)
    top = top_wall(scene.domain)
    edges = [top] if top else [f"{a}_{side}" for a in "xyz"[: scene.dim] for side in ("min", "max")]
    covered = (owner >= 0) | solid
    for wall in edges:
        a = "xyz".index(wall[0])
        layer = points[:, a] < step[a] if wall.endswith("min") else points[:, a] > size[a] - step[a]
        if not covered[layer].all():
            return False
    return True


def _staying_gas(scene) -> tuple[float, float, str]:
    """(volume, least volume, why) of the gas the shapes seed in a closed domain they lid (_lidded):
    no open air to vent to, so as the liquid rises it takes the gas's room only by compressing it:
    not at all where a gas is incompressible, else by Boyle's law up to MAX_INJECTED_GAUGE (or the
    gas shapes' bound, where lower), as check_injection. (0, 0, "") where the gas may vent."""
    points, cell, solid, owner = _lattice_owners(scene)
    gas_volume, gas_rest = _seeded_gas(scene)
    if gas_volume <= 0.0 or not _lidded(scene, points, solid, owner):
        return 0.0, 0.0, ""
    mats = [m for m in scene.materials.values() if m.is_gas]
    if any(m.eos == "incompressible" for m in mats):
        return gas_volume, gas_volume, "incompressible (eos)"
    gamma = max(m.gamma if m.eos == "adiabatic" else 1.0 for m in mats)
    p_atm = scene.domain.ambient_pressure
    max_gauge = min(float(max_gauge_pressure(scene.materials)), MAX_INJECTED_GAUGE * p_atm)
    least = gas_rest * (p_atm / (p_atm + max_gauge)) ** (1.0 / gamma)
    return gas_volume, least, f"compressed at most to {_g(max_gauge)} Pa gauge (Boyle's law)"


def check_pour(scene):
    """Refuse a domain the liquid cannot leave (no open wall but the top) whose liquid emitters
    bring more liquid than it has room for: beside the liquid the shapes seed and, where the shapes
    lid a domain with no open wall (_lidded), beside the gas they seed, which has no open air to
    vent to and gives the liquid no more room than compressing it can (_staying_gas)."""
    pours = [(i, e) for i, e in enumerate(scene.emitters) if hasattr(e, "volume_rate")]
    if not pours or draining_walls(scene.domain):
        return  # the liquid leaves through an open wall: what stays is not predictable here
    room, solid, seeded = room_and_seeded_liquid(scene)
    t_end = scene.output.frames / scene.output.fps
    poured = {i: poured_volume(e, t_end) for i, e in pours}
    total = seeded + sum(poured.values())
    if total <= room * (1.0 + 1e-9):
        gas, least, how = _staying_gas(scene)
        if total + least > room * (1.0 + 1e-9):
            _refuse_pour_into_gas(scene, poured, room, seeded, gas, least, how)
        return
    key_i = max(poured, key=poured.get)  # the emitter that brings the most
    e = scene.emitters[key_i]
    unit = "m^2" if scene.dim == 2 else "m^3"  # 2D: per metre of slab, as the emitters' rates
    others = sum(poured.values()) - poured[key_i]
    spare = room - seeded - others  # what this emitter may still pour
    stop_fix = (f"stop <= {_down(e.start + spare / e.volume_rate)} s" if spare > 0.0
                else "remove it (the shapes and other emitters fill the room already)")
    frames = _most_frames(scene, room, seeded)
    key = f"[emitters.{key_i}]"
    msg = (f"{scene.source}: {key}: pours {poured[key_i]:.4g} {unit} of liquid over the run ({e.volume_rate:.4g} "
           f"{unit}/s from t = {_g(e.start)} s to {_g(t_end if e.stop is None else min(e.stop, t_end))} s)"
           + (f", other emitters {others:.4g} {unit}" if others else "")
           + f", on top of {seeded:.4g} {unit} that the shapes seed: {total:.4g} {unit} in all, but the domain, "
           f"which the liquid cannot leave, holds {room:.4g} {unit} ({room + solid:.4g} minus {solid:.4g} of colliders"
           + (", per metre of the 2D slab" if scene.dim == 2 else "") + "), so the liquid would be packed "
           f"{total / room:.3g} times over its density. Fixes: a bigger [domain].size, an open wall the "
           f"liquid can leave through (not the top, where it falls back in: [domain].walls = "
           f"{{ {_example_wall(scene.domain)} = \"open\" }}), {key}.{stop_fix}, "
           + (f"[output].frames <= {frames}, " if frames >= 1 else "")
           + f"or a lower {key}.speed or radius")
    raise SceneError(msg, key, poured[key_i], f"at most {max(spare, 0.0):.4g} {unit}")


def _refuse_pour_into_gas(scene, poured: dict, room: float, seeded: float, gas: float, least: float, how: str):
    """check_pour's refusal where the liquid fits the room but not beside the gas that stays."""
    key_i = max(poured, key=poured.get)
    e, unit = scene.emitters[key_i], "m^2" if scene.dim == 2 else "m^3"
    others = sum(poured.values()) - poured[key_i]
    spare = room - seeded - least - others
    key = f"[emitters.{key_i}]"
    stop_fix = (f"{key}.stop <= {_down(e.start + spare / e.volume_rate)} s" if spare > 0.0
                else f"remove {key}")
    msg = (f"{scene.source}: {key}: pours {poured[key_i]:.4g} {unit} of liquid over the run"
           + (f" (other emitters {others:.4g} {unit})" if others else "")
           + f" into a domain with no open wall whose shapes cover its top, so the {gas:.4g} {unit} of gas they "
           f"seed has no open air to vent to and stays; {how}, it still takes {least:.4g} {unit}. With the "
           f"{seeded:.4g} {unit} of liquid the shapes seed that is {seeded + sum(poured.values()) + least:.4g} "
           f"{unit}, but the domain holds {room:.4g} {unit}" + (" per metre of the 2D slab" if scene.dim == 2 else "")
           + f". Fixes: an open wall the liquid can leave through ([domain].walls = "
           f"{{ {_example_wall(scene.domain)} = \"open\" }}), less gas (leave open air under the top), "
           f"{stop_fix}, or a lower {key}.speed or radius")
    raise SceneError(msg, key, poured[key_i], f"at most {max(spare, 0.0):.4g} {unit}")


# ---------------------------------------------------------------------------- gas injected
def _seeded_gas(scene) -> tuple[float, float]:
    """(volume, rest volume at ambient pressure) of the gas the shapes seed outside the colliders
    (m^3; 2D: m^2 per metre of slab). A shape at gauge pressure p holds (1 + p / p_atm)^(1/gamma) times
    its volume at ambient pressure (its eos' law)."""
    points, cell, solid, owner = _lattice_owners(scene)
    volume = rest = 0.0
    p_atm = scene.domain.ambient_pressure
    for i, shape in enumerate(scene.shapes):
        m = scene.materials[shape.material]
        if not m.is_gas:
            continue
        v = np.count_nonzero((owner == i) & ~solid) * cell
        gamma = m.gamma if m.eos == "adiabatic" else 1.0
        volume += v
        rest += v * ((p_atm + (shape.pressure or 0.0)) / p_atm) ** (1.0 / gamma)
    return volume, rest


def injected_rest_volume(scene, emitter, t_end: float) -> float:
    """The gas an injector releases from its start to min(stop, t_end), at ambient pressure: its
    whole bubbles times their mean volume (log-normal radius: E[r^k] = r^k exp(k^2 s^2 / 2)); 2D: the
    disks' area, per metre of slab like the other volumes here."""
    stop = t_end if emitter.stop is None else min(emitter.stop, t_end)
    bubbles = math.floor(emitter.rate * max(0.0, stop - emitter.start) + 1e-9)
    k = len(emitter.center)  # 3: spheres, 2: disks
    size = (4.0 / 3.0 if k == 3 else 1.0) * math.pi * emitter.radius**k * math.exp(0.5 * (k * emitter.radius_spread) ** 2)
    return bubbles * size


def check_injection(scene):
    """Refuse gas injected into a domain the liquid cannot leave whose shapes leave no open air (the
    liquid and gas shapes fill the room, so nothing vents), when the gas cannot take it in: the
    liquid fills the room, the gas is incompressible, or, all of it compressed to fit the room the
    liquid leaves (Boyle: J = room / rest volume), it would be above MAX_INJECTED_GAUGE (or the gas
    shapes' bound where lower). The run stops alike where the open air fills up later
    (effects/emitters.py, GasRoomError)."""
    injectors = [(i, e) for i, e in enumerate(scene.emitters) if isinstance(e, GasInjector)]
    if not injectors or draining_walls(scene.domain):
        return
    room, solid, liquid = room_and_seeded_liquid(scene)
    gas_volume, gas_rest = _seeded_gas(scene)
    if liquid + gas_volume < room * (1.0 - 1e-9):
        return  # open air in the box: bubbles reaching it vent, what stays is not predictable here
    t_end = scene.output.frames / scene.output.fps
    released = {i: injected_rest_volume(scene, e, t_end) for i, e in injectors}
    i = max(released, key=released.get)  # the injector that brings the most
    if released[i] <= 0.0:
        return
    key, space, unit = f"[emitters.{i}]", room - liquid, "m^2" if scene.dim == 2 else "m^3"
    mats = [m for m in scene.materials.values() if m.is_gas]
    gamma = max(m.gamma if m.eos == "adiabatic" else 1.0 for m in mats)
    p_atm = scene.domain.ambient_pressure
    max_gauge = min(float(max_gauge_pressure(scene.materials)), MAX_INJECTED_GAUGE * p_atm)
    rest = gas_rest + sum(released.values())
    if space <= 0.0:
        why = "the liquid the shapes seed fills all of it"
    elif any(m.eos == "incompressible" for m in mats):
        why = "the gas is incompressible (eos), so none of it can make room"
    else:
        gauge = p_atm * (rest / space) ** gamma - p_atm
        if gauge <= max_gauge:
            return
        why = (f"the gas ({gas_rest:.4g} {unit} seeded and {sum(released.values()):.4g} {unit} injected, at "
               f"ambient pressure) squeezed into the {space:.4g} {unit} the liquid leaves would be at "
               f"{gauge:.4g} Pa gauge, above the {max_gauge:.4g} Pa that compressed gas is held to")
    e = scene.emitters[i]
    raise SceneError(
        f"{scene.source}: {key}: releases {released[i]:.4g} {unit} of gas over the run into a domain the liquid "
        f"cannot leave, which the shapes fill (no open air for it to vent to), and has no room for it: {why}. "
        f"Fixes: an open wall the liquid can leave through (not the top: [domain].walls = "
        f"{{ {_example_wall(scene.domain)} = \"open\" }}), less liquid (leave open air above it), or a lower "
        f"{key}.rate or radius", key, e.rate, "a rate the room holds")
