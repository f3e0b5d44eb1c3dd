"""The 2010 report's sparse cylinder-constrained VO (section 5), one step a module: features (region Harris,
SIFT, matching), keyframes, the pipe-frame geometry and the wall sums S(g), the 1-DOF and 6-DOF keyframe
motion, the initial offset batch (eqs. 45-49) and its bundle form, the odometry that schedules them, and
run.py, which maps a dataset (`pipemap run --method sparse-cylinder`)."""
