"""Build DeckSpec objects directly (no YAML) for unit tests of the core; compare two
results' positions; make the Python force elements raise."""

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
    def a(v):
        return None if v is None else np.asarray(v, float)

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


def slider_crank_spec(ell=0.3, driven=True, g=9.81):
    """The seed's spatial slider-crank (reference geometry §1; Table 12.2.1): crank about x
    through (0, 0.1, 0.12), crank 0.08 m, rod `ell`, slider on the x axis, gravity -z.
    driven: the crank turned at -2 pi rad/s from pi/2 (the deck's driver), else free.
    Rod estimates close to the assembled ones for the tabulated lengths (others assemble
    from the 0.3 m estimate)."""
    from mbsim.expr import parse_expression

    xC = np.sqrt(ell**2 - 0.1**2 - 0.2**2)
    rod_p = {
        0.3: (0.42926, 0.56191, -0.69455, -0.13265),
        0.27: (0.46612, 0.53173, -0.68405, -0.17911),
        0.24: (0.52244, 0.47650, -0.65984, -0.25419),
    }.get(ell, (0.42926, 0.56191, -0.69455, -0.13265))
    bodies = [
        body("crank", 0.12, (1e-4, 1e-5, 1e-4), (0, 0.1, 0.12), (0.70711, 0.70711, 0, 0)),
        body("rod", 0.5, (0.004, 0.0004, 0.004), (xC / 2, 0.05, 0.1), rod_p),
        body("slider", 2.0, (1e-4, 1e-4, 1e-4), (xC, 0, 0)),
        body("ground", ground=True),
    ]
    joints = [
        joint("A", "revolute", "ground", "crank",
              {"ground": pts((0, 0.1, 0.12), (1, 0.1, 0.12), (0, 1.1, 0.12)),
               "crank": pts((0, 0, 0), (1, 0, 0), (0, 1, 0))}),
        joint("B", "spherical", "crank", "rod",
              {"crank": pts((0, 0.08, 0)), "rod": pts((0, ell / 2, 0))}),
        joint("C", "universal", "rod", "slider",
              {"rod": pts((0, -ell / 2, 0), (1, -ell / 2, 0)),
               "slider": pts((0, 0, 0), (1, 0, 0))}),
        joint("T", "translational", "slider", "ground",
              {"slider": pts((0, 0, 0), (1, 0, 0), (0, 1, 0)),
               "ground": pts((0, 0, 0), (1, 0, 0), (0, 1, 0))}),
    ]
    drivers = ([driver("crank", "rotation",
                       func("expression", expr=parse_expression("pi/2 - 2*pi*t")), joint="A")]
               if driven else [])
    return spec(bodies, joints, drivers, gravity=(0, 0, -g))


# one run of every integrator family with its tolerances, for tests that check a property on
# all of them (events located, friction's stick-slip): the adaptive ones at rtol 1e-9
# (generalized-alpha and HHT, second order, at 1e-8: tighter costs minutes), the fixed-step
# ones at h = 2 ms (fourth order: error ~ h^4 = 1.6e-11 in the scale of a 1 s motion)
INTEGRATOR_FAMILIES = [
    ("projection-dop853", {"rtol": 1e-9, "atol": 1e-11}),
    ("projection", {"rtol": 1e-9, "atol": 1e-11}),
    ("baumgarte", {"rtol": 1e-9, "atol": 1e-11}),
    ("rk4", {"h": 2e-3}),
    ("gcp-rk45", {"rtol": 1e-9, "atol": 1e-11}),
    ("gcp-dop853", {"rtol": 1e-9, "atol": 1e-11}),
    ("gcp-rk4", {"h": 2e-3}),
    ("genalpha", {"rtol": 1e-8, "atol": 1e-10}),
    ("hht", {"rtol": 1e-8, "atol": 1e-10}),
]


def position_error(res, ref):
    """max over outputs, bodies and output points of |r - r_ref| (m) between two Results of
    one deck at the same output times."""
    err = 0.0
    for name, ch in res.channels.items():
        if (name.startswith("bodies/") and name.endswith("/r")) or \
                (name.startswith("points/") and name.endswith("/position")):
            err = max(err, float(np.linalg.norm(ch.data - ref.channel(name).data, axis=1).max()))
    return err


def python_loads_raise(monkeypatch, exc, after=0.01):
    """Every Python force element's load evaluation after time ``after`` raises ``exc`` (an
    exception instance or class), as a failing law would, wherever it is called from (the
    compiled steps' load callback included)."""
    from mbsim.fast.dynamics import System

    apply = System.apply_python

    def failing(self, st, t, loads):
        if t > after:
            raise exc
        return apply(self, st, t, loads)

    monkeypatch.setattr(System, "apply_python", failing)
