"""The MPM core every scene runs: the MAC grid, the particle <-> grid transfers, the one two-phase
pressure system and its multigrid-preconditioned CG, the state and the step (see docs/design.md)."""
