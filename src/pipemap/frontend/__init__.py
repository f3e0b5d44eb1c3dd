"""Fisheye feature tracking (fisheye paper III-A): frames -> keyframes with tracks and relative poses.

    harris       region Harris corners inside the fisheye circle
    descriptors  11 x 11 grey templates, cosine matching
    relpose      five-point RANSAC and refinement on bearing vectors
    guided       epipolar-guided ZNCC on the raw fisheye image
    keyframes    keyframe rule, keyframe trajectory
    tracks       Keyframe, track ids
    tracker      the streaming FeatureTracker (descriptors in every frame), make_tracker and run_tracking
    flow_tracker the FlowTracker: Lucas-Kanade between keyframes
    tracks_io    frames.csv and tracks.csv
"""

from pipemap.frontend.keyframes import chain_poses, needs_keyframe
from pipemap.frontend.relpose import RelativePose, estimate_relative_pose, five_point, sampson_angle
from pipemap.frontend.tracker import FeatureTracker, TrackingResult, make_tracker, run_tracking, track_frames
from pipemap.frontend.tracks import Keyframe, track_lengths
from pipemap.frontend.tracks_io import read_frames_csv, read_tracks_csv, write_frames_csv, write_tracks_csv

__all__ = [
    "FeatureTracker", "Keyframe", "RelativePose", "TrackingResult",
    "chain_poses", "estimate_relative_pose", "five_point", "make_tracker", "needs_keyframe", "read_frames_csv",
    "read_tracks_csv", "run_tracking", "sampson_angle", "track_frames", "track_lengths",
    "write_frames_csv", "write_tracks_csv",
]
