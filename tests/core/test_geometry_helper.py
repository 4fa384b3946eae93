"""The rectangle test used by the collision checks must itself be right."""

import numpy as np
from conftest import box_corners, boxes_overlap


def test_overlap_detects_touching_and_separated_boxes():
    a = box_corners(0.0, 0.0, 0.0, 5.0, 2.0)
    assert boxes_overlap(a, box_corners(4.9, 0.0, 0.0, 5.0, 2.0))
    assert not boxes_overlap(a, box_corners(5.1, 0.0, 0.0, 5.0, 2.0))
    assert not boxes_overlap(a, box_corners(0.0, 2.1, 0.0, 5.0, 2.0))
    # Rotated box: its corner reaches into the other one.
    assert boxes_overlap(a, box_corners(0.0, 2.3, np.pi / 4, 5.0, 2.0))
