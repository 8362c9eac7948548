"""The scenario's contact keys: ``[[scene.obstacles]]`` (an array of tables, one per obstacle)
and ``[scene.contact]`` (the contact law's parameters, defaults from :class:`ContactModel`).

A scenario has contact when it lists obstacles or sets ``scene.contact.target_box = true``
(the target's box as an obstacle); without either the plant is the contact-free model.
"""

from __future__ import annotations

from dataclasses import fields
from typing import Annotated, Literal

import numpy as np
from pydantic import model_validator

from .._config import ConfigModel, Field
from .shapes import ORIGIN, Box, ContactModel, Cylinder, Plane, Sphere, rotation_about

Vec3 = Annotated[list[float], Field(min_length=3, max_length=3)]
_D = {f.name: f.default for f in fields(ContactModel)}


class ObstacleConfig(ConfigModel):
    """One ``[[scene.obstacles]]`` table: a plane, sphere, box or cylinder."""

    shape: Literal["plane", "sphere", "box", "cylinder"] = Field(description="kind of obstacle")
    position: Vec3 = Field(list(ORIGIN), description="m, centre (a point of a plane)")
    normal: Vec3 = Field(list(Plane().normal), description="plane: outward normal (solid below it)")
    radius: float | None = Field(None, gt=0, description="m, sphere or cylinder radius")
    size: Vec3 | None = Field(None, description="m, box edge lengths along its axes")
    length: float | None = Field(None, gt=0, description="m, cylinder length along its axis")
    rpy_deg: Vec3 = Field(
        [0.0, 0.0, 0.0], description="deg, box or cylinder orientation: roll, pitch, yaw (ZYX)"
    )

    @model_validator(mode="after")
    def _sizes(self):
        need = {"sphere": ("radius",), "box": ("size",), "cylinder": ("radius", "length")}
        for key in need.get(self.shape, ()):
            if getattr(self, key) is None:
                raise ValueError(f"a {self.shape} needs {key}")
        if self.size is not None and min(self.size) <= 0:
            raise ValueError("size must be positive")
        return self

    def obstacle(self):
        """The :mod:`tdacm.contact.shapes` record."""
        r, p, y = self.rpy_deg
        rot = rotation_about("z", y) @ rotation_about("y", p) @ rotation_about("x", r)
        pos = tuple(self.position)
        if self.shape == "plane":
            return Plane(pos, tuple(self.normal))
        if self.shape == "sphere":
            return Sphere(pos, self.radius)
        if self.shape == "box":
            return Box(pos, tuple(self.size), rot)
        return Cylinder(pos, self.radius, self.length, rot)


class ContactConfig(ConfigModel):
    """``[scene.contact]``: the contact law (:class:`~tdacm.contact.ContactModel`) and how the
    plant integrates it."""

    target_box: bool = Field(False, description="the target's box is an obstacle too")
    rod_stiffness: float = Field(_D["rod_stiffness"], gt=0, description="N/m^2, rod penalty")
    tip_stiffness: float = Field(_D["tip_stiffness"], gt=0, description="N/m, tip penalty")
    tip_radius: float = Field(_D["tip_radius"], gt=0, description="m, tip sphere radius")
    damping: float = Field(_D["damping"], ge=0, description="s/m, Hunt-Crossley damping c")
    mu_static: float = Field(_D["mu_static"], ge=0, description="static friction coefficient")
    mu_kinetic: float = Field(_D["mu_kinetic"], ge=0, description="kinetic friction coefficient")
    slip_speed: float = Field(_D["slip_speed"], gt=0, description="m/s, Coulomb regularization")
    stribeck_speed: float = Field(
        _D["stribeck_speed"], gt=0, description="m/s, static -> kinetic transition speed"
    )
    rod: bool = Field(_D["rod"], description="the rod's backbone touches the obstacles")
    tip: bool = Field(_D["tip"], description="the tip sphere touches the obstacles")
    contact_substeps: int = Field(
        32,
        ge=1,
        alias="substeps",
        description="plant RK4 steps per control period near an obstacle",
    )
    contact_margin: float = Field(
        0.01,
        ge=0,
        alias="margin",
        description="m, clearance under which a period counts as near an obstacle",
    )
    force_limit: float | None = Field(
        None, gt=0, description="N, a contact force above it ends the run (unset: no limit)"
    )

    def model(self, obstacles) -> ContactModel:
        keys = {f.name for f in fields(ContactModel)} - {"obstacles"}
        return ContactModel(obstacles=tuple(obstacles), **{k: getattr(self, k) for k in keys})


def box_obstacle(box_size: float, box_xy) -> Box:
    """The target's box: a cube of edge ``box_size`` standing on the ground at ``box_xy``."""
    x, y = (float(v) for v in box_xy)
    return Box((x, y, 0.5 * box_size), (box_size,) * 3, np.eye(3))
