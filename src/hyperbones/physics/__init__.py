"""Physics: cloth materials, energies (HOOD's), proximity to the body, metrics."""
