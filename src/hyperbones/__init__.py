"""HyperBones: real-time bone-driven garment simulation on the Anny body.

Conventions (see the project README): metres and seconds, Z up, the body faces -Y,
30 frames per second unless a motion says otherwise.
"""

__version__ = "0.1.0"
