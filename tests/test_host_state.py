"""Typed host state (core/host_state.py): each stage's small host values are a dataclass it owns,
checkpointed under the names checkpoints have always used, so an older checkpoint resumes."""

import math

import numpy as np
import warp as wp

from scenes import tank_2d
from warp_mpm_bubbles import Material, Sphere
from warp_mpm_bubbles.core.simulation import Simulation
from warp_mpm_bubbles.scene.effects import Entrainment, SubgridBubbles

wp.config.quiet = True


def test_the_checkpoint_names_and_types_are_those_of_older_checkpoints(tmp_path):
    scene = tank_2d(cells=16, depth=0.6, out=tmp_path / "h.usdc")
    scene.materials["water"] = Material("water", viscosity=0.5)
    scene.materials["air"] = Material("air", kind="gas")
    scene.shapes.append(Sphere("air", center=(0.5, 0.3), radius=0.12))
    scene.effects = {"subgrid_bubbles": SubgridBubbles(), "entrainment": Entrainment()}
    sim = Simulation(scene.validate(), "cpu")
    arrays = sim.state_arrays()
    assert set(arrays) == {"next_id", "liquid_added", "gas_added", "gas_mass_trapped", "gas_gauge",
                           "gas_expansion_rate", "gas_cavity", "viscous_rate", "entrainment_capacity",
                           "gas_mass_entrained", "gas_mass_rounding"}
    assert arrays["next_id"].dtype == np.int64 and arrays["next_id"][0] == sim.num_particles
    assert arrays["entrainment_capacity"].dtype == np.int64 and arrays["gas_gauge"].dtype == np.float64
    assert math.isnan(arrays["gas_gauge"][0])  # not measured yet

    # A resumed run takes back what it finds; a name an older checkpoint lacks keeps its fresh value.
    other = Simulation(scene.validate(), "cpu")
    other.load_state({"gas_gauge": np.array([123.0]), "next_id": np.array([7], np.int64)})
    assert other.stage("gas").state.gauge == 123.0 and other.ledger.next_id == 7
    assert isinstance(other.ledger.next_id, int) and other.stage("entrainment").state.capacity == 256
