"""Records: a block's typed parameters and state, for one world or many.

A block of the closed loop keeps its parameters and its state as *records*: NamedTuples of
numpy arrays and scalars with named fields (a scalar that the block's compiled step changes
is a one-element array, since a tuple's fields cannot be reassigned). The block's compiled
step takes its records as arguments, so the same function runs one world (the block loop,
:mod:`tdacm.loop`) and every world of a batch (:mod:`tdacm.batch`).

Many worlds' records are the same NamedTuple with a leading world axis on every field
(:func:`stack`). :func:`take` gives world ``w``'s record of such a stack, in Python and inside
compiled code; there the row has exactly the numba type of one world's record (a field
stacked from C-contiguous arrays is a C-contiguous array again, a stacked scalar a scalar), so
the engine calls the block's step as compiled once for the block loop: no second
specialization, no second truth.
"""

from __future__ import annotations

import numpy as np
from numba import types
from numba.core import cgutils
from numba.extending import intrinsic, overload

__all__ = ["take", "take_at", "stack", "put", "replicate", "copy_into", "borrow"]


def take(records, w: int):
    """World ``w``'s record of the stacked ``records`` (module docstring): the NamedTuple of
    ``field[w]`` (views of the stacked arrays; a nested record is taken in turn)."""
    return _row(records, w)


def take_at(records, w: int, a: int):
    """Row ``a`` of world ``w``'s record of ``records`` stacked over worlds and then over arms
    (a world axis and an arm axis): ``take(take(records, w), a)`` with one record built instead
    of two (in compiled code each record built is a call passing every array's fields, which
    the caller's compile pays for)."""
    return _row(records, (w, a))


def _row(records, index):
    """The NamedTuple of ``field[index]`` of ``records``, nested records in turn."""
    return type(records)(
        *(_row(f, index) if _is_record(f) else f[index] for f in records)  # type: ignore[arg-type]
    )


def _is_record(value) -> bool:
    return isinstance(value, tuple) and hasattr(value, "_fields")


def _row_impl(records, fn, params: str):
    """The compiled form of :func:`take` (``fn``, ``params`` ``"w"``) or :func:`take_at`
    (``"w, a"``): a constructor call over the record's fields, generated once per record type
    (the calling function is what numba caches); None for a value that is not a record."""
    if not isinstance(records, types.BaseNamedTuple):
        return None
    args = ", ".join(
        f"fn(records[{i}], {params})" if isinstance(t, types.BaseNamedTuple)
        else f"records[{i}][{params}]"
        for i, t in enumerate(records.types)
    )  # fmt: skip
    src = f"def impl(records, {params}):\n    return cls({args})\n"
    scope = {"cls": records.instance_class, "fn": fn}
    exec(src, scope)  # noqa: S102 - the source is the field list above
    return scope["impl"]


@overload(take)
def _take_compiled(records, w):
    """:func:`take` in compiled code (:func:`_row_impl`)."""
    return _row_impl(records, take, "w")


@overload(take_at)
def _take_at_compiled(records, w, a):
    """:func:`take_at` in compiled code (:func:`_row_impl`)."""
    return _row_impl(records, take_at, "w, a")


def borrow(records):
    """``records`` with every array *borrowed*: the same data, shape and strides without an
    owner (numba's meminfo), so compiled code passing it on does no reference counting.

    Numba counts a reference of every array argument at each compiled call it enters and
    leaves (an atomic increment and decrement of the array's owner). The engine's per-world
    steps take records of dozens of arrays each; every world's rows are views of one stacked
    array, so the threads stepping worlds also contend for the same owner's counter. Measured
    on ``paper-in-fov`` (N = 256): a third of the engine's compiled time was these counts.
    The caller keeps the arrays alive: :func:`~tdacm.batch.engine.worlds` borrows the batch's
    model and data, which its Python caller holds for the whole call. In Python: ``records``
    itself (an array always has its owner there)."""
    return records


def _holds_array(ty) -> bool:
    if isinstance(ty, types.Array):
        return True
    return isinstance(ty, types.BaseTuple) and any(_holds_array(t) for t in ty.types)


def _without_owners(context, builder, ty, value):
    """The LLVM ``value`` of numba type ``ty`` with every array's meminfo and parent null
    (tuples and records walked field by field; other values as they are)."""
    if isinstance(ty, types.Array):
        model = context.data_model_manager[ty]
        for name in ("meminfo", "parent"):
            i = model.get_field_position(name)
            value = builder.insert_value(value, cgutils.get_null_value(value.type.elements[i]), i)
        return value
    if isinstance(ty, types.BaseTuple):
        for i, t in enumerate(ty.types):
            if _holds_array(t):
                item = _without_owners(context, builder, t, builder.extract_value(value, i))
                value = builder.insert_value(value, item, i)
    return value


@intrinsic
def _unowned(typingctx, records):
    """:func:`borrow` as one intrinsic over the whole record: two field insertions per array
    (a generated function per record type, calling one intrinsic per array, made a function
    of the engine's model and data take about 60 s more to compile). The engine's entry still
    compiles about 47 s longer with its records borrowed (docs/benchmarks.md, "Borrowed
    arrays"), once per machine."""

    def codegen(context, builder, signature, args):
        return _without_owners(context, builder, signature.args[0], args[0])

    return records(records), codegen


@overload(borrow)
def _borrow_compiled(records):
    """:func:`borrow` in compiled code."""
    if _holds_array(records):
        return lambda records: _unowned(records)
    return lambda records: records


def copy_into(src, dst) -> None:
    """Copy every array field of the record ``src`` into the same field of ``dst`` (in place;
    records of one type, e.g. one world's outputs into another's)."""
    for a, b in zip(src, dst, strict=True):
        if _is_record(a):
            copy_into(a, b)
        else:
            b[...] = a


@overload(copy_into)
def _copy_into_compiled(src, dst):
    """:func:`copy_into` in compiled code: one assignment per field, generated once per record
    type."""
    if not isinstance(src, types.BaseNamedTuple):
        return None
    body = "\n".join(
        f"    copy_into(src[{i}], dst[{i}])"
        if isinstance(t, types.BaseNamedTuple)
        else f"    dst[{i}][...] = src[{i}]"
        for i, t in enumerate(src.types)
    )
    scope = {"copy_into": copy_into}
    exec(f"def impl(src, dst):\n{body}\n", scope)  # noqa: S102 - the source is the field list
    return scope["impl"]


def stack(records: list):
    """The stacked record of a list of records of one type (one per world): every field with
    a leading world axis, C-contiguous (``numpy.stack`` of the arrays; scalars become arrays
    of their type)."""
    if not records:
        raise ValueError("stack: at least one record")
    first = records[0]
    if not _is_record(first):  # a plain array or scalar: one row a world
        return np.ascontiguousarray(np.stack([np.asarray(r) for r in records]))
    out = []
    for i, f in enumerate(first):
        column = [r[i] for r in records]
        if _is_record(f):
            out.append(stack(column))
        else:
            out.append(np.ascontiguousarray(np.stack([np.asarray(c) for c in column])))
    return type(first)(*out)


def replicate(record, n: int):
    """``n`` worlds of one record (:func:`stack` of ``n`` copies)."""
    return stack([record] * int(n))


def put(records, w: int, record) -> None:
    """Write ``record`` into world ``w``'s row of the stacked ``records`` (in place)."""
    for f, v in zip(records, record, strict=True):
        if _is_record(f):
            put(f, w, v)
        else:
            f[w] = v
