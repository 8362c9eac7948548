"""Records (tdacm._records): a world's row of stacked records, and borrowed arrays."""

from typing import NamedTuple

import numpy as np
from numba import njit

from tdacm._records import borrow, replicate, stack, take, take_at


class Inner(NamedTuple):
    gains: np.ndarray
    scale: float
    flags: np.ndarray


class Outer(NamedTuple):
    inner: Inner
    state: np.ndarray
    count: int


@njit
def _bump(inner, state, w):
    """Writes through a world's row (a call that is not inlined: its arguments are passed on)."""
    state[w, 0] += inner.scale * inner.gains[1]
    inner.flags[0] = True
    return inner.gains.sum()


@njit
def _steps(records, reps, borrowed):
    if borrowed:
        records = borrow(records)
    total = 0.0
    for r in range(reps):
        w = r % records.state.shape[0]
        total += _bump(take(records.inner, w), records.state, w)
    return total, records.count


def _records():
    worlds = [Inner(np.arange(3.0) + w, 0.5 * (w + 1), np.zeros(2, np.bool_)) for w in range(3)]
    return Outer(stack(worlds), np.zeros((3, 2)), 7)


def test_borrowed_records_read_and_write_the_same_arrays():
    owned, borrowed = _records(), _records()
    a = _steps(owned, 30, False)
    b = _steps(borrowed, 30, True)
    assert a == b
    assert a[1] == 7  # a scalar field passes through
    # ten visits of each world, each adding scale * gains[1] = 0.5 (w + 1) (1 + w)
    np.testing.assert_array_equal(borrowed.state[:, 0], [5.0, 20.0, 45.0])
    np.testing.assert_array_equal(borrowed.state, owned.state)
    assert borrowed.inner.flags[:, 0].all()


def test_borrow_is_the_record_itself_in_python():
    r = _records()
    assert borrow(r) is r


def test_take_and_replicate_round_trip():
    one = Inner(np.array([1.0, 2.0, 3.0]), 2.0, np.ones(2, np.bool_))
    many = replicate(one, 4)
    assert many.gains.shape == (4, 3) and many.scale.shape == (4,)
    row = take(many, 2)
    np.testing.assert_array_equal(row.gains, one.gains)
    assert float(row.scale) == 2.0


@njit
def _arm_rows(records, w, a):
    """A world's arm row both ways, written through the second."""
    one, two = take(take(records, w), a), take_at(records, w, a)
    two.inner.flags[1] = True
    return one.inner.gains.sum(), two.inner.gains.sum(), one.count, two.count, one.inner.scale


def test_take_at_is_take_of_take():
    """Row ``a`` of world ``w`` of records stacked over worlds then arms, in one step: the same
    views (a write through one shows in the stack) in Python and in compiled code."""
    worlds = [stack([Outer(Inner(np.arange(3.0) + 10 * w + a, 0.5 * a + w, np.zeros(2, np.bool_)),
                           np.full(2, float(a)), 3 * w + a) for a in range(2)])
              for w in range(3)]  # fmt: skip
    many = stack(worlds)
    assert many.inner.gains.shape == (3, 2, 3) and many.count.shape == (3, 2)
    for w in range(3):
        for a in range(2):
            row, ref = take_at(many, w, a), take(take(many, w), a)
            np.testing.assert_array_equal(row.inner.gains, ref.inner.gains)
            assert row.count == ref.count == 3 * w + a and row.inner.scale == ref.inner.scale
            g1, g2, c1, c2, sc = _arm_rows(many, w, a)
            assert g1 == g2 == ref.inner.gains.sum() and c1 == c2 == 3 * w + a
            assert sc == 0.5 * a + w
    assert many.inner.flags[:, :, 1].all() and not many.inner.flags[:, :, 0].any()
