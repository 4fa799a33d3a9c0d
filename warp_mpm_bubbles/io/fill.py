"""A domain that fills up: the run stops, by name, when the liquid no longer fits.

The liquid is incompressible and an emitter adds liquid at its rate whatever is already there, so
liquid that finds no room (a closed domain poured full, or a stream an open wall cannot drain fast
enough) is packed tighter and tighter: its particles pile up several to a place, with nothing to
show for it but a wrong animation. `check_pour` (scene/capacity.py) refuses what the scene makes
predictable; this guard catches the rest after each frame:

    check_domain_fill(sim)   # after sim.advance_frame(): raises DomainFullError

The fill is the liquid's rest volume (the vol0 of its particles in the domain and of those flying
above an open top, which fall back in) over the room: the interior cells that are not solid
(colliders' cells, where the last step marked them). A box filled to the brim reads 1.00.
Where the liquid fits, the liquid and the resolved gas together (the volume its law gives it,
V0 J) must too, within the same MAX_FILL: gas crowded into less room than that is squeezed
without its J knowing (bubbles injected into a full tank faster than its open walls let the
water out), and the run stops naming the gas injectors.
"""
from __future__ import annotations

import numpy as np

from ..core.grid import ACTIVE, AIRBORNE, PHASE_GAS, PHASE_LIQUID, SOLID_FREE_SLIP, SOLID_NO_SLIP
from ..scene.effects import GasInjector
from ..core.simulation import SimulationError
from ..scene.capacity import draining_walls

# The liquid's rest volume may exceed the room by 5% before the run stops. Measured on a closed 16 x 16
# cell box (0.2 m, 1.25 cm cells) with a one-cell layer of water and a 4 cm nozzle pouring 2 m/s
# (tests/test_scene_refusals.py's POUR, stepped past the frames check allows): the fill reads 0.0625
# at the start and grows by the pour, 1/15 a frame: 0.994 at frame 14 (the box full), 1.056 at 15,
# 1.125 at 16, 1.66 at 24; a box seeded full reads 1.000 and stays there (the rest volume changes
# only by emitters and outflow). So 1.05 passes a box filled exactly to the top, overshoot by the
# last stream layers included, and stops water packed more than 5% over its density, within a frame
# of the pour at which it happens.
MAX_FILL = 1.05


class DomainFullError(SimulationError):
    """The liquid's rest volume exceeds the room the domain has for it; the message names the
    frame, the fill and the fixes."""

    def __init__(self, message: str, fill: float):
        super().__init__(message)
        self.fill = fill


def liquid_rest_volume(sim) -> float:
    """m^3: the volume the liquid particles would fill uncompressed (their vol0), those flying above
    an open top included."""
    p = sim.particles
    if p.count == 0:
        return 0.0
    # Liquid flying above an open top (AIRBORNE) falls back in: the domain must hold it too.
    held = np.isin(p.numpy("active"), (ACTIVE, AIRBORNE))
    liquid = held & (p.numpy("phase") == PHASE_LIQUID)
    return float(p.numpy("vol0")[liquid].astype(np.float64).sum())


def gas_volume(sim) -> float:
    """m^3: the volume the resolved gas claims, V0 J of its active particles (its law's volume)."""
    p = sim.particles
    if p.count == 0 or not sim.has_gas:
        return 0.0
    gas = (p.numpy("active") == ACTIVE) & (p.numpy("phase") == PHASE_GAS)
    return float((p.numpy("vol0")[gas].astype(np.float64) * p.numpy("J")[gas]).sum())


def domain_room(sim) -> float:
    """m^3: the interior cells the liquid can hold, those the last step did not mark solid."""
    g = sim.grid
    types = sim.fields.types.numpy()[g.interior_slice()]
    solid = np.count_nonzero((types == SOLID_FREE_SLIP) | (types == SOLID_NO_SLIP))
    return float((types.size - solid) * g.dx**3)


def domain_fill(sim) -> float:
    """The liquid's rest volume over the room (1.0: full to the brim at the liquid's density)."""
    room = domain_room(sim)
    return liquid_rest_volume(sim) / room if room > 0.0 else float("inf")


def check_domain_fill(sim, max_fill: float = MAX_FILL) -> float:
    """Raise DomainFullError when the liquid's rest volume exceeds `max_fill` times the room; return
    the fill. Call it after each frame (the runner's frame loop)."""
    fill = domain_fill(sim)
    if fill <= max_fill:
        both = fill + gas_volume(sim) / domain_room(sim) if sim.has_gas else fill
        if both > max_fill:
            raise _squeezed_gas(sim, fill, both, max_fill)
        return fill
    scene = sim.scene
    closed = not draining_walls(scene.domain)
    emitters = [f"[emitters.{i}]" for i, e in enumerate(scene.emitters) if hasattr(e, "volume_rate")]
    source = " and ".join(emitters) if emitters else "the liquid"
    raise DomainFullError(
        f"frame {sim.frame} (t = {sim.time:.6g} s): the domain is overfull: the liquid's rest volume is "
        f"{fill:.3g} times the room the domain has for it (the interior cells not solid), so it is packed "
        f"{fill:.3g} times over its density, more than the {max_fill:g} allowed. {source} brought more liquid "
        f"than {'the closed domain holds' if closed else 'the open walls let leave'}: enlarge [domain].size, "
        + ("open a wall it can leave through ([domain].walls; not the top, above which it falls back in), "
           if closed else "open more walls, ")
        + "give the emitters an earlier stop, a lower speed or radius, or use fewer [output].frames", fill)


def _squeezed_gas(sim, fill: float, both: float, max_fill: float) -> DomainFullError:
    """The liquid fits, but not with the gas: the volume the gas's law gives it (V0 J) is not there,
    and its J does not know. Seen where gas injectors release bubbles into a tank the water fills
    faster than the push that makes their room (effects/room.py, first images only) carries the
    water out through its open walls: the rest is crowded against the closed ones (the run fuzz's
    air stone in a full tank open at the side: 1.07 of the box by frame 1)."""
    scene = sim.scene
    injectors = [f"[emitters.{i}]" for i, e in enumerate(scene.emitters) if isinstance(e, GasInjector)]
    source = " and ".join(injectors) if injectors else "the gas"
    fixes = (f"release less gas ({injectors[0]}.rate, radius or stop), leave open air above the water (less "
             f"liquid), open a wall near the injector ([domain].walls), or enlarge [domain].size"
             if injectors else "leave open air above the water (less liquid or gas in [[shapes]]), or enlarge "
             "[domain].size")
    return DomainFullError(
        f"frame {sim.frame} (t = {sim.time:.6g} s): the domain is overfull: the liquid ({fill:.3g} of the room "
        f"the domain has: the interior cells not solid) and the gas ({both - fill:.3g}, the volume its law "
        f"gives it) fill {both:.3g} of it, more than the {max_fill:g} allowed: the fluid is squeezed into "
        f"less room than its volume. {source} brought more gas than the domain could make room for: {fixes}",
        both)
