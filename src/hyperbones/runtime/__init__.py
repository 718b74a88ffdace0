"""Runtime tools: benchmarks (and, later, the per-frame simulator)."""
