"""The virtual-bone rig of a garment on a body (skeleton -> bones -> garment)."""
