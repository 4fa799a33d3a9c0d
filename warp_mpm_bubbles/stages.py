"""The built-in stages, by the effect name a scene asks for, and their order in the step.

The package registers them with the core's stage registry (core/stage.py) when it loads, so the
core names no effect: a stage's module ("module:Class") is imported only when a scene asks for it,
and its kernels compile only then.

Stages run in STEP_ORDER at every hook point (stages registered from outside come after). The
order matters only where two stages share a hook: colliders mark solid cells before the gas labels
phases (the phases read the cell types); forces add viscosity then tension; after g2p, films
retract before anything else reads the gas, entrained bubbles are seeded before the sub-grid stage
moves them, and foam takes surfacing gas before venting would remove it.
"""

# The built-in stages, by the effect name a scene asks for: "module:Class", imported on first use.
BUILTIN_STAGES = {
    "gas": "warp_mpm_bubbles.physics.gas:GasStage",
    "colliders": "warp_mpm_bubbles.effects.colliders:ColliderStage",
    "viscosity": "warp_mpm_bubbles.physics.viscosity:ViscosityStage",
    "surface_tension": "warp_mpm_bubbles.physics.tension:TensionStage",
    "emitters": "warp_mpm_bubbles.effects.emitters:EmitterStage",
    "foam": "warp_mpm_bubbles.effects.foam:FoamStage",
    "subgrid_bubbles": "warp_mpm_bubbles.effects.subgrid:SubgridBubbleStage",
    "entrainment": "warp_mpm_bubbles.effects.entrainment:EntrainmentStage",
}
# Order at every hook point (see the module docstring).
STEP_ORDER = ("emitters", "colliders", "viscosity", "surface_tension", "entrainment", "subgrid_bubbles", "foam",
              "gas")

