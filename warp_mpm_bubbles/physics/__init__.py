"""Physics stages a scene turns on through its materials: gas, surface tension, viscosity.
Each module owns all of its physics: its keys, its time-step limit, its kernels and its hooks."""
