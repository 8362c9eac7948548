"""Records (tdacm._records): a world's row of stacked records, and borrowed arrays."""

from typing import NamedTuple

import numpy as np
from numba import njit

from tdacm._records import borrow, replicate, stack, take


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
