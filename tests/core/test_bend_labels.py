"""frames.csv labels the frames of a bend the images did not see as a junction."""

import numpy as np

from pipemap.pipeline import bend_labels


def test_frames_from_a_bend_keyframe_to_the_next_are_labelled_bend():
    labels = {i: ("junction" if 4 <= i < 6 else "straight") for i in range(12)}
    labels[9] = "repeated"
    keyframes = np.array([0, 3, 5, 8, 11])
    bends = np.array([False, True, True, False, True])
    # keyframe 1 covers frames 3-4 (4 was classified junction), keyframe 2 frames 5-7 (5 junction), the last
    # keyframe its own frame; classified and repeated frames keep their labels
    assert bend_labels(labels, keyframes, bends) == {3: "bend", 6: "bend", 7: "bend", 11: "bend"}
    assert bend_labels(labels, keyframes, np.zeros(5, bool)) == {}
    assert bend_labels(labels, keyframes, None) == {}
