"""The per-frame runtime: the Simulator, identity caches, contact push-out, edge projection, benchmarks."""
