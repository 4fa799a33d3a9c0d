"""Checking scene input: one SceneError per refusal, naming the file, the key path, the value
given and what is allowed (shared by model.py and effects.py)."""
from __future__ import annotations

import difflib
from dataclasses import fields
import math
import numbers
import operator

import numpy as np

AXES = ("x", "y", "z")
_LIMITS = (("gt", ">", operator.gt), ("ge", ">=", operator.ge), ("lt", "<", operator.lt), ("le", "<=", operator.le))


class SceneError(ValueError):
    """A scene was refused; the message names the file, key path, value and the fix."""

    def __init__(self, message: str, key: str = "", value=None, allowed: str = ""):
        super().__init__(message)
        self.key, self.value, self.allowed = key, value, allowed


def _fmt(v) -> str:
    """A value as the user wrote it (repr keeps 1000.0 and 'text' recognisable)."""
    if isinstance(v, (list, tuple, np.ndarray)):
        return "[" + ", ".join(_fmt(x) for x in v) + "]"
    if isinstance(v, dict):
        return "{" + ", ".join(f"{k} = {_fmt(x)}" for k, x in v.items()) + "}"
    if isinstance(v, np.generic):
        v = v.item()
    return repr(v)


def _g(v) -> str:
    """A computed number or vector, short."""
    if isinstance(v, (list, tuple, np.ndarray)):
        return "[" + ", ".join(_g(x) for x in v) + "]"
    return f"{float(v):.10g}"


def _did_you_mean(word, options) -> str:
    match = difflib.get_close_matches(str(word), [str(o) for o in options], n=1)
    return f" (did you mean '{match[0]}'?)" if match else ""


class _Checker:
    """Type and range checks; each failure raises one SceneError prefixed with the source."""

    def __init__(self, source: str):
        self.source = source

    def fail(self, key, value, allowed, shown=None):
        shown = _fmt(value) if shown is None else shown
        raise SceneError(f"{self.source}: {key} = {shown}: {allowed}", key, value, allowed)

    def missing(self, key, allowed):
        raise SceneError(f"{self.source}: missing required key {key}; {allowed}", key, None, allowed)

    def unknown_keys(self, table, d, allowed):
        for k, v in d.items():
            if k not in allowed:
                key = f"{table}.{k}" if table else str(k)
                hint = f"allowed keys: {', '.join(allowed)}{_did_you_mean(k, allowed)}"
                raise SceneError(f"{self.source}: unknown key {key} = {_fmt(v)}; {hint}", key, v, hint)

    def table(self, key, v):
        if not isinstance(v, dict):
            self.fail(key, v, "expected a table (key = value pairs)")
        return v

    def number(self, key, v, whole=False, **limits):
        """A finite float (an int when `whole`) within the given limits gt, ge, lt, le; a limit
        that is a scene.limits.Limit adds its reason to the refusal."""
        bounds = [f"{op} {_g(limits[name])}" for name, op, _ in _LIMITS if name in limits]
        allowed = ("a whole number" if whole else "a finite number") + "".join(
            f" {'and ' if i else ''}{b}" for i, b in enumerate(bounds))
        if isinstance(v, (bool, np.bool_)) or not isinstance(v, numbers.Real):  # bool is an int subclass
            self.fail(key, v, f"expected {allowed}, got {type(v).__name__}")
        if not math.isfinite(v) or (whole and not float(v).is_integer()):
            self.fail(key, v, f"must be {allowed}")
        x = int(v) if whole else float(v)
        failed = [name for name, _, test in _LIMITS if name in limits and not test(x, limits[name])]
        if failed:
            reasons = [limits[name] for name in failed if getattr(limits[name], "why", "")]
            self.fail(key, v, f"must be {allowed}" + (f" ({_g(reasons[0])} {reasons[0].why})" if reasons else ""))
        return x

    def magnitude(self, key, vector, limit, what="its magnitude"):
        """Refuse a vector longer than `limit` (a scene.limits.Limit: its reason is given)."""
        norm = math.hypot(*vector)
        if norm > limit:
            self.fail(key, vector, f"{what} {norm:.6g} exceeds {_g(limit)} {getattr(limit, 'why', '')}".rstrip())
        return vector

    def vector(self, key, v, n, why="", **limits):
        if isinstance(v, (str, bytes)) or not isinstance(v, (list, tuple, np.ndarray)) or len(v) != n:
            self.fail(key, v, f"expected a list of {n} numbers{why}")
        return tuple(self.number(f"{key}[{i}]", x, **limits) for i, x in enumerate(v))

    def flag(self, key, v) -> bool:
        if not isinstance(v, (bool, np.bool_)):  # TOML true/false only: 1 and "yes" are refused
            self.fail(key, v, "expected true or false")
        return bool(v)

    def choice(self, key, v, options):
        if not isinstance(v, str) or v not in options:
            allowed = "one of " + ", ".join(f"'{o}'" for o in options)
            self.fail(key, v, f"expected {allowed}{_did_you_mean(v, options)}")
        return v

    def instance(self, key, v, cls, what):
        if not isinstance(v, cls):
            self.fail(key, v, f"expected {what}")
        return v


def _plain(obj, skip=()):
    """A dataclass as TOML-shaped data: lists for tuples, None (unset) fields left out."""
    def conv(v):
        if isinstance(v, (tuple, list, np.ndarray)):
            return [conv(x) for x in v]
        return dict(v) if isinstance(v, dict) else v
    return {f.name: conv(getattr(obj, f.name)) for f in fields(obj)
            if f.name not in skip and getattr(obj, f.name) is not None}


def dim_why(dim):
    return f" (the scene is {dim}D: [domain].size has {dim} entries)"


def derive(obj, name: str, value):
    """Fill an unset field from other settings and remember that it was derived, so a change of
    those settings (Scene.with_quality) derives it again instead of keeping the old value."""
    setattr(obj, name, value)
    obj.__dict__.setdefault("_derived", set()).add(name)


def underive(obj):
    """Unset the fields `derive` filled, ready to be derived again."""
    for name in obj.__dict__.pop("_derived", ()):
        setattr(obj, name, None)
