"""Pure geometry: rotations, poses, cylinders."""
