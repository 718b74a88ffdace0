"""Physics: cloth materials and rest state, HOOD's energies, metrics of a simulated sequence, contact
planes, the teacher's hard contact and strain limiting."""
