"""sim2d: the pymunk floor-plan simulator, stereo/depth renderer and ground truth (docs/sim2d.md)."""
