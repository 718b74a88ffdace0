"""Physics: cloth materials and rest state, HOOD's energies, metrics, the teacher's strain limiting and contact."""
