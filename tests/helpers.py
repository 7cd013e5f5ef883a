"""Build DeckSpec objects directly (no YAML) for unit tests of the core."""

from __future__ import annotations

import numpy as np

from mbsim.deck.spec import BodySpec, DeckSpec, DriverSpec, FunctionSpec, JointSpec, PointSet


def body(name, mass=1.0, inertia=(1.0, 1.0, 1.0), r=(0, 0, 0), p=(1, 0, 0, 0), ground=False,
         rdot=None, omega=None, omega_local=None):
    J = np.diag(inertia) if len(inertia) == 3 else np.asarray(inertia, float)
    return BodySpec(name, float(mass), J, np.asarray(r, float), np.asarray(p, float),
                    None if rdot is None else np.asarray(rdot, float),
                    None if omega is None else np.asarray(omega, float),
                    None if omega_local is None else np.asarray(omega_local, float), ground)


def pts(P, Q=None, R=None):
    a = lambda v: None if v is None else np.asarray(v, float)
    return PointSet(a(P), a(Q), a(R))


def joint(name, type, bi, bj, points, **data):
    return JointSpec(name, type, (bi, bj), points, data)


def func(kind="constant", **data):
    return FunctionSpec(kind, data)


def driver(name, type, fn, joint=None, bodies=None, points=None, **data):
    return DriverSpec(name, type, fn, joint, bodies, points or {}, data)


def spec(bodies, joints=(), drivers=(), forces=(), gravity=(0, 0, 0), outputs=None):
    return DeckSpec(
        title="test", file="<test>", text="", gravity=np.asarray(gravity, float), parameters={},
        bodies={b.name: b for b in bodies}, joints={j.name: j for j in joints},
        drivers={d.name: d for d in drivers}, forces={f.name: f for f in forces},
        outputs=outputs or {}, analysis={},
    )
