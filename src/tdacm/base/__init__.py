"""Bases of the rod: the underactuated quadrotor and a fixed clamp."""

from .quadrotor import FixedBase, Quadrotor

__all__ = ["FixedBase", "Quadrotor"]
