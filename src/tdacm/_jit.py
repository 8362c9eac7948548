"""The decorator of the hot compiled kernels that allocate nothing: numba without its
reference counting.

numba counts the references of every array it passes around (its runtime, NRT): each view
(``x[i]``, ``x[0, a:b]``), each tuple of arrays unpacked and each array handed to a compiled
function adds and later removes a reference with an atomic instruction. In the small
kernels of the model (eight coordinates, six Magnus steps) these atomics were half the cost:
one evaluation of the forward dynamics of the paper's system took 8.3 us with them and
4.3 us without, with bit-identical results (the arithmetic is the same; only the bookkeeping
goes). With two threads stepping worlds that share the model's arrays, the counts of those
shared arrays also bounce between the cores' caches.

:data:`kernel` compiles a function with the runtime off (numba's ``_nrt=False``) and cached.
Such a function cannot allocate (numba refuses to compile ``np.empty`` or a copying slice
assignment there: the scratch comes from the caller) and must not return an array (numba
refuses a new one; ``tests/test_jit.py`` checks that no such kernel returns one of its
arguments): it works in place on arrays that its caller owns, and may call compiled functions
that return no new array.

numba compiles a function called from a kernel *without* the runtime too, unless the
function sets its own: a callee that allocates would then fail to compile, or compile, depending
on which caller compiled it first. Every compiled function that a kernel reaches is therefore
either a kernel itself or declares the runtime with :data:`allocating` (``tests/test_jit.py``
walks the calls).
"""

from __future__ import annotations

from numba import njit

#: ``@kernel``: :func:`numba.njit` with ``cache=True`` and without reference counting (the
#: module docstring): for kernels that allocate nothing and return scalars, tuples of scalars
#: or nothing
kernel = njit(cache=True, _nrt=False)

#: ``@allocating``: :func:`numba.njit` with ``cache=True`` and the runtime declared, for the
#: functions that kernels call and that allocate (their scratch, their results): compiled with
#: the runtime whoever calls them first
allocating = njit(cache=True, _nrt=True)
