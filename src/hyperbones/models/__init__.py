"""Neural modules: the MeshGraphNet trunk and body–garment graph, the teacher (Module C), Modules
A and B, and loading them from checkpoints (``models.loading``)."""
