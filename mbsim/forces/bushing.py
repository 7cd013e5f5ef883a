"""Bushing: six-component linear (or tabulated) stiffness and damping between two body frames,
as ADAMS BUSHING.

Frames.  Body i carries the bushing frame B_i at P_i with axes (f, g, h) from the points P, Q,
R in its frame (x along P->Q, y towards R, z = x cross y; the convention of the joint tables,
:func:`mbsim.model.joint_frame`); body j carries B_j likewise.  Global orientation matrices
B_i = A_i C_i, B_j = A_j C_j (C: the constant frame axes in body coordinates).  Body i is the
reference (ADAMS' J marker), body j the one that moves against it (ADAMS' I marker); either
may be the ground body.

Deflections.

- translational  d = B_i^T (P_j - P_i)          (3,) m, in frame i
- rotational     theta = log(B_i^T B_j)         (3,) rad, the rotation vector of the relative
  rotation (axis times angle, components in frame i, equal to those in frame j since R theta
  = theta).  For small angles theta equals ADAMS' (AX, AY, AZ) to second order; it is defined
  and smooth for |theta| < pi (at pi the axis flips sign: the bushing is meant for the small
  deflections where its stiffness was measured).
- rates          d' = d/dt d (in frame i), theta' = J_r^{-1}(theta) B_j^T (omega_j - omega_i),
  with J_r the right Jacobian of SO(3): exp(theta + dtheta) = exp(theta) exp(J_r dtheta).

Loads.  The elastic-and-preload potential is

    V = sum_k V_k(d_k) + sum_k W_k(theta_k) - f0 . d - t0 . theta,

V_k = k_k d_k^2 / 2 (or the integral of a curve f_k(d)), W_k = kr_k theta_k^2 / 2 (or of a curve).
The generalised loads are its exact gradient plus the damping C d', Cr theta':

    e   = K d + C d' - f0      (frame i; force on body j is -B_i e, at the point P_j;
                                the reaction +B_i e acts on body i at the same point P_j)
    m   = Kr theta + Cr theta' - t0
    n_j = -B_j J_r^{-T}(theta) m   (global torque on body j, the opposite on body i)

Applying the reaction at P_j (not P_i) is what makes the force the gradient of V: d depends on
B_i, and its rotation derivative adds exactly the moment of B_i e about P_i -> P_j.  With the
rotation vector and J_r^{-T}, the torque is the gradient of W; at small angles J_r ~ I and the
torque is Kr theta about the bushing axes, as ADAMS.  Power of the damping: -d'.C d' -
theta'.Cr theta' <= 0.
"""

from __future__ import annotations

import numpy as np

from mbsim import functions
from mbsim.deck.spec import FunctionSpec
from mbsim.errors import DeckError
from mbsim.expr import Expression
from mbsim.forces import register
from mbsim.forces.base import ForceElement
from mbsim.forces.elements import _body_indices
from mbsim.model import joint_frame
from mbsim.rotations import cross, from_matrix, skew

SMALL_ANGLE = 1e-4  # rad: below it J_r^{-1}'s theta~^2 coefficient uses its series (1/12)


def rotation_vector(R: np.ndarray) -> np.ndarray:
    """(3,) axis * angle of the rotation matrix R, angle in [0, pi]."""
    p = from_matrix(R)
    if p[0] < 0:
        p = -p
    s = float(np.linalg.norm(p[1:]))
    if s == 0.0:
        return np.zeros(3)
    return 2.0 * np.arctan2(s, p[0]) / s * p[1:]


def jr_inverse(theta: np.ndarray) -> np.ndarray:
    """(3, 3) J_r^{-1}(theta) = I + theta~/2 + (1/phi^2 - (1 + cos phi)/(2 phi sin phi)) theta~^2
    (the inverse right Jacobian of SO(3); series 1/12 + phi^2/720 below SMALL_ANGLE)."""
    phi = float(np.linalg.norm(theta))
    T = skew(theta)
    if phi < SMALL_ANGLE:
        a = 1.0 / 12.0 + phi**2 / 720.0
    else:
        a = 1.0 / phi**2 - (1.0 + np.cos(phi)) / (2.0 * phi * np.sin(phi))
    return np.eye(3) + 0.5 * T + a * (T @ T)


class Curve:
    """f(x): a component's elastic force (torque) as a function of its deflection; a deck
    function form (table, polynomial, ...) whose argument is the deflection, or a formula in
    ``d``.  ``energy(x)`` = integral of f from 0 to x (quadrature; equilibrium only)."""

    def __init__(self, value, where):
        if isinstance(value, FunctionSpec):
            self._f = functions.from_spec(value)
        elif isinstance(value, Expression):
            extra = sorted(value.names - {"d"})
            if extra:
                raise DeckError(
                    f"a bushing curve is a function of the deflection d; unknown name {extra[0]!r}",
                    where,
                )
            self._f = lambda x, e=value: float(e({"d": float(x)}))
        elif isinstance(value, (int, float)) and not isinstance(value, bool):
            raise DeckError(
                "a curve is a function of the deflection (table, polynomial or a formula in "
                f"d), got the number {value}; a linear component goes in k/kr",
                where,
            )
        else:
            raise DeckError(f"expected a curve, got {type(value).__name__}", where)

    def __call__(self, x: float) -> float:
        return float(self._f(x))

    def energy(self, x: float) -> float:
        from scipy.integrate import quad  # here: scipy.integrate costs ~0.3 s to import

        return float(quad(self, 0.0, x, limit=200)[0])


def _diag(data: dict, key: str, where, n: int = 3) -> np.ndarray:
    v = np.array(data.get(key, np.zeros(n)), dtype=float).reshape(n)
    bad = np.flatnonzero(v < 0)
    if bad.size:
        raise DeckError(
            f"{key} must not be negative, got {v[bad[0]]:g} in component {'xyz'[bad[0]]}",
            where.child(key),
        )
    return v


def _curves(data: dict, key: str, linear: str, where) -> list | None:
    if data.get(key) is None:
        return None
    if np.any(np.asarray(data.get(linear, np.zeros(3))) != 0):
        raise DeckError(f"give either {linear} or {key}, not both", where.child(key))
    return [Curve(v, where.child(key).child(f"[{k}]")) for k, v in enumerate(data[key])]


def _frame(spec, name) -> tuple[np.ndarray, np.ndarray]:
    """(P (3,), C (3, 3) columns f, g, h) of body ``name``'s bushing frame, body coordinates."""
    ps = spec.points.get(name)
    where = spec.where.child("points").child(name)
    if ps is None:
        raise DeckError(f"missing the points of body {name!r}", spec.where.child("points"))
    fr = joint_frame(ps)
    C = np.column_stack([fr["f"], fr["g"], fr["h"]])
    if ps.Q is not None and ps.R is not None:
        u, w = ps.Q - ps.P, ps.R - ps.P
        cos = abs(u @ w) / (np.linalg.norm(u) * np.linalg.norm(w))
        if cos > AXES_ORTHOGONAL:
            raise DeckError(
                f"the bushing axes P->Q and P->R must be orthogonal; they are "
                f"{np.degrees(np.arccos(min(1.0, cos))):.4g} deg from parallel "
                f"(cosine {cos:.3g})",
                where.child("R"),
            )
    P, C = fr["P"].copy(), C
    P.setflags(write=False)
    C.setflags(write=False)
    return P, C


AXES_ORTHOGONAL = 1e-4  # |cos| of P->Q, P->R above which the axes are not orthogonal (0.006 deg;
#   typed 5-digit directions such as 0.70711 stay well below it)


@register
class Bushing(ForceElement):
    type = "bushing"
    description = (
        "six-component bushing between two body frames: K d + C d' and Kr theta + Cr theta' "
        "(rotation vector), preloads, optional curves per component (ADAMS BUSHING)"
    )

    @classmethod
    def from_spec(cls, spec, body_index):
        el = cls()
        d, where = spec.data, spec.where
        el.bi, el.bj = _body_indices(spec, body_index, 2)
        (el.si, el.Ci), (el.sj, el.Cj) = (_frame(spec, n) for n in spec.bodies)
        el.k, el.c = _diag(d, "k", where), _diag(d, "c", where)
        el.kr, el.cr = _diag(d, "kr", where), _diag(d, "cr", where)
        el.f0 = np.array(d.get("preload_force", np.zeros(3)), float).reshape(3)
        el.t0 = np.array(d.get("preload_torque", np.zeros(3)), float).reshape(3)
        el.curves = _curves(d, "force_curves", "k", where)
        el.torque_curves = _curves(d, "torque_curves", "kr", where)
        return el

    def __repr__(self) -> str:
        return f"<bushing {self.name}>"

    def describe(self, model) -> str:
        """One line for ``mbsim info``: the stiffnesses."""

        def fmt(v):
            return "[" + ", ".join(f"{x:.4g}" for x in v) + "]"

        k = "curves" if self.curves is not None else f"{fmt(self.k)} N/m"
        kr = "curves" if self.torque_curves is not None else f"{fmt(self.kr)} N m/rad"
        return f"k = {k}, kr = {kr}"

    # -- measures ----------------------------------------------------------------------------
    def deflections(self, st):
        """(d (3,), theta (3,), Bi, Bj, Pj, Jinv): deflections in frame i, frames, point P_j
        (global) and J_r^{-1}(theta)."""
        Ai, Aj = st.A[self.bi], st.A[self.bj]
        Bi, Bj = Ai @ self.Ci, Aj @ self.Cj
        Pi = st.r[self.bi] + Ai @ self.si
        Pj = st.r[self.bj] + Aj @ self.sj
        theta = rotation_vector(Bi.T @ Bj)
        return Bi.T @ (Pj - Pi), theta, Bi, Bj, Pi, Pj

    def rates(self, st, Bi, Bj, Pi, Pj, theta):
        """(d' (3,), theta' (3,), Jinv (3, 3))."""
        bi, bj = self.bi, self.bj
        wi = st.A[bi] @ st.omega_local[bi]  # global angular velocities
        wj = st.A[bj] @ st.omega_local[bj]
        vi = st.rd[bi] + cross(wi, Pi - st.r[bi])  # velocity of P_i, of P_j
        vj = st.rd[bj] + cross(wj, Pj - st.r[bj])
        dd = Bi.T @ (vj - vi - cross(wi, Pj - Pi))  # d/dt (B_i^T (P_j - P_i))
        Jinv = jr_inverse(theta)
        return dd, Jinv @ (Bj.T @ (wj - wi)), Jinv

    def _elastic(self, d, theta):
        """(3,), (3,): the elastic components K d (or the curves) and Kr theta."""
        fe = self.k * d if self.curves is None else np.array([c(x) for c, x in zip(self.curves, d)])
        if self.torque_curves is None:
            me = self.kr * theta
        else:
            me = np.array([c(x) for c, x in zip(self.torque_curves, theta)])
        return fe, me

    def state(self, st):
        """dict of d, theta, their rates, e (force on j, frame i, sign: -e), m, Bi, Bj, Pj,
        Jinv."""
        d, theta, Bi, Bj, Pi, Pj = self.deflections(st)
        dd, thd, Jinv = self.rates(st, Bi, Bj, Pi, Pj, theta)
        fe, me = self._elastic(d, theta)
        e = fe + self.c * dd - self.f0
        m = me + self.cr * thd - self.t0
        return dict(d=d, theta=theta, dd=dd, thd=thd, e=e, m=m, Bi=Bi, Bj=Bj, Pj=Pj, Jinv=Jinv)

    # -- contract ----------------------------------------------------------------------------
    def apply(self, st, t, F, n_local):
        s = self.state(st)
        bi, bj = self.bi, self.bj
        Fj = -s["Bi"] @ s["e"]  # on body j at P_j; the reaction on body i at P_j
        Tj = -s["Bj"] @ (s["Jinv"].T @ s["m"])
        Pj = s["Pj"]
        F[bj] += Fj
        F[bi] -= Fj
        n_local[bj] += st.A[bj].T @ (cross(Pj - st.r[bj], Fj) + Tj)
        n_local[bi] -= st.A[bi].T @ (cross(Pj - st.r[bi], Fj) + Tj)

    def potential(self, st):
        """V = 1/2 d.K d + 1/2 theta.Kr theta - f0.d - t0.theta (curves: their integrals)."""
        d, theta, *_ = self.deflections(st)
        if self.curves is None:
            V = 0.5 * float(d @ (self.k * d))
        else:
            V = sum(c.energy(x) for c, x in zip(self.curves, d))
        if self.torque_curves is None:
            V += 0.5 * float(theta @ (self.kr * theta))
        else:
            V += sum(c.energy(x) for c, x in zip(self.torque_curves, theta))
        return V - float(self.f0 @ d) - float(self.t0 @ theta)

    def channels(self, st, t):
        s = self.state(st)
        fe, me = self._elastic(s["d"], s["theta"])
        return {
            "deflection": (s["d"], "m"),
            "angle": (s["theta"], "rad"),
            "velocity": (s["dd"], "m/s"),
            "rate": (s["thd"], "rad/s"),
            "force": (-s["e"], "N"),  # on body j, frame i
            "torque": (-(s["Jinv"].T @ s["m"]), "N m"),  # on body j, frame j
            "energy": (self.potential(st), "J"),
        }
