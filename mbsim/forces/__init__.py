"""Force elements (gravity is a model field, applied in :mod:`mbsim.core`)."""

from __future__ import annotations

from mbsim.errors import DeckError
from mbsim.forces.base import ForceElement

FORCES: dict[str, type[ForceElement]] = {}


def register(cls):
    FORCES[cls.type] = cls
    return cls


def compile_forces(spec, body_index) -> tuple:
    out = []
    for name, fs in spec.forces.items():
        cls = FORCES.get(fs.type)
        if cls is None:
            raise DeckError(f"unknown force type {fs.type!r}; known: {', '.join(sorted(FORCES))}",
                            fs.where.child("type"))
        el = cls.from_spec(fs, body_index)
        el.name = name
        out.append(el)
    return tuple(out)


from mbsim.forces import elements, tire  # noqa: E402, F401  (register the built-in types, the tire)

# isort: split
# bushing; contact and stop; stick-slip joint friction
from mbsim.forces import bushing, contact, friction  # noqa: E402, F401
