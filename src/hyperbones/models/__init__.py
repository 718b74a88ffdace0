"""Neural modules: the shared MeshGraphNet trunk and the teacher (Module C) built on it."""
