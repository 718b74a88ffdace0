"""Rigs of a garment on a body: virtual bones (skeleton -> bones -> garment) and the garment's
skinning to the body's own joints (the LBS method)."""
