"""Force specs and small models for the force tests (no YAML)."""

from __future__ import annotations

import numpy as np

from mbsim.deck.spec import ForceSpec
from mbsim.forces.measures import MeasureSpec
from mbsim.model import compile_model
from mbsim.rotations import E as rot_E
from tests.helpers import body, joint, pts, spec
from tests.reference import equations as eq


def force(name, type_, bodies, points=None, **data):
    """ForceSpec; points: {body: P} (P a 3-list) or {body: PointSet}."""
    ps = {b: (v if hasattr(v, "P") else pts(v)) for b, v in (points or {}).items()}
    return ForceSpec(name, type_, tuple(bodies), ps, data)


def measure(name, type_, bodies=(), points=None, **data):
    ps = {b: (v if hasattr(v, "P") else pts(v)) for b, v in (points or {}).items()}
    return MeasureSpec(name, type_, tuple(bodies), ps, data)


def two_body_deck(forces, rng, joints=()):
    """The deck of :func:`two_body_model` (a DeckSpec: its forces can be edited and the deck
    compiled again)."""
    bodies = [
        body("a", 2.0, (1, 2, 3), rng.normal(size=3), rng.normal(size=4)),
        body("b", 3.0, (2, 2, 1), rng.normal(size=3), rng.normal(size=4)),
    ]
    return spec(bodies, joints, forces=forces)


def two_body_model(forces, rng, joints=()):
    """Bodies a and b at random poses (off any constraint), gravity off."""
    return compile_model(two_body_deck(forces, rng, joints))


def revolute_ab(rng):
    """A revolute joint between a and b with random frames (only its frames are used)."""
    P = rng.normal(size=3)
    return joint(
        "REV",
        "revolute",
        "a",
        "b",
        {
            "a": pts(P, P + rng.normal(size=3), P + rng.normal(size=3)),
            "b": pts(rng.normal(size=3), rng.normal(size=3), rng.normal(size=3)),
        },
    )


def tangent(model, q, rng):
    """A random tangent direction dq: dp perpendicular to p for every body."""
    dq = rng.normal(size=model.nq).reshape(model.nb, 7)
    p = q.reshape(model.nb, 7)[:, 3:]
    dq[:, 3:] -= p * np.sum(dq[:, 3:] * p, 1, keepdims=True)
    return dq.reshape(-1)


def elastic_work_pairs(model, q, rng, h, n=6, fixed=()):
    """(-Q . dq, (V(q + h dq) - V(q - h dq)) / 2h) for n random tangent directions dq
    (:func:`tangent`; the bodies in ``fixed`` held), Q the applied forces at zero velocity
    from the core: equal to O(h^2) where the loads are -grad V."""
    from mbsim import core

    Q, _, _ = core.applied_forces(model, None, q, np.zeros(model.nq))
    out = []
    for _ in range(n):
        dq = tangent(model, q, rng).reshape(model.nb, 7)
        dq[list(fixed)] = 0
        dq = dq.reshape(-1)
        dV = (core.potential_energy(model, None, q + h * dq)
              - core.potential_energy(model, None, q - h * dq)) / (2 * h)
        out.append((-Q @ dq, dV))
    return out


def rotations(model, q, dq):
    """(nb, 3) global small rotations dphi = 2 E(p) dp of a tangent dq."""
    p = q.reshape(model.nb, 7)[:, 3:]
    dp = dq.reshape(model.nb, 7)[:, 3:]
    return 2 * np.einsum("bij,bj->bi", rot_E(p), dp)


def Q_of(model, q, qd=None, t=0.0):
    qd = np.zeros(model.nq) if qd is None else qd
    return eq.applied_forces(model, q, qd, t)[0]


def assert_bad_edit(deck, old, new, message, path):
    """The deck file ``deck`` with ``old`` replaced by ``new`` (once) is a DeckError whose
    text holds ``message`` and the key ``path``."""
    import pytest

    from mbsim.deck import load_deck_text
    from mbsim.errors import DeckError

    text = deck.read_text()
    assert old in text
    with pytest.raises(DeckError) as exc:
        compile_model(load_deck_text(text.replace(old, new, 1)))
    assert message in str(exc.value) and path in str(exc.value)
