"""Small host values kept from one step to the next (a stage's progress, the core's ledger), typed.

Each is a dataclass deriving from `HostState`, owned by whoever writes it (a stage's `state`, the
simulation's `ledger`). A checkpoint (io/checkpoint.py) saves `arrays()`, each field as a numpy
array under its checkpoint name (`saved(name, default)`), and a resumed run gives them back with
`load(arrays)`: a name an older checkpoint lacks keeps its fresh value.
"""

from __future__ import annotations

from dataclasses import dataclass, field, fields

import numpy as np


def saved(name: str, default=None, factory=None):
    """A field checkpointed under `name` (a scalar default, or a factory for an array)."""
    if factory is not None:
        return field(default_factory=factory, metadata={"name": name})
    return field(default=default, metadata={"name": name})


@dataclass
class HostState:
    def arrays(self) -> dict[str, np.ndarray]:
        """Every field by its checkpoint name: an int as int64, a float as float64, an array as is."""
        out = {}
        for f in fields(self):
            value = getattr(self, f.name)
            if isinstance(value, np.ndarray):
                out[f.metadata["name"]] = value
            else:
                out[f.metadata["name"]] = np.array([value], np.int64 if isinstance(value, int) else np.float64)
        return out

    def load(self, arrays: dict) -> None:
        """Take back the fields `arrays` holds by name, each as its fresh value's type."""
        for f in fields(self):
            if f.metadata["name"] not in arrays:
                continue
            stored, value = arrays[f.metadata["name"]], getattr(self, f.name)
            if isinstance(value, np.ndarray):
                setattr(self, f.name, np.array(stored, copy=True))
            else:
                setattr(self, f.name, int(stored[0]) if isinstance(value, int) else float(stored[0]))


@dataclass
class Ledger(HostState):
    """The core's: the next particle's id, and the kg of liquid and of gas ever added (seeded,
    emitted; conversions re-append the gas they retire, so that one is an upper bound of what is
    held). `Simulation.add_particles` books them; mass_budget and the emitters' room bound read them."""

    next_id: int = saved("next_id", 0)
    liquid_added: float = saved("liquid_added", 0.0)
    gas_added: float = saved("gas_added", 0.0)
