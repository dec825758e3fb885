"""The compiled copies and cross product against numpy's: the same bits."""

import numpy as np

from windbench.arrays import copy_head, copy_rows, cross


def test_cross_is_numpys_bit_for_bit_and_right_handed():
    rng = np.random.default_rng(7)
    a, b = rng.standard_normal((2, 200, 3))
    ours = np.array([cross(x, y) for x, y in zip(a, b, strict=True)])
    assert np.array_equal(ours, np.cross(a, b))
    e = np.eye(3)
    assert np.array_equal(cross(e[0], e[1]), e[2])
    assert np.array_equal(cross(e[1], e[0]), -e[2])


def test_copies_write_the_head_and_leave_the_rest():
    src = np.arange(12.0).reshape(4, 3)
    dst = np.full((6, 3), -1.0)
    copy_rows(dst, src, 4)
    assert np.array_equal(dst[:4], src) and np.all(dst[4:] == -1.0)
    head = np.zeros(5, np.int64)
    copy_head(head, np.arange(1, 6), 3)
    assert head.tolist() == [1, 2, 3, 0, 0]
