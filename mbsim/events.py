"""Events: conditions located in time on the integrator's dense output, and the modes of
hybrid force elements (stick-slip friction, switching laws) that change at them.

An *event function* (:class:`Switch`) is a scalar g(t, q, qd) whose zero crossing in a given
direction is an event.  Two kinds of owners:

- the deck's ``events:`` (:class:`UserEvent`): a condition on measures and body channels,
  ``when: 'v < 0'``; its action ``stop`` ends the run there, ``record`` notes it;
- *hybrid* force elements (``hybrid = True``, contract below): their law depends on a
  discrete mode (a friction joint sticks or slips in one direction; a valve law is on or
  off), fixed during a step, so that the equations of motion are smooth inside every step;
  the element's switches say when the mode must change, and the element chooses the new
  mode at the event (:meth:`next_mode`).

After every accepted step the driver (:func:`mbsim.analyses.trajectory.integrate`) evaluates
the armed switches at the step's end; a sign change in a switch's direction is located on
the step's dense output (:func:`locate`, the Illinois method) to
``EVENT_TIME_TOL x max(1, |t|)``; the earliest event in the step wins, the outputs before it
are taken from the step, and the integration restarts at the event's state with the new
modes (and the constraint rows they hold).  The event time then carries the run's own error:
|dt| ~ |error of g| / |dg/dt|, so the run's rtol decides how exactly an event is placed (the
tests compare with closed forms at rtol 1e-10).

Contract of a hybrid force element (besides :class:`mbsim.forces.base.ForceElement`):

1. ``hybrid = True``; ``reactions``: True when its loads depend on the constraint
   multipliers (a friction whose normal force is the joint's reaction): the equations of
   motion then solve the loop loads <-> multipliers by fixed-point iteration
   (:meth:`mbsim.fast.dynamics.System.accelerations`), in Python steps.
2. ``initial_mode(ctx) -> mode`` (hashable): the mode at t_start (ctx: :class:`Context`).
3. ``apply_in(mode, st, t, lam, F, n_local)``: add the loads in ``mode`` (as ``apply``);
   ``lam``: (m,) multipliers on all rows of the system's model (None: not yet known; an
   element then uses its preload or zero).
4. ``holds(mode, ctx) -> [HoldRow]``: constraint rows the mode adds (a stick holds the
   joint's relative coordinate at its value when the stick began); [] for none.
5. ``switches(mode) -> [Switch]``: the event functions watched in ``mode``.
6. ``next_mode(mode, switch, ctx) -> mode``: the mode after ``switch`` fired at ``ctx``
   (may test a candidate with ``ctx.trial``).
7. ``channels_in(mode, st, t, lam, modes) -> dict``: optional channels (as ``channels``);
   ``lam``: the multipliers on the model's rows followed by the held rows, ``modes``: every
   hybrid element's mode there (which held rows are whose: ``hold_count(mode)`` rows each,
   in the order of the model's forces).
8. ``hold_count(mode) -> int``: the number of rows ``holds`` gives in ``mode``.
9. ``step_limit(mode, ctx) -> float``: optional, the longest next step from the state ctx
   (inf: none), e.g. so that a contact cannot be stepped through unseen; applied by the
   driver before every step (:meth:`Watch.step_limit`).
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field, replace
from typing import Any, Callable

import numpy as np

from mbsim.errors import DeckError, ExpressionError, Where

EVENT_TIME_TOL = 1e-12
"""An event's time is the root of its function on the step's dense output to within this x
max(1, |t|) seconds (the interpolant's own root; the solution's error adds to it)."""
MAX_EVENTS = 100000  # events in one run (a chattering law ends the run, named, not a hang)
MAX_EVENTS_AT_ONE_TIME = 50  # mode changes without the time moving: a Zeno point or a loop


# -- event functions -----------------------------------------------------------------------
@dataclass(frozen=True)
class Switch:
    """An event function: ``value(ctx) -> float``; fires when it crosses zero in
    ``direction`` (+1: from < 0 to >= 0, -1: from > 0 to <= 0, 0: either)."""

    name: str
    direction: int
    value: Callable[["Context"], float]
    owner: str = ""  # the element or event name
    action: str = "switch"  # 'switch' (a hybrid element's) | 'stop' | 'record'
    hysteresis: float = 0.0
    probe: int = 0  # interior points of each step also looked at (a brief crossing)


class Context:
    """The state at one time, with what event functions and mode choices need, computed
    on demand: ``t``, ``q``, ``qd``; ``system``: the equations of motion in the current
    modes; ``accelerations()``: (qdd, lam (m,) on all rows of ``system.model``)."""

    def __init__(self, system, t, q, qd):
        self.system, self.t, self.q, self.qd = system, float(t), q, qd
        self._acc = None
        self._state = None

    @property
    def model(self):
        return self.system.model

    @property
    def state(self):
        if self._state is None:
            from mbsim import core

            self._state = core.State(self.system.model, self.q, self.qd)
        return self._state

    def accelerations(self):
        if self._acc is None:
            qdd, lam, _ = self.system.accelerations(self.q, self.qd, self.t)
            self._acc = (qdd, self.system.full_lam(lam))
        return self._acc

    def trial(self, modes):
        """(qdd, lam on all rows of the trial model, trial system) with the elements in
        ``modes`` (name -> mode; the others keep theirs): a mode candidate tested at this
        state without changing the run."""
        system = self.system.family.system_for({**self.system.modes, **modes}, self)
        qdd, lam, _ = system.accelerations(self.q, self.qd, self.t)
        return qdd, system.full_lam(lam), system


def locate(g, ta, tb, ga, gb, tol):
    """The root of g on [ta, tb] with g(ta) ga, g(tb) gb of opposite signs (gb may be 0):
    the Illinois method (regula falsi that halves the value kept at an end which stays
    twice in a row), which keeps a bracket and converges superlinearly.  Returns t with
    |t - root| <= tol (the bracket's width) or an exact zero."""
    if gb == 0.0:
        return tb
    side = 0  # which end moved last: -1 the right one, +1 the left one
    for _ in range(200):
        if tb - ta <= tol:
            break
        t = (ta * gb - tb * ga) / (gb - ga)
        t = min(max(t, ta + 0.25 * tol), tb - 0.25 * tol)
        gt = g(t)
        if gt == 0.0:
            return t
        if (gt > 0) == (gb > 0):  # the root lies in [ta, t]
            tb, gb = t, gt
            if side == -1:
                ga *= 0.5
            side = -1
        else:  # in [t, tb]
            ta, ga = t, gt
            if side == 1:
                gb *= 0.5
            side = 1
    return tb


def crossed(direction, g0, g1) -> bool:
    """Whether a switch with ``direction`` fires between the values g0 (start, armed) and
    g1 (end) of a step."""
    if direction >= 0 and g0 < 0.0 <= g1:
        return True
    if direction <= 0 and g0 > 0.0 >= g1:
        return True
    return False


class Hybrid:
    """Defaults of the hybrid contract (module doc) for an element that needs fewer parts:
    no held rows, channels as without modes, modes shown by str()."""

    hybrid = True
    reactions = False

    def holds(self, mode, ctx):
        return []

    def channels_in(self, mode, st, t, lam, modes=None):
        return self.channels(st, t)

    def hold_count(self, mode) -> int:
        return 0

    def step_limit(self, mode, ctx) -> float:
        return math.inf

    @staticmethod
    def mode_text(mode) -> str:
        return str(mode)


# -- hold rows: constraints a mode adds ---------------------------------------------------
@dataclass(frozen=True)
class HoldRow:
    """One constraint row that a mode adds (a joint stuck by friction): a kernel of
    :mod:`mbsim.constraints.blocks` (``kernel``, its ``args`` naming entries of ``frames``,
    as the joint types' rows), between bodies ``bi`` and ``bj`` (-1: ground/one body),
    Phi = measure - ``target``.  ``owner``: the element's name, ``label``: the row's."""

    kernel: str
    args: dict
    frames: dict
    bi: int
    bj: int
    target: float
    owner: str
    label: str


def extend_model(model, holds):
    """The model with ``holds`` (HoldRow list) appended as constraint rows m, m + 1, ...
    (items of kind 'hold', one per owner); the model itself when there are none.  The
    base model stays as compiled: every other analysis sees no hold rows."""
    if not holds:
        return model
    from mbsim.model import Item, _Rows

    rows = _Rows()
    rows.m = model.m
    items = list(model.items)
    owners: dict[str, list] = {}
    item_no = {o: len(items) + k for k, o in enumerate(dict.fromkeys(h.owner for h in holds))}
    for h in holds:
        args = dict(h.args)
        if h.kernel == "absolute":
            args["axis"] = "axis"
        r = rows.add(h.kernel, args, dict(h.frames), h.bi, h.bj, h.target, None, False,
                     item_no[h.owner], h.label)
        owners.setdefault(h.owner, []).append((r, h))
    for name, rs in owners.items():
        r = np.concatenate([x[0] for x in rs])
        r.setflags(write=False)
        h = rs[0][1]
        fr = h.frames
        Ci = np.column_stack([fr.get("f_i", np.eye(3)[0]), fr.get("g_i", np.eye(3)[1]),
                              fr.get("h_i", np.eye(3)[2])])
        items.append(Item(f"hold:{name}", "hold", "hold", r, h.bi, h.bj,
                          np.asarray(fr.get("P_i", np.zeros(3))), fr.get("P_j"), Ci, None))
    blocks = model.blocks + rows.blocks(model.nq)
    row_item = np.concatenate([model.row_item, np.array(rows.owner, dtype=int)])
    row_item.setflags(write=False)
    return replace(model, m=rows.m, blocks=blocks, items=tuple(items), row_item=row_item,
                   row_label=model.row_label + tuple(rows.labels))


# -- the deck's events ---------------------------------------------------------------------
ACTIONS = ("stop", "record")
DIRECTIONS = {"rising": 1, "falling": -1, "both": 0}
_CMP = re.compile(r"(<=|>=|<|>)")
_CHANNEL = re.compile(r"(?<![\w.])[A-Za-z_][A-Za-z0-9_]*\.[A-Za-z_]\w*")
BODY_CHANNELS = ("x", "y", "z", "vx", "vy", "vz", "wx", "wy", "wz")
"""``<body>.<c>`` names an event condition may use besides its measures: the centroid's
global position (m) and velocity (m/s) and the global angular velocity (rad/s)."""


@dataclass
class EventSpec:
    """An event as the deck gives it (validated by :func:`read_events`)."""

    name: str
    when: str
    direction: str | None = None
    hysteresis: float = 0.0
    action: str = "record"
    measures: dict = field(default_factory=dict)
    where: Where = field(default_factory=Where)


class UserEvent:
    """A compiled deck event: g = lhs - rhs of its condition, watched in the direction in
    which the condition becomes true (``a < b``: g falling through 0), or as given."""

    def __init__(self, spec: EventSpec, body_index: dict):
        from mbsim.expr import parse_expression
        from mbsim.forces.measures import compile_measures

        self.name, self.action, self.hysteresis = spec.name, spec.action, spec.hysteresis
        where = spec.where.child("when")
        parts = _CMP.split(spec.when)
        if len(parts) != 3:
            raise DeckError(f"expected one comparison 'a < b' (or >, <=, >=), got {spec.when!r}",
                            where)
        lhs, op, rhs = (p.strip() for p in parts)
        self.measures = compile_measures(spec.measures, body_index, spec.where.child("measures"))
        names = dict.fromkeys(list(self.measures) + ["t"])
        for text in (lhs, rhs):
            for token in _CHANNEL.findall(text):
                body, _, comp = token.partition(".")
                if body not in body_index:
                    raise DeckError(f"unknown body {body!r} in {token!r} (a measure named in "
                                    f"measures:, t, or <body>.<{'|'.join(BODY_CHANNELS)}>)", where)
                if comp not in BODY_CHANNELS:
                    raise DeckError(f"unknown channel {token!r}: a body gives "
                                    f"{', '.join(BODY_CHANNELS)}", where)
                names[token.replace(".", "__")] = None
        def plain(text):  # block.vx -> block__vx (a name the formula parser accepts)
            return _CHANNEL.sub(lambda m: m.group(0).replace(".", "__"), text)

        try:
            self.lhs = parse_expression(plain(lhs), list(names))
            self.rhs = parse_expression(plain(rhs), list(names))
        except ExpressionError as exc:
            raise DeckError(f"{exc} (names: the event's measures, t, "
                            f"<body>.<{'|'.join(BODY_CHANNELS)}>)", where) from exc
        becomes = -1 if op.startswith("<") else 1
        self.direction = becomes if spec.direction is None else DIRECTIONS[spec.direction]
        self.body_index = body_index

    def value(self, ctx) -> float:
        env: dict[str, Any] = {"t": ctx.t}
        st = ctx.state
        for name, m in self.measures.items():
            env[name] = float(m.value(st, ctx.t))
        for key in set(self.lhs.names) | set(self.rhs.names):
            if "__" in key and key not in env:
                body, comp = key.split("__")
                b = self.body_index[body]
                kind, axis = comp[:-1], "xyz".index(comp[-1])
                if kind == "":
                    env[key] = float(st.r[b, axis])
                elif kind == "v":
                    env[key] = float(st.rd[b, axis])
                else:
                    env[key] = float(st.omega[b, axis])
        return float(self.lhs(env)) - float(self.rhs(env))

    def switch(self) -> Switch:
        return Switch(self.name, self.direction, self.value, self.name, self.action,
                      self.hysteresis)


def compile_events(specs: dict, body_index: dict) -> tuple:
    return tuple(UserEvent(s, body_index) for s in specs.values())


EVENT_KEYS = ("when", "direction", "hysteresis", "action", "measures")


def read_events(rd, node, where, bodies, joints) -> dict:
    """``events:`` -> {name: EventSpec} (the deck loader's call)."""
    from mbsim.forces.measures import read_measures

    out = {}
    for name, child, w in rd.items(node, where):
        got = rd.fields(child, w, EVENT_KEYS, ("when",), "an event")
        wn, ww = got["when"]
        if wn.kind != "scalar" or not isinstance(wn.value, str):
            raise rd.error(ww, "expected a condition such as 'v < 0' (a string)", wn)
        spec = EventSpec(name, wn.value, where=w)
        if "direction" in got:
            spec.direction = rd.choice(*got["direction"], tuple(DIRECTIONS))
        if "action" in got:
            spec.action = rd.choice(*got["action"], ACTIONS)
        if "hysteresis" in got:
            spec.hysteresis = rd.number(*got["hysteresis"])  # in the unit of g
            if spec.hysteresis < 0:
                raise rd.error(got["hysteresis"][1], "expected hysteresis >= 0")
        if "measures" in got:
            spec.measures = read_measures(rd, *got["measures"], bodies, joints)
        out[name] = spec
    return out



# -- watching a run ------------------------------------------------------------------------
@dataclass
class Event:
    """A located event: time, state there (q, qd, w: the integrated work) and the switches
    that fired (within the location tolerance of the earliest)."""

    t: float
    q: np.ndarray
    qd: np.ndarray
    w: float
    fired: list


def _key(sw):
    return (sw.owner, sw.name)


class Watch:
    """The switches of a run (the deck's events and the hybrid elements' switches in their
    current modes), their values at the last accepted state and which deck events are armed
    (a deck event that fired re-arms once its function is back beyond its hysteresis on the
    side it came from)."""

    def __init__(self, user_events):
        self.user = [ue.switch() for ue in user_events]
        self.values: dict = {}
        self.armed = {_key(sw): True for sw in self.user}
        self.since = {}  # deck event -> the sign of g before it fired (re-arming)

    def switches(self, run):
        out = list(self.user)
        for el in run.system.hybrid:
            out += el.switches(run.modes.get(el.name))
        return out

    def step_limit(self, run, h_max):
        """The longest next step from the run's state: ``h_max`` (the option) or less where
        a hybrid element limits it (contract item 8)."""
        limits = [el for el in run.system.hybrid
                  if getattr(type(el), "step_limit", Hybrid.step_limit) is not Hybrid.step_limit]
        if not limits:
            return h_max
        s = run.solver
        ctx = Context(run.system, s.t, s.q, s.qd)
        return min([h_max] + [el.step_limit(run.modes.get(el.name), ctx) for el in limits])

    def reset(self, run, t, q, qd):
        """The switch values at a (re)start of the integration at (t, q, qd)."""
        ctx = Context(run.system, t, q, qd)
        self.values = {_key(sw): sw.value(ctx) for sw in self.switches(run)}
        self._rearm()

    def _rearm(self):
        for sw in self.user:
            k = _key(sw)
            if not self.armed[k] and k in self.values:
                # side: the sign of g before the firing; a one-way event fires again only
                # after g is back on that side, beyond the hysteresis; an event on both
                # directions once g is beyond it on the side it crossed to
                side = self.since.get(k, 0.0) * (-1.0 if sw.direction == 0 else 1.0)
                g = self.values[k]
                if side * g > sw.hysteresis or (side == 0 and abs(g) > sw.hysteresis):
                    self.armed[k] = True

    def check(self, run):
        """After an accepted step of ``run``: the earliest event in the step (:class:`Event`)
        or None (the values then move to the step's end).

        A switch whose function is back on its first side at the step's end (a crossing and
        its return inside the step) is seen by its probes (``Switch.probe``), or, where an
        earlier event cuts the step, by its value at that event: the events are located
        again until none crosses before the earliest."""
        solver, system = run.solver, run.system
        t0, t1 = solver.t_old, solver.t
        ctx1 = Context(system, t1, solver.q, solver.qd)
        found, values, watched = [], {}, []

        def locate_in(sw, ta, ga, tb, gb):
            def g(t):
                Q, QD, _ = solver.dense_output_many([t])
                return sw.value(Context(system, t, Q[0], QD[0]))

            if not crossed(sw.direction, ga, gb):
                if not sw.probe:
                    return None
                # a crossing and its return inside [ta, tb]: the first probe past it
                for tp in np.linspace(ta, tb, sw.probe + 2)[1:-1]:
                    gp = g(tp)
                    if crossed(sw.direction, ga, gp):
                        tb, gb = tp, gp
                        break
                    ta, ga = tp, gp
                else:
                    return None
            return locate(g, ta, tb, ga, gb, EVENT_TIME_TOL * max(1.0, abs(tb))), ga

        for sw in self.switches(run):
            k = _key(sw)
            g1 = sw.value(ctx1)
            values[k] = g1
            g0 = self.values.get(k)
            if g0 is None or not self.armed.get(k, True):
                continue
            watched.append((sw, g0))
            hit = locate_in(sw, t0, g0, t1, g1)
            if hit is not None:
                found.append((hit[0], sw, hit[1]))
        if not found:
            self.values = values
            self._rearm()
            return None
        while True:
            te = min(f[0] for f in found)
            if te >= t1:
                Q, QD, W = solver.q[None], solver.qd[None], np.array([solver.w])
            else:
                Q, QD, W = solver.dense_output_many([te])
            ctx_e = Context(system, te, Q[0], QD[0])
            seen = {_key(f[1]) for f in found}
            more = False
            for sw, g0 in watched:
                if _key(sw) in seen:
                    continue
                hit = locate_in(sw, t0, g0, te, sw.value(ctx_e))
                if hit is not None:
                    found.append((hit[0], sw, hit[1]))
                    more = True
            if not more:
                break
        tol = EVENT_TIME_TOL * max(1.0, abs(te))
        fired = [(sw, g0) for t, sw, g0 in found if t <= te + 2 * tol]
        for sw, g0 in fired:
            if sw.action != "switch":
                self.armed[_key(sw)] = False
                self.since[_key(sw)] = float(np.sign(g0))
        return Event(float(te), Q[0].copy(), QD[0].copy(), float(W[0]), [sw for sw, _ in fired])
