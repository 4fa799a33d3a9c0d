"""What a step costs: throughput, the solvers, transfers, start-up, scaling, and next to a peer."""
