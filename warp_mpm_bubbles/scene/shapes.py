"""The shapes that seed particles: Box, Sphere and Cylinder ([[shapes]] tables). Lengths in metres,
velocities in m/s, pressures in Pa (gauge: above [domain].ambient_pressure)."""
from __future__ import annotations

from dataclasses import dataclass, fields
from typing import ClassVar

import numpy as np

from .checks import AXES, _Checker, _did_you_mean, _fmt, _g, dim_why
from .limits import MAX_SPEED, max_gauge_pressure


class _Shape:
    """Behaviour shared by the shape dataclasses (which keep their own field order)."""

    type_name: ClassVar[str]

    def contains(self, points: np.ndarray) -> np.ndarray:
        dim = len(self.bounds()[0])
        return self._contains(np.asarray(points)[:, :dim])  # 2D shapes ignore a z column

    def describe(self) -> str:
        parts = [f"{f.name}={_fmt(getattr(self, f.name))}" for f in fields(self)
                 if f.name not in ("material", "velocity", "pressure")]
        return f"{self.type_name} " + " ".join(parts)

    def _validate(self, c: _Checker, key, scene):  # scene: model.Scene, which imports this module
        dim, mats = scene.dim, scene.materials
        if not isinstance(self.material, str) or self.material not in mats:
            c.fail(f"{key}.material", self.material,
                   f"no such material; defined materials: {', '.join(mats)}{_did_you_mean(self.material, mats)}")
        if mats[self.material].kind == "foam":
            c.fail(f"{key}.material", self.material, "foam is made at the surface by [effects.foam], not placed "
                                                     "by a shape; use a liquid or gas material")
        self._validate_geometry(c, key, scene.domain)
        self.velocity = (0.0,) * dim if self.velocity is None else self.velocity
        self.velocity = c.vector(f"{key}.velocity", self.velocity, dim, dim_why(dim))
        c.magnitude(f"{key}.velocity", self.velocity, MAX_SPEED, "its speed")
        if self.pressure is not None:
            m = mats[self.material]
            if not m.is_gas or m.eos == "incompressible":
                c.fail(f"{key}.pressure", self.pressure, f"an initial pressure needs a compressible gas; material "
                                                         f"'{self.material}' is {m.kind}"
                       + (f" with eos = \"{m.eos}\"" if m.is_gas else "") + "; remove the key")
            self.pressure = c.number(f"{key}.pressure", self.pressure, gt=-scene.domain.ambient_pressure,
                                     le=max_gauge_pressure(mats))
        lo, hi = self.bounds()
        size = np.array(scene.domain.size)
        if (lo < -1e-9 * size).any() or (hi > size * (1 + 1e-9)).any():
            c.fail(key, self, f"its bounds {_g(lo)} .. {_g(hi)} are not inside the domain {_g(0 * size)} .. "
                              f"{_g(size)}; move or shrink the shape, or enlarge [domain].size",
                   shown=self.describe())


@dataclass
class Box(_Shape):
    """An axis-aligned box of `material`.

    Attributes:
        material: name of a liquid or gas material in Scene.materials.
        min, max: opposite corners, m (2 or 3 numbers, as [domain].size); min < max on every axis.
        velocity: initial velocity, m/s (default at rest); its speed at most 1,000 m/s.
        pressure: gas only, initial gauge pressure, Pa (above ambient; > -ambient; at most
            density x 444^2 of the lightest liquid, 1.97e8 for water, and 1e9).
    """
    material: str
    min: tuple
    max: tuple
    velocity: tuple | None = None
    pressure: float | None = None  # gas only: initial gauge pressure, Pa
    type_name: ClassVar[str] = "box"

    def bounds(self):
        return np.array(self.min, float), np.array(self.max, float)

    def _contains(self, p):
        return np.all((p >= np.array(self.min)) & (p <= np.array(self.max)), axis=1)

    def _validate_geometry(self, c, key, domain):
        why = dim_why(domain.dim)
        self.min = c.vector(f"{key}.min", self.min, domain.dim, why)
        self.max = c.vector(f"{key}.max", self.max, domain.dim, why)
        for a, (lo, hi) in enumerate(zip(self.min, self.max)):
            if lo >= hi:
                c.fail(f"{key}.min", self.min, f"must be < {key}.max = {_fmt(self.max)} on every axis "
                                               f"(not on {AXES[a]}: {_g(lo)} >= {_g(hi)})")


@dataclass
class Sphere(_Shape):
    """A ball (a disk in 2D) of `material`.

    Attributes:
        material: name of a liquid or gas material in Scene.materials.
        center: m (2 or 3 numbers); radius: m, > 0. The whole shape must lie inside the domain.
        velocity: initial velocity, m/s (default at rest); its speed at most 1,000 m/s.
        pressure: gas only, initial gauge pressure, Pa (above ambient; > -ambient; at most
            density x 444^2 of the lightest liquid, 1.97e8 for water, and 1e9).
    """
    material: str
    center: tuple
    radius: float
    velocity: tuple | None = None
    pressure: float | None = None  # gas only: initial gauge pressure, Pa
    type_name: ClassVar[str] = "sphere"

    def bounds(self):
        c = np.array(self.center, float)
        return c - self.radius, c + self.radius

    def _contains(self, p):
        return np.sum((p - np.array(self.center)) ** 2, axis=1) <= self.radius ** 2

    def _validate_geometry(self, c, key, domain):
        self.center = c.vector(f"{key}.center", self.center, domain.dim, dim_why(domain.dim))
        self.radius = c.number(f"{key}.radius", self.radius, gt=0)


@dataclass
class Cylinder(_Shape):
    """A round cylinder of `material` along `axis` (in 2D along z: a disk; along x or y: a strip).

    Attributes:
        material: name of a liquid or gas material in Scene.materials.
        center: m; radius: m, > 0; axis: "x" | "y" | "z" (default "z").
        length: m along the axis; None spans the whole domain along it.
        velocity: initial velocity, m/s (default at rest); its speed at most 1,000 m/s.
        pressure: gas only, initial gauge pressure, Pa (above ambient; > -ambient; at most
            density x 444^2 of the lightest liquid, 1.97e8 for water, and 1e9).
    """
    material: str
    center: tuple
    radius: float
    axis: str = "z"
    length: float | None = None
    velocity: tuple | None = None
    pressure: float | None = None  # gas only: initial gauge pressure, Pa
    type_name: ClassVar[str] = "cylinder"

    def bounds(self):
        c, a = np.array(self.center, float), AXES.index(self.axis)
        half = np.full(len(c), float(self.radius))
        if a < len(c):  # a 2D cylinder along z is a disk: no extent along its axis
            half[a] = 0.5 * self.length
        return c - half, c + half

    def _contains(self, p):
        c, a = np.array(self.center), AXES.index(self.axis)
        radial = [i for i in range(len(c)) if i != a]
        inside = np.sum((p[:, radial] - c[radial]) ** 2, axis=1) <= self.radius ** 2
        if a < len(c):
            inside &= np.abs(p[:, a] - c[a]) <= 0.5 * self.length
        return inside

    def _validate_geometry(self, c, key, domain):
        self.center = c.vector(f"{key}.center", self.center, domain.dim, dim_why(domain.dim))
        self.radius = c.number(f"{key}.radius", self.radius, gt=0)
        self.axis = c.choice(f"{key}.axis", self.axis, AXES)
        a = AXES.index(self.axis)
        if self.length is None:
            if a < domain.dim:  # span the whole domain: centre it along the axis
                self.length = domain.size[a]
                self.center = tuple(domain.size[a] / 2 if i == a else x for i, x in enumerate(self.center))
            else:  # 2D disk: the length is the one-cell slab thickness (unused)
                self.length = domain.dx
        self.length = c.number(f"{key}.length", self.length, gt=0)


SHAPE_TYPES = {cls.type_name: cls for cls in (Box, Sphere, Cylinder)}

