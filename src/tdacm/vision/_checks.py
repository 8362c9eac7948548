"""Input validation for the vision layer: the project's one set of checks,
:mod:`tdacm._validate`, under the name the vision modules import."""

from .._validate import (  # noqa: F401  (re-exported)
    array,
    finite_scalar,
    nonnegative,
    points,
    positive,
    positive_int,
    rotation,
    transform,
    unit_vector,
)
