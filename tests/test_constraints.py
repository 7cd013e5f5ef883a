"""Every joint and driver type: analytic Phi_q, nu, gamma against finite differences of Phi,
in both implementations: the numpy reference (tests/reference/equations.py, basic.py) and the
C kernels the integrators use (mbsim.fast, kernels.c), each differentiated against its own Phi.

Checks (q random, off the constraint manifold; |p| off 1 too, since Phi_q is the exact
derivative of Phi everywhere):
- Phi_q == central difference of Phi (step 1e-6: error O(h^2 |Phi'''|) ~ 1e-12, round-off
  ~ 1e-16/1e-6 = 1e-10, so 1e-7 absolute is a safe bound for O(1) data);
- nu == -dPhi/dt (central difference in t);
- gamma == -d^2/ds^2 Phi(q + s qd, t + s) at s = 0: along a path with qdd = 0,
  Phi_q qdd = gamma  <=>  Phi'' = 0, so Phi'' = -gamma  (second difference, step 1e-4:
  truncation ~ h^2 ~ 1e-8, round-off ~ 1e-16/h^2 = 1e-8; bound 1e-5).
"""

import numpy as np
import pytest

from mbsim import fast
from mbsim.constraints import DRIVERS, JOINTS
from mbsim.model import compile_model
from tests.helpers import body, driver, func, joint, pts, spec
from tests.reference import equations as eq

rng = np.random.default_rng(12345)


def _pointset(needs):
    if needs is None:
        return None
    P = rng.normal(size=3)
    Q = P + rng.normal(size=3) if "Q" in needs else None
    R = P + rng.normal(size=3) if "R" in needs else None
    return pts(P, Q, R)


def _two_bodies():
    return [body("a", 2.0, (1, 2, 3), rng.normal(size=3), rng.normal(size=4)),
            body("b", 3.0, (2, 2, 1), rng.normal(size=3), rng.normal(size=4))]


def _joint_spec(type_):
    cls = JOINTS[type_]
    ni, nj = cls.needs
    points = {"a": _pointset(ni)}
    data = {}
    if nj is not None:
        points["b"] = _pointset(nj)
    if cls.target == "distance":
        data["distance"] = 0.7
    if type_ == "absolute":
        data.update(axis="y", value=func("expression", expr=_expr("0.3*sin(2*t) + t**2")))
    return joint("J", type_, "a", "b" if nj is not None else None, points, **data)


def _expr(text):
    from mbsim.expr import parse_expression

    return parse_expression(text)


def _driver_specs(type_):
    f = func("expression", expr=_expr("0.4 + 1.3*t + 0.2*sin(3*t)"))
    if type_ == "rotation":
        return [_joint_spec("revolute")], [driver("D", "rotation", f, joint="J")]
    if type_ == "translation":
        return [_joint_spec("translational")], [driver("D", "translation", f, joint="J")]
    if type_ == "distance":
        return [], [driver("D", "distance", f, bodies=("a", "b"),
                           points={"a": pts(rng.normal(size=3)), "b": pts(rng.normal(size=3))})]
    if type_ == "absolute":
        return [], [driver("D", "absolute", f, bodies=("a", None),
                           points={"a": pts(rng.normal(size=3))}, axis="z")]
    raise KeyError(type_)


IMPLS = ["reference", "c"]


def _evaluators(model, impl):
    """(terms(q, t, qd) -> Terms with jac, gamma, nu; phi(q, t) -> Phi) of one implementation."""
    if impl == "reference":
        return (lambda q, t, qd: eq.constraints(model, q, t, qd=qd, gamma=True, nu=True),
                lambda q, t: eq.phi(model, q, t))
    fc = fast.FastConstraints(model, sparse=False)
    return (lambda q, t, qd: fc.constraints(q, t, qd=qd, gamma=True, nu=True),
            lambda q, t: fc.constraints(q, t, jac=False).phi)


def _check(model, impl="reference", t=0.37):
    terms, phi = _evaluators(model, impl)
    q = model.q0 + 0.1 * rng.normal(size=model.nq)
    qd = rng.normal(size=model.nq)
    T = terms(q, t, qd)
    h = 1e-6
    J_fd = np.empty_like(T.jac)
    for k in range(model.nq):
        dq = np.zeros(model.nq)
        dq[k] = h
        J_fd[:, k] = (phi(q + dq, t) - phi(q - dq, t)) / (2 * h)
    assert np.abs(T.jac - J_fd).max() < 1e-7
    nu_fd = -(phi(q, t + h) - phi(q, t - h)) / (2 * h)
    assert np.abs(T.nu - nu_fd).max() < 1e-7
    s = 1e-4
    d2 = (phi(q + s * qd, t + s) - 2 * phi(q, t) + phi(q - s * qd, t - s)) / s ** 2
    assert np.abs(T.gamma + d2).max() < 1e-5 * max(1.0, np.abs(d2).max())
    # sparse and dense Jacobians are the same matrix
    if impl == "reference":
        Js = eq.constraints(model, q, t, sparse=True).jac.toarray()
    else:
        Js = fast.FastConstraints(model, sparse=True).constraints(q, t).jac.toarray()
    assert np.array_equal(Js, T.jac)


@pytest.mark.parametrize("impl", IMPLS)
@pytest.mark.parametrize("type_", sorted(JOINTS))
def test_joint_derivatives_match_finite_differences(type_, impl):
    js = _joint_spec(type_)
    model = compile_model(spec(_two_bodies(), [js]))
    assert model.item("J").rows.size == JOINTS[type_].n_eq
    _check(model, impl)


@pytest.mark.parametrize("impl", IMPLS)
@pytest.mark.parametrize("type_", sorted(DRIVERS))
def test_driver_derivatives_match_finite_differences(type_, impl):
    joints, drivers = _driver_specs(type_)
    model = compile_model(spec(_two_bodies(), joints, drivers))
    _check(model, impl)


@pytest.mark.parametrize("impl", IMPLS)
def test_ground_and_normalization_rows(impl):
    model = compile_model(spec([body("g", ground=True), body("a", r=(1, 2, 3))],
                               [joint("S", "spherical", "g", "a",
                                      {"g": pts([1, 0, 0]), "a": pts([0, 1, 0])})]))
    # book counting: 2 bodies x 7 = 14 coordinates; 3 (sph) + 6 (ground) + 2 (norm) = 11
    assert model.nq == 14 and model.m == 11
    _check(model, impl)
