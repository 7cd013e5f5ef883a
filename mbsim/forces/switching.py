"""Switching force laws: a ``force`` or ``torque`` whose expression law has ``where(...)``
conditions on the sign of a velocity-type measure (``velocity``, ``angular_velocity``),
made well-posed at zero velocity as a hybrid element (contract: :mod:`mbsim.events`).

The compressor's valve law ``where(v < 0, F(y), 0)`` is the example: the air pushes the
piston only while it moves toward A.  Evaluated as a plain formula, the law jumps where v
changes sign; where both sides drive v back to 0 (the rotor stalls with the air force on)
the motion is a sliding mode that no integrator can step across.  Here:

- **Modes.** Every condition ``m < 0``, ``m <= 0``, ``m > 0``, ``m >= 0`` (or ``0 > m``...)
  on the element's velocity measure m is replaced by its truth value on one *side*
  (:class:`Side`: m < 0 or m > 0), fixed during a step: inside a step the law is smooth,
  and the side changes at an event (the switch: m crossing 0 by half the surface's band,
  V_ZERO, located on the dense output).
- **Filippov at m = 0** (Filippov 1988, Ch. 2, Sec. 4): at a crossing the new side is
  chosen from the accelerations of m with the element on either side (``ctx.trial``):
  a_neg (side m < 0) and a_pos (side m > 0).  a_neg < 0 or a_pos > 0 alone: the motion
  goes on to that side (a crossing, or a return).  a_neg >= 0 and a_pos <= 0: both sides
  drive m back to 0, the sliding mode: the element *holds* m at 0 (:class:`Hold`, a
  constraint row on the coordinate whose rate m is: :meth:`SwitchingLaw.hold_row`), with
  the force of Filippov's convex combination
  F = (1 - alpha) F_neg + alpha F_pos, alpha = a_neg / (a_neg - a_pos) in [0, 1]
  (the value that makes dm/dt = 0).  alpha is watched (switches ``alpha < 0`` and
  ``alpha > 1``, from the same two one-sided accelerations at the current state); when it
  leaves [0, 1] the hold ends at that event, to the side whose acceleration then drives m
  away from 0.
- **Several elements at once** (the compressor's six pistons at the stall: v_k = c_k(theta)
  omega all reach 0 together): elements at m = 0 whose velocity rows are dependent on one
  another's together with the mechanism's constraints (the pistons of a 1-DOF mechanism)
  have *one* switching surface, m_lead = 0, with m_k = beta_k m_lead on it.  They form a
  group with one lead (the first element whose law jumps there): one hold row (the
  lead's; a row per member would be redundant), one alpha, and the sides of the members
  oriented by the sign of beta_k (Filippov's convex combination of the two side fields of
  the one surface).  Dependence is decided from the null space of the extended Jacobian
  [Phi_q; J_lead] (SVD, relative tolerance RANK_TOL).  Groups on independent surfaces
  are decided one after another, each with the others' modes unchanged (the general
  multi-surface case is a complementarity problem; not solved here).

While an element holds, its load is F_neg + alpha0 (F_pos - F_neg) with alpha0 the value
at the start of the hold, and the hold row's multiplier carries the rest: the motion is
exact (the row holds m at 0 to round-off).  ``forces/<name>/force`` (``torque``) reports
that load; the lead adds its row's force where it can tell its row among the multipliers
(the compiled model bound by :meth:`SwitchingLaw.bind` and every element's mode passed to
``channels_in``), so that it is the whole holding force; else it is exact while the loads
on the mechanism do not change during the hold (the compressor's stall) and otherwise
leaves out what the row carries.  Channel ``forces/<name>/side``: -1, +1 (the side), 0
while it holds.

A hold needs the measure's coordinate as a constraint row: a ``velocity`` measure along a
global x, y or z axis (``absolute`` row), or an ``angular_velocity`` about a global axis
(``angle`` row against a ground body; exact while the body turns about that axis, as on a
revolute joint).  Other measures (body-frame axes, oblique velocities) still switch at
located events; a sliding mode on them ends the run (incomplete, naming the element).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from mbsim import core
from mbsim.errors import DeckError
from mbsim.events import HoldRow, Switch, extend_model
from mbsim.expr import Apply, Expression, Name, Num
from mbsim.fast.dynamics import SolveError
from mbsim.forces.elements import PointForce, Torque
from mbsim.forces.laws import Law
from mbsim.forces.measures import AngularVelocity, Velocity
from mbsim.rotations import skew

V_ZERO = 1e-9
"""An element is at its switching surface when |m| <= V_ZERO x max(1, max |qd|) (m/s or
rad/s): an event is located to 1e-12 s, so m there is off 0 by |dm/dt| x 1e-12 (1e-9 up
to accelerations of 1e3 m/s^2) plus the run's round-off."""
V_GROUP = 1e-4
"""A group's members (elements whose velocity is beta x the lead's on the mechanism) must
be at rest to |m| <= V_GROUP x max(1, max |qd|): the velocity drift of the methods that do
not project (baumgarte at rtol 1e-6: 4e-7 m/s at the compressor's stall), not the motion
a driver gives them."""
RANK_TOL = 1e-9
"""Relative singular-value tolerance of the extended Jacobian [Phi_q; J_lead] (as the
rank of Phi_q in :func:`mbsim.analyses.common.rank_and_redundant`)."""

_CMP = {"<": lambda s: s < 0, "<=": lambda s: s <= 0, ">": lambda s: s > 0,
        ">=": lambda s: s >= 0}
_FLIP = {"<": ">", "<=": ">=", ">": "<", ">=": "<="}


# -- modes ---------------------------------------------------------------------------------
@dataclass(frozen=True)
class Side:
    """The element on one side of its surface: sign -1 (m < 0) or +1 (m > 0)."""

    sign: int
    measure: str = "v"

    def __str__(self):
        return f"{self.measure} {'<' if self.sign < 0 else '>'} 0"


@dataclass(frozen=True)
class Hold:
    """A group of elements held on their common surface m_lead = 0 (module doc): ``lead``
    (the element with the hold row), ``members`` ((name, sigma), ...) with sigma = sign of
    dm_k/dm_lead, ``alpha0`` the convex weight of the positive side at the hold's start."""

    lead: str
    members: tuple
    alpha0: float

    def sigma(self, name) -> int:
        return dict(self.members)[name]

    def __str__(self):
        return f"hold (lead {self.lead}, alpha {self.alpha0:.4g})"


# -- the law with its conditions as mode inputs ----------------------------------------------
def _replace_conditions(node, velocity: set, found: list):
    """The tree with every condition ``m op 0`` (m in ``velocity``) of a where replaced by a
    placeholder name; ``found`` collects (placeholder, measure, op)."""
    if not isinstance(node, Apply):
        return node
    args = [_replace_conditions(a, velocity, found) for a in node.args]
    if node.op == "where":
        c = node.args[0]
        if isinstance(c, Apply) and c.op in _CMP:
            a, b = c.args
            hit = None
            if isinstance(a, Name) and a.id in velocity and isinstance(b, Num) and b.value == 0:
                hit = (a.id, c.op)
            elif isinstance(b, Name) and b.id in velocity and isinstance(a, Num) and a.value == 0:
                hit = (b.id, _FLIP[c.op])
            if hit is not None:
                ph = f"_side{len(found)}"
                found.append((ph, *hit))
                args[0] = Name(ph)
    return Apply(node.op, tuple(args))


def _sided(law: Law, velocity: set):
    """(law with placeholders, [(placeholder, measure, op)]) or (law, []) when it has no
    such condition."""
    if law is None or law.kind != "expression":
        return law, []
    found: list = []
    node = _replace_conditions(law._expr._node, velocity, found)
    if not found:
        return law, []
    expr = Expression(node)
    used = tuple((n, m) for n, m in law.measures)
    return Law("expression", law.text, expr=expr, measures=used, own=law.own), found


def make_switching(el, where=None):
    """``el`` (a compiled force or torque) as a switching element when its law has
    conditions on the sign of a velocity measure; else ``el`` itself."""
    laws = el.laws if el.laws is not None else ([el.scaled[0]] if el.scaled else [])
    measures = {n: m for law in laws for n, m in law.measures}
    velocity = {n for n, m in measures.items() if isinstance(m, (Velocity, AngularVelocity))}
    if not velocity:
        return el
    sided = [_sided(law, velocity) for law in laws]
    conds = [c for _, found in sided for c in found]
    if not conds:
        return el
    names = sorted({c[1] for c in conds})
    if len(names) > 1:
        raise DeckError(f"a switching law tests the sign of one velocity measure; this one "
                        f"tests {', '.join(names)}", where)
    cls = SWITCHING[type(el)]
    out = cls.__new__(cls)
    out.__dict__.update(el.__dict__)
    out.mname = names[0]
    out.measure = measures[names[0]]
    out.conds = tuple(conds)
    if el.laws is not None:
        out.sided_laws = [s for s, _ in sided]
    else:
        out.sided_laws = [sided[0][0]]
    return out


class SwitchingLaw:
    """Mixin of the switching force and torque (contract of a hybrid element:
    :mod:`mbsim.events`)."""

    hybrid = True
    reactions = False
    mname = "v"
    measure = None
    conds: tuple = ()
    sided_laws: list = []

    # -- loads ---------------------------------------------------------------------------
    def vector_on_side(self, sign, st, t) -> np.ndarray:
        """(3,) the vector with every condition at its truth value on side ``sign``."""
        own = {ph: 1.0 if _CMP[op](sign) else 0.0 for ph, _, op in self.conds}
        if self.laws is not None:
            return np.array([law(st, t, own) for law in self.sided_laws])
        return self.sided_laws[0](st, t, own) * self.scaled[1]

    def vector_in(self, mode, st, t) -> np.ndarray:
        if isinstance(mode, Side):
            return self.vector_on_side(mode.sign, st, t)
        if isinstance(mode, Hold):
            s = mode.sigma(self.name)
            f_neg, f_pos = self.vector_on_side(-s, st, t), self.vector_on_side(s, st, t)
            return f_neg + mode.alpha0 * (f_pos - f_neg)
        return self.vector(st, t)  # no mode (outside a run): the plain formula

    def apply_in(self, mode, st, t, lam, F, n_local):
        self.add_vector(st, self.vector_in(mode, st, t), F, n_local)

    def jumps(self, st, t) -> bool:
        """Whether the law differs between the two sides at (st, t)."""
        return bool(np.any(self.vector_on_side(-1, st, t) != self.vector_on_side(1, st, t)))

    def channels_in(self, mode, st, t, lam, modes=None):
        out = self.channels_from(st, t, self.vector_in(mode, st, t))
        side = mode.sign if isinstance(mode, Side) else 0.0
        if mode is None:
            side = float(np.sign(self.measure.value(st, t)))
        out["side"] = (float(side), "")
        return out

    # -- the measure ---------------------------------------------------------------------
    def gradient(self, st, nq) -> np.ndarray:
        """J (nq,): m = J qd (the measure is linear in the velocities)."""
        m, J = self.measure, np.zeros(nq)
        b = m.b
        G, A = st.G[b], st.A[b]
        if isinstance(m, Velocity):  # m = u.(rd - A s'~ 2 G pd)
            u = m.axis(st)
            J[7 * b : 7 * b + 3] = u
            J[7 * b + 3 : 7 * b + 7] = -2.0 * G.T @ (m.S.T @ (A.T @ u))
        elif m.local:  # u'. 2 G pd
            J[7 * b + 3 : 7 * b + 7] = 2.0 * G.T @ m.u
        else:  # u . A 2 G pd
            J[7 * b + 3 : 7 * b + 7] = 2.0 * G.T @ (A.T @ m.u)
        return J

    def rate(self, ctx, qdd) -> float:
        """dm/dt at ctx with the accelerations qdd (nq,) (Haug Ch. 6: d(2 G pd)/dt =
        2 G pdd, since G' pd = 0)."""
        m, st = self.measure, ctx.state
        sa = core.State(ctx.model, ctx.q, qdd)  # rd -> rdd, omega_local -> omega_local'
        b = m.b
        A, w, wd = st.A[b], st.omega_local[b], sa.omega_local[b]
        if isinstance(m, Velocity):
            vp = st.rd[b] - A @ (m.S @ w)
            ap = sa.rd[b] - A @ (m.S @ wd) - A @ (skew(w) @ (m.S @ w))
            out = m.axis(st) @ ap
            if m.local:
                out += (A @ (skew(w) @ m.u)) @ vp
            return float(out)
        if m.local:
            return float(m.u @ wd)
        return float(m.u @ (A @ wd))

    def hold_row(self, ctx):
        """The HoldRow that holds the measure at 0, or None when it cannot: a ``velocity``
        along a global x, y or z axis holds that coordinate of its point (``absolute``,
        target = its value at ctx); an ``angular_velocity`` about a global axis u holds the
        body's rotation about u against a ground body (``angle`` from g to g_j about
        f = u, g_j the body-fixed copy of g at ctx, target 0: d(angle)/dt = u . w there,
        exact while the body turns about u, as on a revolute joint)."""
        m, st = self.measure, ctx.state
        if m.local:
            return None
        if isinstance(m, Velocity):
            axis = int(np.argmax(np.abs(m.u)))
            if abs(abs(m.u[axis]) - 1.0) > 1e-15:
                return None
            target = float(st.r[m.b, axis] + (st.A[m.b] @ m.s)[axis])
            return HoldRow("absolute", {"s": "P_i"},
                           {"P_i": np.array(m.s, float), "axis": axis},
                           m.b, -1, target, self.name, f"{self.name} hold")
        grounds = np.flatnonzero(ctx.model.is_ground)
        if grounds.size == 0:
            return None
        g0 = int(grounds[0])
        u = m.u / np.linalg.norm(m.u)
        g = np.cross(u, np.eye(3)[int(np.argmin(np.abs(u)))])
        g /= np.linalg.norm(g)
        h = np.cross(u, g)  # g x h = u
        A0, Ab = st.A[g0], st.A[m.b]
        frames = {"f_i": A0.T @ u, "g_i": A0.T @ g, "h_i": A0.T @ h, "g_j": Ab.T @ g}
        return HoldRow("angle", {"gi": "g_i", "hi": "h_i", "gj": "g_j"}, frames, g0, m.b,
                       0.0, self.name, f"{self.name} hold")

    # -- the hybrid contract ---------------------------------------------------------------
    def initial_mode(self, ctx):
        v = self.measure.value(ctx.state, ctx.t)
        if abs(v) > _v_zero(ctx):
            return Side(1 if v > 0 else -1, self.mname)
        return plan(ctx).get(self.name, Side(1, self.mname))

    model = None  # the compiled model, where the compiler binds it (bind)

    def bind(self, model):
        """Keep the compiled model: it says which held rows of ``lam`` are this element's."""
        self.model = model

    def held_multiplier(self, lam, modes):
        """The multiplier of this element's hold row in ``lam`` (the model's rows, then the
        held rows: ``hold_count`` per hybrid element in the order of the model's forces),
        given every hybrid element's mode ``modes``; None when that is not known."""
        if self.model is None or lam is None or modes is None:
            return None
        row = self.model.m
        for f in self.model.forces:
            if not getattr(f, "hybrid", False):
                continue
            if not hasattr(f, "hold_count"):
                return None
            k = f.hold_count(modes.get(f.name))
            if f is self:
                return float(lam[row]) if k and len(lam) > row else None
            row += k
        return None

    def hold_count(self, mode) -> int:
        return 1 if isinstance(mode, Hold) and mode.lead == self.name else 0

    def describe(self, model) -> str:
        return (f"switches on the sign of {self.mname} (located events; Filippov hold at "
                f"{self.mname} = 0)")

    def holds(self, mode, ctx):
        if isinstance(mode, Hold) and mode.lead == self.name:
            return [self.hold_row(ctx)]
        return []

    def switches(self, mode):
        if isinstance(mode, Hold):
            return [Switch("alpha < 0", -1, lambda ctx, m=mode: _alpha(ctx, m), self.name),
                    Switch("alpha > 1", -1, lambda ctx, m=mode: 1.0 - _alpha(ctx, m),
                           self.name)]
        if isinstance(mode, Side):
            # the side ends where m is half the surface's band |m| <= V_ZERO x max(1, max
            # |qd|) (_v_zero) past 0: an element at rest on its surface (m = 0 exactly
            # under the projection methods) carries the velocity noise of the index-3
            # methods (+-1e-13 m/s on the compressor's pistons under genalpha), which
            # crossed m = 0 at every step and ended the run in events piling up at t_end.
            # Half the band: the event's state is then inside it, where the decision at the
            # surface (plan) takes it as on the surface.  A real crossing is located
            # V_ZERO / (2 |dm/dt|) later (5e-13 s at 1e3 m/s^2).
            return [Switch(f"{self.mname} = 0", -mode.sign,
                           lambda ctx, s=mode.sign: self._value(ctx) + 0.5 * s * _v_zero(ctx),
                           self.name)]
        return [Switch(f"{self.mname} = 0", 0, self._value, self.name)]

    def _value(self, ctx):
        return self.measure.value(ctx.state, ctx.t)

    def joins(self, mode, ctx):
        """The mode this element takes at an event where its own switch did not fire but
        the switching elements that did put it in their plan (the members of a group whose
        roots the dense output placed a round-off apart); None: no change."""
        memo = ctx.__dict__.get("_switching_plan")
        new = None if memo is None else memo.get(self.name)
        return None if new is None or new == mode else new

    def next_mode(self, mode, switch, ctx):
        new = plan(ctx).get(self.name)
        # a hold ends where alpha reaches 0 or 1; located to EVENT_TIME_TOL, the test there
        # may still find the hold (alpha at its bound): the side alpha leaves to decides
        if new is not None and not (isinstance(mode, Hold) and isinstance(new, Hold)):
            return new
        if isinstance(mode, Hold):  # left its surface: the side alpha left to
            s = mode.sigma(self.name) * (-1 if switch.name == "alpha < 0" else 1)
            return Side(s, self.mname)
        return Side(-mode.sign if isinstance(mode, Side) else 1, self.mname)


# -- the decision at a surface -----------------------------------------------------------
def _v_zero(ctx) -> float:
    return V_ZERO * max(1.0, float(np.abs(ctx.qd).max(initial=0.0)))


def _members_of(system):
    return [el for el in system.hybrid if isinstance(el, SwitchingLaw)]


def _one_sided(ctx, lead, members, sign):
    """dm_lead/dt with the members on the side where m_lead has ``sign``."""
    modes = {name: Side(sign * s, el.mname) for (name, s), el in members}
    qdd, _, _ = ctx.trial(modes)
    return lead.rate(ctx, qdd)


def _alpha(ctx, mode: Hold) -> float:
    """Filippov's alpha of the held group ``mode`` at ctx: a_neg / (a_neg - a_pos), from
    the one-sided accelerations of the lead's measure (memo on ctx: every member's
    switches ask for the same value)."""
    memo = ctx.__dict__.setdefault("_switching_alpha", {})
    if mode.lead in memo:
        return memo[mode.lead]
    els = {el.name: el for el in _members_of(ctx.system)}
    members = [((n, s), els[n]) for n, s in mode.members]
    lead = els[mode.lead]
    a_neg = _one_sided(ctx, lead, members, -1)
    a_pos = _one_sided(ctx, lead, members, 1)
    den = a_neg - a_pos
    if den > 0:
        alpha = a_neg / den
    else:  # not attracting: the side that drives away (a_neg < 0: negative side)
        alpha = -1.0 if a_neg < 0 else 2.0
    memo[mode.lead] = alpha
    return alpha


def _jacobian_without(ctx, names):
    """Phi_q (dense) of the run's model with the hold rows of elements other than
    ``names``."""
    from mbsim.analyses.diagnosis import jacobian

    family = ctx.system.family
    holds = [h for h in family.holds if h.owner not in names]
    J = jacobian(extend_model(family.model, holds), ctx.q, ctx.t)
    return J if isinstance(J, np.ndarray) else J.toarray()


def plan(ctx) -> dict:
    """{name: mode} for the switching elements at their surface at ctx (module doc): the
    groups on a common surface, each crossing, returning or held; memo on ctx (every
    element that fires at one event asks for the same plan)."""
    memo = ctx.__dict__.get("_switching_plan")
    if memo is not None:
        return memo
    st, t = ctx.state, ctx.t
    vz = _v_zero(ctx)
    els = _members_of(ctx.system)
    v = {el.name: el.measure.value(st, t) for el in els}
    at = [el for el in els if abs(v[el.name]) <= vz]
    out: dict = {}
    if at:
        nq = ctx.model.nq
        grads = {el.name: el.gradient(st, nq) for el in els}
        base = _jacobian_without(ctx, {el.name for el in els})
        s = np.linalg.svd(base, compute_uv=False)
        rank_base = int(np.sum(s > RANK_TOL * s[0])) if s.size else 0
        # members: the elements whose velocity the lead's fixes on the mechanism, at rest
        # to the velocity drift of the methods that do not project (V_GROUP)
        vg = V_GROUP * max(1.0, float(np.abs(ctx.qd).max(initial=0.0)))
        free = [el for el in els if abs(v[el.name]) <= vg]
        for lead in at:
            if lead not in free or not lead.jumps(st, t):
                continue
            members = _group(base, rank_base, grads, lead, free)
            out.update(_decide(ctx, lead, members))
            done = {el.name for _, el in members}
            free = [el for el in free if el.name not in done]
        rest = [el for el in at if el.name not in out]
        if rest:  # no jump in their laws: the side their measure moves to
            qdd, _ = ctx.accelerations()
            for el in rest:
                a = el.rate(ctx, qdd)
                old = ctx.system.modes.get(el.name)
                sign = 1 if a > 0 else -1 if a < 0 else (old.sign if isinstance(old, Side) else 1)
                out[el.name] = Side(sign, el.mname)
    ctx.__dict__["_switching_plan"] = out
    return out


def _group(base, rank_base, grads, lead, candidates):
    """[((name, sigma), el)]: the candidates whose measure is beta x the lead's on the
    mechanism (their gradient in the row space of [Phi_q; J_lead]), sigma = sign(beta);
    the lead alone when its measure is not a direction of its own (rank of [Phi_q;
    J_lead] = rank of Phi_q: a dead centre)."""
    A = np.vstack([base, grads[lead.name]])
    _, s, Vt = np.linalg.svd(A)
    rank = int(np.sum(s > RANK_TOL * s[0]))
    if rank <= rank_base:
        return [((lead.name, 1), lead)]
    null = Vt[rank:]
    e = np.zeros(A.shape[0])
    e[-1] = 1.0
    w = np.linalg.lstsq(A, e, rcond=RANK_TOL)[0]  # a velocity with m_lead = 1
    out = []
    for el in candidates:
        g = grads[el.name]
        scale = float(np.linalg.norm(g))
        if scale == 0.0 or np.linalg.norm(null @ g) > 1e-8 * scale:
            continue
        beta = float(g @ w)
        if el is lead or abs(beta) > 1e-9 * scale * float(np.linalg.norm(w)):
            out.append(((el.name, 1 if el is lead else int(np.sign(beta))), el))
    return out


def _decide(ctx, lead, members) -> dict:
    """The modes of a group at its surface (module doc: Filippov's test)."""
    a_neg = _one_sided(ctx, lead, members, -1)
    a_pos = _one_sided(ctx, lead, members, 1)
    neg_ok, pos_ok = a_neg < 0, a_pos > 0
    if neg_ok and pos_ok:  # repulsive: on across the surface, away from where it came
        old = ctx.system.modes.get(lead.name)
        sign = -old.sign if isinstance(old, Side) else (-1 if -a_neg > a_pos else 1)
    elif neg_ok or pos_ok:
        sign = -1 if neg_ok else 1
    else:  # both sides drive m_lead back to 0: the sliding mode
        if lead.hold_row(ctx) is None:
            raise SolveError(f"{lead.name}: its law holds {lead.mname} at 0 (a sliding "
                             f"mode), which needs a velocity measure along a global x, y "
                             f"or z axis or an angular velocity about a global axis with a "
                             f"ground body")
        den = a_neg - a_pos
        alpha = min(max(a_neg / den, 0.0), 1.0) if den > 0 else 0.0
        mode = Hold(lead.name, tuple(m for m, _ in members), float(alpha))
        return {name: mode for (name, _), _ in members}
    return {name: Side(sign * s, el.mname) for (name, s), el in members}


# the hybrid forms of the vector loads (they keep their deck types, force and torque)
class SwitchingForce(SwitchingLaw, PointForce):
    """A ``force`` whose law switches on the sign of a velocity (module doc)."""

    def channels_from(self, st, t, v):
        return {"force": (st.A[self.b] @ v if self.local else np.array(v), "N")}

    def channels_in(self, mode, st, t, lam, modes=None):
        """As :meth:`SwitchingLaw.channels_in`; the lead of a hold adds its row's force,
        -lam e_axis at the point (Phi = coordinate - target, M qdd + Phi_q^T lam = Q), so
        that ``force`` is the whole force that holds v at 0, where the row is known."""
        out = super().channels_in(mode, st, t, lam, modes)
        if (isinstance(mode, Hold) and mode.lead == self.name
                and isinstance(self.measure, Velocity)):
            lam_h = self.held_multiplier(lam, modes)
            if lam_h is not None:
                axis = int(np.argmax(np.abs(self.measure.u)))
                out["force"][0][axis] -= lam_h
        return out


class SwitchingTorque(SwitchingLaw, Torque):
    """A ``torque`` whose law switches on the sign of a velocity (module doc)."""

    def channels_from(self, st, t, v):
        return {"torque": (np.array(self.torque_global(st, t, v)), "N m")}

    def channels_in(self, mode, st, t, lam, modes=None):
        """As :meth:`SwitchingLaw.channels_in`; the lead of a hold on an angular velocity
        adds its row's torque on the body, -lam u (the angle row's gradient is u there)."""
        out = super().channels_in(mode, st, t, lam, modes)
        if (isinstance(mode, Hold) and mode.lead == self.name
                and isinstance(self.measure, AngularVelocity)):
            lam_h = self.held_multiplier(lam, modes)
            if lam_h is not None:
                out["torque"][0][:] -= lam_h * self.measure.u / np.linalg.norm(self.measure.u)
        return out


SWITCHING = {PointForce: SwitchingForce, Torque: SwitchingTorque}
"""A vector-load class -> its switching form."""
