"""The ``tire`` force element: a vertical tire on a flat road z = 0 (Haug Sec. 12.5.1).

Haug's model (Eqs. 12.5.1-12.5.3 and the text around them):

- vertical force F_ver = k_t d, d = tire deflection from the spindle height above the road;
- lateral force F_lat = C_alpha alpha, at most mu F_ver in magnitude;
- slip angle alpha = psi - psi_v (12.5.1), tire heading psi = 2 acos(e0) (12.5.2), velocity
  angle psi_v = -atan(v_x / v_y) (12.5.3).

Written here so that it holds at any heading and at standstill (12.5.2 presumes the spindle
turns about z only and 12.5.3 loses the quadrant):

- heading u: the body-fixed ``forward`` axis (default y', the book's driving direction)
  projected on the road and normalised; lateral axis l = u x z (to the right of u);
- v: velocity of the body point at the contact point C (below the spindle on the road);
  v_fwd = u . v, v_lat = l . v;
- alpha = atan2(v_lat, |v_fwd|): equal to psi - psi_v (mod 2 pi) in forward motion, at every
  heading; in reverse the slip is measured from the backward direction, so the lateral force
  still opposes sideways sliding (Haug's angle would be near pi there);
- below the speed ``v_min`` the lateral force fades to zero (cubic smoothstep in the road
  speed |v_h|), so that it vanishes at standstill where alpha has no meaning;
- F_ver = max(0, k_t d + c d_dot) for d > 0, else 0 (no tension off the ground); ``c`` is an
  optional tire damping (the book has none);
- F_lat = w(|v_h|) clip(C_alpha alpha, -mu F_ver, mu F_ver); optional rolling resistance
  F_roll = f_r F_ver clip(v_fwd / v_min, -1, 1) against the forward motion.

The force F = F_ver z - F_lat l - F_roll u acts at C = P - h z (P the spindle point, h its
height): the lateral force at the road gives the roll moment a real tire gives.  Because the
slip uses the velocity of the point where the force acts, the lateral force never does
positive work (its power is -F_lat v_lat with F_lat of the sign of v_lat).

Channels: ``F_ver`` (N), ``F_lat`` (N, along -l), ``alpha`` (rad), ``saturated`` (1 where
|C_alpha alpha| >= mu F_ver on the ground, else 0), ``deflection`` (m), ``heading`` (psi of
eq. 12.5.2 in (-pi, pi], from global y about z, rad), ``speed`` (|v_h|, the road speed of the
contact point, m/s), ``force`` (global).

The law is written once, in C (mbsim/fast/kernels.c ``tire_law``): the equations of motion
evaluate the tires as compiled elements (``EL_TIRE``, the data of :meth:`Tire.table_row`),
and everything here (a tire's state, channels and loads at one state or at every output)
reads the same function through :func:`mbsim.fast.dynamics.tire_states`.  The tests check it
against the scalar law of tests/forces/tire_reference.py.
"""

from __future__ import annotations

import math
import weakref

import numpy as np

from mbsim.errors import DeckError
from mbsim.forces import register
from mbsim.forces.elements import _body_indices, _Element, _local_point


@register
class Tire(_Element):
    type = "tire"
    description = (
        "vertical tire on the road z = 0: F_ver = k_t d, F_lat = C_alpha alpha <= mu F_ver "
        "(Haug Sec. 12.5.1)"
    )

    @classmethod
    def from_spec(cls, spec, body_index):
        el = cls()
        d, where = spec.data, spec.where
        (el.b,) = _body_indices(spec, body_index, 1)
        el.s = _local_point(spec, spec.bodies[0])  # spindle, body frame
        el.kt = float(d["kt"])
        el.radius = float(d["radius"])
        el.c = float(d.get("c", 0.0))
        el.c_alpha = float(d["c_alpha"])
        el.mu = float(d.get("mu", 0.8))
        el.rolling = float(d.get("rolling", 0.0))
        el.v_min = float(d.get("v_min", 0.5))
        fwd = np.array(d.get("forward", (0.0, 1.0, 0.0)), dtype=float)
        for key, value in (("kt", el.kt), ("radius", el.radius), ("v_min", el.v_min)):
            if not value > 0:
                raise DeckError(f"expected a positive {key}, got {value:g}", where.child(key))
        for key, value in (("c", el.c), ("c_alpha", el.c_alpha), ("mu", el.mu),
                           ("rolling", el.rolling)):  # fmt: skip
            if value < 0:
                raise DeckError(f"expected {key} >= 0, got {value:g}", where.child(key))
        if not np.linalg.norm(fwd) > 0:
            raise DeckError("the forward axis must not be the zero vector", where.child("forward"))
        el.fwd = fwd / np.linalg.norm(fwd)
        el.fwd.setflags(write=False)
        # own: this tire alone (its state at one state); group: every tire of the model,
        # which the outputs evaluate once for all (Tire.bind); slot: this tire's index in
        # its group
        el.own = el.group = TireGroup((el,))
        el.slot = 0
        return el

    def table_row(self) -> np.ndarray:
        """(13,) this tire's line of the compiled elements' data (mbsim/fast/dynamics.py
        ``ef``, kernels.c ``tire_law``): s' (3), forward (3), kt, radius, c, c_alpha, mu,
        rolling, v_min."""
        return np.concatenate([self.s, self.fwd, [self.kt, self.radius, self.c, self.c_alpha,
                                                  self.mu, self.rolling, self.v_min]])

    def bind(self, model):
        """Share one :class:`TireGroup` among all tires of ``model`` (compile_model's call)."""
        tires = tuple(el for el in model.forces if isinstance(el, Tire))
        if self.group.b.size == len(tires) > 1:
            return  # bound with its siblings by the first tire's call
        group = TireGroup(tires)
        for slot, el in enumerate(tires):
            el.group, el.slot = group, slot

    def state(self, st, t) -> dict:
        """Everything the tire computes at one state (see the module doc for the symbols):
        F, sc, v, u (3,), the rest floats."""
        s = self.own.at(st)
        out = {key: s[key][0] for key in ("F", "sc", "v", "u")}
        out.update({key: float(s[key][0]) for key in _SCALARS})
        return out

    def apply(self, st, t, F, n_local):
        """This tire's load alone (a System evaluates the tires in its C force evaluation,
        ``EL_TIRE``; this is the same law, for callers that ask one element)."""
        self.own.apply(st, t, F, n_local)

    def potential(self, st):
        """k_t d^2 / 2 on the ground (the damping, lateral and rolling forces are not counted)."""
        d = self.radius - float(st.r[self.b][2] + st.A[self.b][2] @ self.s)
        return 0.5 * self.kt * d * d if d > 0 else 0.0

    def state_many(self, states, t) -> dict:
        """:meth:`state` at every output of ``states`` (:class:`mbsim.core.States`): the same
        quantities with a leading time axis (F, sc, v, u (nt, 3); the rest (nt,)); this
        tire's column of its group's evaluation (:meth:`TireGroup.at_many`: once per
        ``states`` for all the tires)."""
        k = self.slot
        return {key: value[:, k].copy() for key, value in self.group.at_many(states).items()}

    def loads_many(self, states, t, F, n_local):
        """:meth:`apply` at every output: adds to F, n_local (nt, nb, 3)."""
        s, b, k = self.group.at_many(states), self.b, self.slot
        F[:, b] += s["F"][:, k]
        n_local[:, b] += s["n_local"][:, k]

    def potential_many(self, states):
        d = self.radius - (states.r[:, self.b, 2] + states.A[:, self.b, 2] @ self.s)
        return np.where(d > 0, 0.5 * self.kt * d * d, 0.0)

    def channels_many(self, states, t):
        s = self.state_many(states, t)
        return {
            "F_ver": (s["F_ver"], "N"),
            "F_lat": (s["F_lat"], "N"),
            "alpha": (s["alpha"], "rad"),
            "saturated": (s["saturated"], ""),
            "deflection": (s["deflection"], "m"),
            "heading": (np.arctan2(-s["u"][:, 0], s["u"][:, 1]), "rad"),
            "speed": (s["speed"], "m/s"),
            "force": (s["F"], "N"),
        }

    def channels(self, st, t):
        s = self.state(st, t)
        return {
            "F_ver": (s["F_ver"], "N"),
            "F_lat": (s["F_lat"], "N"),
            "alpha": (s["alpha"], "rad"),
            "saturated": (s["saturated"], ""),
            "deflection": (s["deflection"], "m"),
            "heading": (math.atan2(-s["u"][0], s["u"][1]), "rad"),
            "speed": (s["speed"], "m/s"),
            "force": (s["F"], "N"),
        }


_SCALARS = ("F_ver", "F_lat", "F_roll", "alpha", "saturated", "deflection", "speed")


class TireGroup:
    """All tires of a model, evaluated together: the tire law (module doc; kernels.c
    ``tire_law``) of every tire at one state or at every output of a run in one C call
    (:func:`mbsim.fast.dynamics.tire_states`).

    Constant arrays, built once per model (:meth:`Tire.bind`): ``b`` (ne,) body of each tire,
    ``table`` (ne, 13) its data (:meth:`Tire.table_row`, the tire's row of the compiled
    elements' table).

    :meth:`at_many` evaluates the tires at every output of a run once, and each tire's
    channels there read its column (``Tire.slot``).  A tire's state at one state comes from
    its own group of one (``Tire.own``)."""

    def __init__(self, tires):
        self.b = np.array([el.b for el in tires], dtype=np.int64)
        self.table = np.array([el.table_row() for el in tires], dtype=float).reshape(
            len(self.b), -1)
        for a in (self.b, self.table):
            a.setflags(write=False)
        # at_many's results, one per States object while it lives: the outputs' loads and
        # each tire's channels read one evaluation of the group (States are not changed
        # after they are built: mbsim.core.States)
        self._many = weakref.WeakKeyDictionary()

    def __getstate__(self):  # the memo (weak references) is not part of the group's state
        return {k: v for k, v in self.__dict__.items() if k != "_many"}

    def __setstate__(self, state):
        self.__dict__.update(state)
        self._many = weakref.WeakKeyDictionary()

    def at(self, st) -> dict:
        """The law at one state (:class:`mbsim.core.State`): every quantity of
        :meth:`Tire.state` with a leading tire axis (F, sc, v, u, n_local (ne, 3); the rest
        (ne,))."""
        from mbsim.fast.dynamics import tire_states

        return tire_states(self.b, self.table, np.concatenate([st.r, st.p], axis=-1),
                           np.concatenate([st.rd, st.pd], axis=-1))

    def at_many(self, states) -> dict:
        """:meth:`at` at every output of ``states`` (:class:`mbsim.core.States`): time first,
        then tires (F ... (nt, ne, 3); the rest (nt, ne)).  Evaluated once per ``states``
        (kept while it lives): the arrays returned are shared, not to be written."""
        out = self._many.get(states)
        if out is None:
            out = self.at(states)  # r, p, rd, pd (nt, nb, ...): the same concatenation
            for a in out.values():
                a.setflags(write=False)
            self._many[states] = out
        return out

    def apply(self, st, t, F, n_local):
        """Adds every tire's force F and body torque n_local at ``st`` (ForceElement.apply
        for the whole group; two tires may share a body)."""
        s = self.at(st)
        np.add.at(F, self.b, s["F"])
        np.add.at(n_local, self.b, s["n_local"])
