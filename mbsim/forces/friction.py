"""Joint friction with true stick-slip (ADAMS FRICTION on a joint): a hybrid force element
(:mod:`mbsim.events`, the contract there) on a translational, revolute, cylindrical or
spherical joint.

Relative coordinates ("axes") of the joint and their rates v (the drivers' measures):

- translation (translational, cylindrical): s = f_i . (P_j - P_i) (m); the friction force Fs
  acts along f_i on body j and opposite on body i, both at P_j (as
  :class:`mbsim.forces.contact.JointStop`); lever r = 1;
- rotation (revolute, cylindrical): s = theta, the angle from g_i to g_j about f_i (rad, the
  rotation driver's angle, :class:`mbsim.forces.measures.Angle`); Fs is a torque about the
  angle's gradient axis (f_i) on j and opposite on i; lever r = ``pin_radius``;
- spherical: the relative angular velocity w = w_j - w_i (global, rad/s); the friction is a
  torque T on j (-T on i) against w; lever r = ``ball_radius``.

Normal load N (N): the joint's reaction on body j from the multipliers of its own rows
(:func:`mbsim.analyses.reactions.rows_reaction`, Haug Sec. 11.6), plus ``preload``:

- translational, revolute, cylindrical: |F_perp|, the reaction force across f_i, plus
  2 |M_perp| / bearing_length (translational, cylindrical) with M_perp the reaction moment
  about P_j across f_i, carried by two opposite normal forces |M_perp| / L at the bearing's
  ends whose magnitudes add (without bearing_length the moment is left out);
- spherical: |F|, the whole reaction force (the ball carries it in any direction).

With ``reaction: false`` N = preload alone: the element needs no multipliers and the
integrators keep their compiled step.

The capacity of an axis is C(v) = mu(|v|) N r, mu(v) = mu_k + (mu_s - mu_k) exp(-(v / v_s)^2)
with ``stribeck_velocity`` v_s (no v_s: mu = mu_k in slip, plain Coulomb).  Modes of an axis
(fixed during a step, so that the law is smooth inside steps):

- ``'+'`` / ``'-'``: slipping with v > 0 / v < 0: Fs = -s C(v) - viscous v, s = +1 / -1 the
  mode's sign; the switch ``rest`` fires when v crosses 0 (falling in '+', rising in
  '-'): then the stick is tried (:meth:`JointFriction.next_mode`);
- ``'stick'``: a constraint row (:class:`mbsim.events.HoldRow`) holds s at its value when the
  stick began (the translation or rotation driver's row with that constant target); its
  multiplier lam_h is the friction the stick needs: Fs = -lam_h.  The switch ``breakaway``
  g = mu_s N r - |lam_h| fires when g falls through 0; the axis then slips in the direction
  of the load the stick resisted (sign(lam_h));
- ``None``: before the run's first decision (no loads).

The element's mode is its axis's mode (translational, revolute), the pair (translation,
rotation) on a cylindrical joint (the two axes stick and slip independently, each with its
own capacity mu N r: a box, not a circle, for the combined slip), and on a spherical joint
``'stick'`` (three dot-1 rows hold the relative orientation) or ``('slip', u)``: the torque
-mu(|w|) N r w / |w| - viscous w, with the switch g = w . u (u: the slip's direction when it
began) falling through 0; there the stick is tried when |w| <= REST_SPIN, else the slip goes
on with u = w / |w| (a turn of the slip direction, not a stop).

At v = 0 the stick is tried with the multipliers of the stuck system at that state
(:meth:`mbsim.events.Context.trial`): stick if |lam_h| <= mu_s N r, else slip in the
direction of the net load, sign(lam_h).

The loop friction <-> reactions (the friction changes the accelerations, hence the
multipliers, hence N) is solved by :meth:`mbsim.fast.dynamics.System._reaction_loop`: a
fixed-point iteration loads(lam) -> solve -> lam, which contracts when mu times the ratio of
the friction's lever to the lever of the reaction it changes is below 1 (mu r / L for a pin
of radius r on a pendulum of length L).
"""

from __future__ import annotations

import numpy as np

from mbsim import core
from mbsim.errors import DeckError
from mbsim.events import HoldRow, Switch
from mbsim.forces import register
from mbsim.forces.base import ForceElement
from mbsim.forces.elements import _body_indices
from mbsim.forces.measures import axis_travel
from mbsim.rotations import cross

REST_VELOCITY = 1e-9
"""m/s or rad/s: at t_start an axis slower than this is at rest (its stick is tried): far
below any physical slip, above the round-off of a consistent initial velocity (~1e-14 x the
speeds of the mechanism)."""
REST_SPIN = 1e-6
"""rad/s: a spherical joint whose slip direction reverses (w . u = 0) with |w| below this
sticks (when the stuck system holds); the projection onto the stick then removes at most
this relative angular velocity (a kinetic energy I REST_SPIN^2 / 2 ~ 1e-12 I J), far below
the error of the run; above it the slip turns (a new u)."""
MODE_CODE = {"stick": 0.0, "+": 1.0, "-": -1.0, None: np.nan}
JOINT_AXES = {  # joint type -> its friction axes
    "translational": ("translation",),
    "revolute": ("rotation",),
    "cylindrical": ("translation", "rotation"),
    "spherical": (),
}
HOLD_ROWS = {  # axis -> the hold row (kernel, its slots): the drivers' rows
    "translation": ("dot2", {"a": "f_i", "si": "P_i", "sj": "P_j"}),
    "rotation": ("angle", {"gi": "g_i", "hi": "h_i", "gj": "g_j"}),
}
BALL_ROWS = (("h_i", "g_j"), ("f_i", "h_j"), ("g_i", "f_j"))  # spherical: dot-1 rows a_i . b_j


def _slip(u):
    """A spherical joint's slip mode with direction u (3,): ('slip', ux, uy, uz)."""
    return ("slip", *(float(x) for x in u))


def _nonnegative(d, key, where, positive=False):
    v = float(d[key])
    if v < 0 or (positive and v == 0):
        raise DeckError(f"{key} must be {'positive' if positive else '>= 0'}, got {v:g}",
                        where.child(key))
    return v


class _Axis:
    """One relative coordinate of the joint (module doc): ``name``, ``lever`` (1 or the pin
    radius), ``travel(st) -> (s, v, a, P_j)`` and ``add(Fs, st, F, n_local)``."""

    def __init__(self, name, el, fi, fj):
        from mbsim.forces.measures import Angle

        self.name, self.bi, self.bj = name, el.bi, el.bj
        self.lever = el.pin_radius if name == "rotation" else 1.0
        if name == "rotation":
            self.angle = Angle(el.bi, el.bj, fi, fj, 0.0)
        else:
            self.si, self.sj, self.f = fi["P"].copy(), fj["P"].copy(), fi["f"].copy()

    def travel(self, st):
        """(s, v, a (3,) global, P_j (3,) global or None): the coordinate, its rate (None
        without velocities) and the direction of Fs (at P_j, or a torque for None)."""
        if self.name == "rotation":
            s, a = self.angle.terms(st)
            return s, None if st.rd is None else self.angle.rate(st, a), a, None
        return axis_travel(st, self.bi, self.bj, self.si, self.sj, self.f)

    @staticmethod
    def add(Fs, a, Pj, st, bi, bj, F, n_local):
        """Fs along a on body j, the opposite on i: a force at P_j, or a torque (P_j None)."""
        f = Fs * a
        if Pj is None:
            n_local[bj] += st.A[bj].T @ f
            n_local[bi] -= st.A[bi].T @ f
            return
        F[bj] += f
        F[bi] -= f
        n_local[bj] += st.A[bj].T @ cross(Pj - st.r[bj], f)
        n_local[bi] -= st.A[bi].T @ cross(Pj - st.r[bi], f)


@register
class JointFriction(ForceElement):
    type = "friction"
    description = (
        "stick-slip joint friction (translational, revolute, cylindrical, spherical): mu_s, "
        "mu_k, Stribeck, viscous; normal load from the joint's reaction (+ preload); sticks "
        "exactly (held rows)"
    )
    hybrid = True

    @classmethod
    def from_spec(cls, spec, body_index):
        from mbsim.model import _frames_of, joint_frame

        el = cls()
        d, where = spec.data, spec.where
        el.bi, el.bj = _body_indices(spec, body_index, 2)
        el.joint, el.joint_type = d["joint"], d["joint_type"]
        if el.joint_type not in JOINT_AXES:
            raise DeckError(f"friction on a {el.joint_type} joint is not supported (known: "
                            f"{', '.join(JOINT_AXES)})", where.child("joint"))
        el.mu_s = _nonnegative(d, "mu_s", where)
        el.mu_k = _nonnegative(d, "mu_k", where)
        if el.mu_k > el.mu_s:
            raise DeckError(f"mu_k must not exceed mu_s, got mu_k = {el.mu_k:g} > mu_s = "
                            f"{el.mu_s:g}", where.child("mu_k"))
        el.viscous = _nonnegative(d, "viscous", where)
        el.preload = _nonnegative(d, "preload", where)
        el.v_s = (None if d.get("stribeck_velocity") is None
                  else _nonnegative(d, "stribeck_velocity", where, positive=True))
        el.reactions = bool(d.get("reaction", True))
        names = JOINT_AXES[el.joint_type]
        el.ball = el.joint_type == "spherical"
        geometry = {  # key -> the joint types it goes with
            "pin_radius": ("revolute", "cylindrical"),
            "bearing_length": ("translational", "cylindrical"),
            "ball_radius": ("spherical",),
        }
        for key, types in geometry.items():
            if d.get(key) is not None and el.joint_type not in types:
                raise DeckError(f"{key} goes with a {' or '.join(types)} joint, not "
                                f"{el.joint_type}", where.child(key))
        for key, what in (("pin_radius", "rotation"), ("ball_radius", "spherical")):
            if d.get(key) is None and (what in names or (el.ball and key == "ball_radius")):
                raise DeckError(f"friction on a {el.joint_type} joint needs {key} (the lever "
                                f"of the friction torque, m)", where)
        el.pin_radius = (_nonnegative(d, "pin_radius", where, positive=True)
                         if d.get("pin_radius") is not None else None)
        el.ball_radius = (_nonnegative(d, "ball_radius", where, positive=True)
                          if d.get("ball_radius") is not None else None)
        el.L = (_nonnegative(d, "bearing_length", where, positive=True)
                if d.get("bearing_length") is not None else None)
        bodies = tuple(spec.bodies)
        fi, fj = (joint_frame(spec.points.get(n)) for n in bodies)
        el.frames = _frames_of(bodies[0], bodies[1], spec.points)
        el.axes = tuple(_Axis(n, el, fi, fj) for n in names)
        el.model, el._jac, el._travel = None, (None, None), (None, None)
        return el

    def bind(self, model):
        """The compiled model whose joint rows give the normal load (compile_model's call)."""
        self.model = model
        self.item = model.item(self.joint)

    def __repr__(self) -> str:
        return f"<friction {self.name}>"

    def describe(self, model) -> str:
        """One line for ``mbsim info``."""
        law = (f"mu_s {self.mu_s:g}, mu_k {self.mu_k:g}"
               + (f", Stribeck v_s {self.v_s:g}" if self.v_s else "")
               + (f", viscous {self.viscous:g}" if self.viscous else ""))
        load = "joint reaction" if self.reactions else "preload"
        if self.reactions and self.preload:
            load += f" + preload {self.preload:g} N"
        elif not self.reactions:
            load += f" {self.preload:g} N"
        geo = [f"{k.replace('_', ' ')} {v:g} m" for k, v in (
            ("pin_radius", self.pin_radius), ("ball_radius", self.ball_radius),
            ("bearing_length", self.L)) if v]
        return (f"{self.joint_type} joint {self.joint}: {law}; normal load: {load}"
                + "".join(f", {g}" for g in geo))

    # -- kinematics and the normal load ----------------------------------------------------
    def travel(self, st):
        """The first axis's (s, v, a, P_j) (:meth:`_Axis.travel`)."""
        return self.travels(st)[0]

    def travels(self, st):
        """Every axis's (s, v, a, P_j); kept for the last state object (the reaction loop
        evaluates one state with successive multipliers)."""
        if self._travel[0] is not st:
            self._travel = (st, [ax.travel(st) for ax in self.axes])
        return self._travel[1]

    def spin(self, st):
        """Spherical: w = w_j - w_i (3,) global, rad/s."""
        bi, bj = self.bi, self.bj
        return st.A[bj] @ st.omega_local[bj] - st.A[bi] @ st.omega_local[bi]

    def reaction(self, st, lam):
        """(F, M) (3,) global: the joint's reaction force on body j and its moment about P_j
        from the multipliers ``lam`` on the model's rows."""
        from mbsim.analyses.reactions import rows_reaction

        it, bj = self.item, self.bj
        key, J = self._jac  # Phi_q of the joint's rows: one evaluation per state
        if key is not st:
            q = np.concatenate([st.r, st.p], axis=1).reshape(-1)
            J = core.phi_q(self.model, core.make_data(self.model, it.rows), q)
            self._jac = (st, J)
        r = rows_reaction(it.name, "j", bj, J[None, :, 7 * bj: 7 * bj + 7],
                          np.asarray(lam)[it.rows][None], st.p[bj][None], it.P_j, None,
                          st.A[bj][None], st.G[bj][None])
        return r.force[0], r.torque[0]

    def normal_load(self, st, lam):
        """N (N): the joint's reaction across its axis (module doc) from the multipliers
        ``lam`` (on the model's rows; None: not known yet, reaction 0) plus the preload."""
        if not self.reactions or lam is None:
            return self.preload
        F, M = self.reaction(st, lam)
        if self.ball:
            return float(np.sqrt(F @ F)) + self.preload
        f = st.A[self.bi] @ self.frames["f_i"]
        N = float(np.linalg.norm(F - (F @ f) * f))
        if self.L:
            N += 2.0 * float(np.linalg.norm(M - (M @ f) * f)) / self.L
        return N + self.preload

    def mu(self, v):
        if self.v_s is None:
            return self.mu_k
        return self.mu_k + (self.mu_s - self.mu_k) * np.exp(-((v / self.v_s) ** 2))

    # -- modes ------------------------------------------------------------------------------
    def _split(self, mode):
        """The axes' modes of the element's mode (module doc)."""
        if len(self.axes) == 1:
            return (mode,)
        return (None,) * len(self.axes) if mode is None else tuple(mode)

    def _join(self, modes):
        return modes[0] if len(self.axes) == 1 else tuple(modes)

    def _label(self, k):
        return "" if len(self.axes) == 1 else f" ({self.axes[k].name})"

    def slip_loads(self, mode, st, lam):
        """[(axis k, Fs, v)] of the slipping axes and N (module doc)."""
        modes = self._split(mode)
        if not any(m in ("+", "-") for m in modes):
            return [], None
        N = self.normal_load(st, lam)
        out = []
        for k, (ax, m) in enumerate(zip(self.axes, modes)):
            if m in ("+", "-"):
                v = self.travels(st)[k][1]
                sign = 1.0 if m == "+" else -1.0
                out.append((k, -sign * self.mu(v) * N * ax.lever - self.viscous * v, v))
        return out, N

    def slip_load(self, mode, st, lam):
        """(Fs, N, v) of the first slipping axis (translational, revolute: the one)."""
        out, N = self.slip_loads(mode, st, lam)
        k, Fs, v = out[0]
        return Fs, N, v

    def ball_torque(self, st, lam):
        """Spherical slip: (T (3,) on body j, N, w)."""
        w = self.spin(st)
        n = float(np.sqrt(w @ w))
        N = self.normal_load(st, lam)
        T = -self.viscous * w
        if n > 0.0:
            T = T - self.mu(n) * N * self.ball_radius * w / n
        return T, N, w

    # -- the hybrid contract (mbsim.events) ----------------------------------------------------
    def apply(self, st, t, F, n_local):
        """Outside a hybrid run (a static analysis): no friction (the stick is its own
        constraint, the slip a mode of the dynamic run)."""

    def apply_in(self, mode, st, t, lam, F, n_local):
        bi, bj = self.bi, self.bj
        if self.ball:
            if isinstance(mode, tuple):
                T = self.ball_torque(st, lam)[0]
                n_local[bj] += st.A[bj].T @ T
                n_local[bi] -= st.A[bi].T @ T
            return
        out, _ = self.slip_loads(mode, st, lam)
        for k, Fs, _ in out:
            _, _, a, Pj = self.travels(st)[k]
            _Axis.add(Fs, a, Pj, st, bi, bj, F, n_local)

    def hold_count(self, mode) -> int:
        if self.ball:
            return len(BALL_ROWS) if mode == "stick" else 0
        return sum(m == "stick" for m in self._split(mode))

    def holds(self, mode, ctx):
        st = ctx.state
        if self.ball:
            return self._ball_holds(st) if mode == "stick" else []
        out = []
        for k, m in enumerate(self._split(mode)):
            if m == "stick":
                kernel, args = HOLD_ROWS[self.axes[k].name]
                s = self.travels(st)[k][0]
                out.append(HoldRow(kernel, args, self.frames, self.bi, self.bj, float(s),
                                   self.name, f"{self.name}.stick{self._label(k)}"))
        return out

    def _ball_holds(self, st):
        """Three dot-1 rows a_i . b_j between the joint frame on i and, on j, the same frame
        as it lies at the stick (so the rows are independent whatever the relative
        rotation); targets: their values there (0 to round-off)."""
        Ai, Aj = st.A[self.bi], st.A[self.bj]
        fr = dict(self.frames)
        for k in ("f", "g", "h"):
            fr[f"{k}_j"] = Aj.T @ (Ai @ self.frames[f"{k}_i"])
        out = []
        for a, b in BALL_ROWS:
            target = float((Ai @ fr[a]) @ (Aj @ fr[b]))
            out.append(HoldRow("dot1", {"ai": a, "aj": b}, fr, self.bi, self.bj, target,
                               self.name, f"{self.name}.stick.{a[0]}{b[0]}"))
        return out

    def _hold_lams(self, system, lam):
        """The multipliers of this element's held rows in ``system`` (its model's
        ``hold:NAME`` item)."""
        return np.asarray(lam)[system.model.item(f"hold:{self.name}").rows]

    def _held_torque(self, system, lam, st):
        """Spherical stick: the torque (3,) the held rows of ``system`` apply to body j."""
        return self._ball_stick_torque(st, self._hold_lams(system, lam))

    def _stuck_lam(self, k, modes, system, lam):
        """The multiplier of axis k's held row (the stuck axes' rows in axis order)."""
        pos = sum(m == "stick" for m in modes[:k])
        return float(self._hold_lams(system, lam)[pos])

    def _velocity(self, k):
        return lambda ctx: self.travels(ctx.state)[k][1]

    def _breakaway(self, k, mode):
        def g(ctx):
            _, lam = ctx.accelerations()
            N = self.normal_load(ctx.state, lam)
            if self.ball:
                T = self._held_torque(ctx.system, lam, ctx.state)
                return self.mu_s * N * self.ball_radius - float(np.sqrt(T @ T))
            lam_h = self._stuck_lam(k, self._split(mode), ctx.system, lam)
            return self.mu_s * N * self.axes[k].lever - abs(lam_h)
        return g

    def switches(self, mode):
        if self.ball:
            if mode == "stick":
                return [Switch("breakaway", -1, self._breakaway(0, mode), self.name)]
            if isinstance(mode, tuple):
                u = np.array(mode[1:])
                return [Switch("rest", -1, lambda ctx: float(self.spin(ctx.state) @ u),
                               self.name)]
            return []
        out = []
        for k, m in enumerate(self._split(mode)):
            label = self._label(k)
            if m in ("+", "-"):
                out.append(Switch("rest" + label, -1 if m == "+" else 1,
                                  self._velocity(k), self.name))
            elif m == "stick":
                out.append(Switch("breakaway" + label, -1, self._breakaway(k, mode), self.name))
        return out

    def _try_stick(self, ctx, modes, ks):
        """The axes ``ks`` tried stuck (the others in ``modes``): each sticks when the stuck
        system needs |lam_h| <= mu_s N r, else slips in the direction of the load the stick
        would resist.  Returns the axes' modes."""
        trial = list(modes)
        for k in ks:
            trial[k] = "stick"
        _, lam, system = ctx.trial({self.name: self._join(trial)})
        N = self.normal_load(ctx.state, lam)
        out = list(modes)
        for k in ks:
            lam_h = self._stuck_lam(k, trial, system, lam)
            out[k] = ("stick" if abs(lam_h) <= self.mu_s * N * self.axes[k].lever
                      else ("+" if lam_h > 0 else "-"))
        return out

    def _ball_try_stick(self, ctx):
        _, lam, system = ctx.trial({self.name: "stick"})
        T = self._held_torque(system, lam, ctx.state)
        n = float(np.sqrt(T @ T))
        if n <= self.mu_s * self.normal_load(ctx.state, lam) * self.ball_radius:
            return "stick"
        return _slip(-T / n)

    def initial_mode(self, ctx):
        if self.ball:
            w = self.spin(ctx.state)
            n = float(np.sqrt(w @ w))
            if n <= REST_VELOCITY:
                return self._ball_try_stick(ctx)
            return _slip(w / n)
        v = [tr[1] for tr in self.travels(ctx.state)]
        modes = ["+" if vk > 0 else "-" for vk in v]
        rest = [k for k, vk in enumerate(v) if abs(vk) <= REST_VELOCITY]
        if rest:
            modes = self._try_stick(ctx, modes, rest)
        return self._join(modes)

    def next_mode(self, mode, switch, ctx):
        if self.ball:
            if switch.name == "breakaway":
                _, lam = ctx.accelerations()
                T = self._held_torque(ctx.system, lam, ctx.state)
                return _slip(-T / float(np.sqrt(T @ T)))
            w = self.spin(ctx.state)
            n = float(np.sqrt(w @ w))
            if n <= REST_SPIN:
                return self._ball_try_stick(ctx)
            return _slip(w / n)
        modes = list(self._split(mode))
        k = next(i for i in range(len(self.axes)) if switch.name.endswith(self._label(i)))
        if switch.name.startswith("breakaway"):
            _, lam = ctx.accelerations()
            modes[k] = "+" if self._stuck_lam(k, modes, ctx.system, lam) > 0 else "-"
            return self._join(modes)
        return self._join(self._try_stick(ctx, modes, [k]))

    # -- channels ---------------------------------------------------------------------------
    def channels_in(self, mode, st, t, lam, modes=None):
        """friction (N or N m on body j along the axis; spherical: the torque (3,) on j),
        normal_load (N), slip_velocity (m/s or rad/s; spherical: w (3,)), mode (0 stick,
        +1, -1 (spherical: 1 slipping); NaN before the first), power (W, <= 0); on a
        cylindrical joint the rotation's as friction_torque, slip_rate, mode_rotation."""
        base = self._held_base(lam, modes)
        if self.ball:
            w = self.spin(st)
            T, N = np.zeros(3), self.normal_load(st, lam)
            if isinstance(mode, tuple):
                T, N, w = self.ball_torque(st, lam)
            elif mode == "stick" and base is not None:
                T = self._ball_stick_torque(st, np.asarray(lam)[base:base + 3])
            code = 0.0 if mode == "stick" else (1.0 if isinstance(mode, tuple) else np.nan)
            return {"friction": (T, "N m"), "normal_load": (N, "N"),
                    "slip_velocity": (w, "rad/s"), "mode": (code, ""),
                    "power": (float(T @ w), "W")}
        ms = self._split(mode)
        trs = self.travels(st)
        Fs = [0.0] * len(self.axes)
        v = [tr[1] for tr in trs]
        N = self.normal_load(st, lam)
        out, _ = self.slip_loads(mode, st, lam)
        for k, f, vk in out:
            Fs[k], v[k] = f, vk
        if base is not None:
            pos = base
            for k, m in enumerate(ms):
                if m == "stick":
                    Fs[k] = -float(lam[pos])
                    pos += 1
        unit = {"translation": ("N", "m/s"), "rotation": ("N m", "rad/s")}
        first = self.axes[0].name
        chans = {"friction": (Fs[0], unit[first][0]), "normal_load": (N, "N"),
                 "slip_velocity": (v[0], unit[first][1]),
                 "mode": (MODE_CODE.get(ms[0], np.nan), "")}
        if len(self.axes) == 2:
            chans.update({"friction_torque": (Fs[1], "N m"), "slip_rate": (v[1], "rad/s"),
                          "mode_rotation": (MODE_CODE.get(ms[1], np.nan), "")})
        chans["power"] = (float(sum(f * vk for f, vk in zip(Fs, v))), "W")
        return chans

    def _held_base(self, lam, modes):
        """The index in ``lam`` (the model's rows, then the held rows in the order of the
        hybrid elements; ``modes``: every element's mode, None: this one alone holds) of this
        element's first held row; None when lam is not known."""
        if lam is None or self.model is None:
            return None
        m = self.model.m
        if modes is None:
            return m
        for f in self.model.forces:
            if f is self:
                return m
            if getattr(f, "hybrid", False):
                m += f.hold_count(modes.get(f.name))
        return None

    def _ball_stick_torque(self, st, lams):
        """The torque (3,) on body j of the three held rows a_i . b_j with multipliers
        ``lams``: -sum lam_k (b_j x a_i), the rows' rotation gradients; during the stick b_j
        lies where the same axis of frame i lies (the rows hold the relative orientation at
        frame j = frame i), so both come from body i's frame."""
        Ai = st.A[self.bi]
        T = np.zeros(3)
        for lk, (a, b) in zip(lams, BALL_ROWS):
            T -= lk * cross(Ai @ self.frames[b[0] + "_i"], Ai @ self.frames[a])
        return T
