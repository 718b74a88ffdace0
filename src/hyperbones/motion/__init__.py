"""Motion: the Motion type, BVH import and retargeting, built-in clips."""
