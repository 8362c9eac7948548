"""Renderers behind one small interface (:class:`Renderer`)."""

from .base import Renderer
from .planar import PlanarRenderer
from .pybullet_renderer import PyBulletRenderer, projection_matrix, view_matrix

__all__ = ["PlanarRenderer", "PyBulletRenderer", "Renderer", "projection_matrix", "view_matrix"]
