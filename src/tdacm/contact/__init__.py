"""Contact of the arm with its surroundings: obstacles, the compliant contact law and friction.

This package sits at the layer of ``rod``, ``base`` and ``aero`` (it imports only
``_validate``, numpy and numba), below ``system``, whose kernels call its numba functions inside
the coupled dynamics (the distributed wrench and the tip wrench of eq. (16)).
:func:`tdacm.system.contact.contact_array` packs a :class:`ContactModel` for a built model.
"""

from .shapes import SHAPES, Box, ContactModel, Cylinder, Plane, Sphere, rotation_about

__all__ = ["SHAPES", "Box", "ContactModel", "Cylinder", "Plane", "Sphere", "rotation_about"]
