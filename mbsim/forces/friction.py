"""Joint friction with true stick-slip (ADAMS FRICTION on a joint): a hybrid force element
(:mod:`mbsim.events`, the contract there) on a translational or revolute joint.

Relative coordinate s and velocity v of the joint (the drivers' measures):

- translational: s = f_i . (P_j - P_i) (m), v = ds/dt; the friction force Fs acts along f_i
  on body j and opposite on body i, both at P_j (as :class:`mbsim.forces.contact.JointStop`);
- revolute: s = theta, the angle from g_i to g_j about f_i (rad, the rotation driver's angle,
  :class:`mbsim.forces.measures.Angle`), v = theta dot; Fs is a torque about the angle's
  gradient axis (f_i) on j and opposite on i.

Normal load N (N): the joint's reaction on body j from the multipliers of its own rows
(:func:`mbsim.analyses.reactions.rows_reaction`, Haug Sec. 11.6), plus ``preload``:

- translational: N = |F_perp| + 2 |M_perp| / bearing_length, F_perp and M_perp the reaction
  force and moment (about P_j) across f_i; the moment is carried by two opposite normal
  forces |M_perp| / L at the bearing's ends, whose magnitudes add (without bearing_length
  the moment is left out);
- revolute: N = |F_radial| (the reaction force across the axis); the friction torque has the
  lever ``pin_radius`` r.

With ``reaction: false`` N = preload alone: the element needs no multipliers and the
integrators keep their compiled step.

The capacity is C(v) = mu(|v|) N r (r = 1 for a translational joint), mu(v) = mu_k +
(mu_s - mu_k) exp(-(v / v_s)^2) with ``stribeck_velocity`` v_s (no v_s: mu = mu_k in slip,
plain Coulomb).  Modes (fixed during a step, so that the law is smooth inside steps):

- ``'+'`` / ``'-'``: slipping with v > 0 / v < 0: Fs = -s C(v) - viscous v, s = +1 / -1 the
  mode's sign; the switch ``slip->stick`` fires when v crosses 0 (falling in '+', rising in
  '-'): then the stick is tried (:meth:`next_mode`);
- ``'stick'``: a constraint row (:class:`mbsim.events.HoldRow`) holds s at its value when the
  stick began (the translation or rotation driver's row with that constant target); its
  multiplier lam_h is the friction the stick needs: Fs = -lam_h.  The switch ``breakaway``
  g = mu_s N r - |lam_h| fires when g falls through 0; the joint then slips in the direction
  of the load the stick resisted (sign(lam_h));
- ``None``: before the run's first decision (no loads).

At v = 0 the stick is tried with the multipliers of the stuck system at that state
(:meth:`mbsim.events.Context.trial`): stick if |lam_h| <= mu_s N r, else slip in the
direction of the net load, sign(lam_h).

The loop friction <-> reactions (the friction changes the accelerations, hence the
multipliers, hence N) is solved by :meth:`mbsim.fast.dynamics.System._reaction_loop`: a
fixed-point iteration loads(lam) -> solve -> lam, which contracts when mu x lever < 1 (mu
times the ratio of the friction's lever to the lever of the reaction it changes: mu r / L
for a pin, 2 mu h / bearing_length for a slider driven at height h).
"""

from __future__ import annotations

import numpy as np

from mbsim import core
from mbsim.errors import DeckError
from mbsim.events import HoldRow, Switch
from mbsim.forces import register
from mbsim.forces.base import ForceElement
from mbsim.forces.bushing import cross
from mbsim.forces.elements import _body_indices

REST_VELOCITY = 1e-9
"""m/s or rad/s: at t_start a joint slower than this is at rest (its stick is tried): far
below any physical slip, above the round-off of a consistent initial velocity (~1e-14 x the
speeds of the mechanism)."""
MODE_CODE = {"stick": 0.0, "+": 1.0, "-": -1.0, None: np.nan}
HOLD_ROWS = {  # joint type -> the hold row (kernel, its slots): the drivers' rows
    "translational": ("dot2", {"a": "f_i", "si": "P_i", "sj": "P_j"}),
    "revolute": ("angle", {"gi": "g_i", "hi": "h_i", "gj": "g_j"}),
}


def _nonnegative(d, key, where, positive=False):
    v = float(d[key])
    if v < 0 or (positive and v == 0):
        raise DeckError(f"{key} must be {'positive' if positive else '>= 0'}, got {v:g}",
                        where.child(key))
    return v


@register
class JointFriction(ForceElement):
    type = "friction"
    description = (
        "stick-slip joint friction (translational, revolute): mu_s, mu_k, Stribeck, viscous; "
        "normal load from the joint's reaction (+ preload); sticks exactly (a held row)"
    )
    hybrid = True

    @classmethod
    def from_spec(cls, spec, body_index):
        from mbsim.forces.measures import Angle
        from mbsim.model import _frames_of, joint_frame

        el = cls()
        d, where = spec.data, spec.where
        el.bi, el.bj = _body_indices(spec, body_index, 2)
        el.joint, el.joint_type = d["joint"], d["joint_type"]
        if el.joint_type not in HOLD_ROWS:
            raise DeckError(f"friction on a {el.joint_type} joint is not supported (known: "
                            f"{', '.join(HOLD_ROWS)})", where.child("joint"))
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
        el.angular = el.joint_type == "revolute"
        el.lever, el.L = 1.0, None
        if el.angular:
            if d.get("bearing_length") is not None:
                raise DeckError("bearing_length goes with a translational joint",
                                where.child("bearing_length"))
            if d.get("pin_radius") is None:
                raise DeckError("friction on a revolute joint needs pin_radius (the lever of "
                                "the friction torque, m)", where)
            el.lever = _nonnegative(d, "pin_radius", where, positive=True)
        else:
            if d.get("pin_radius") is not None:
                raise DeckError("pin_radius goes with a revolute joint", where.child("pin_radius"))
            if d.get("bearing_length") is not None:
                el.L = _nonnegative(d, "bearing_length", where, positive=True)
        names = tuple(spec.bodies)
        fi, fj = (joint_frame(spec.points.get(n)) for n in names)
        el.frames = _frames_of(names[0], names[1], spec.points)
        if el.angular:
            el.angle = Angle(el.bi, el.bj, fi, fj, 0.0)
        else:
            el.si, el.sj, el.f = fi["P"].copy(), fj["P"].copy(), fi["f"].copy()
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
        lever = f", pin radius {self.lever:g} m" if self.angular else (
            f", bearing length {self.L:g} m" if self.L else "")
        return f"{self.joint_type} joint {self.joint}: {law}; normal load: {load}{lever}"

    # -- the joint's relative coordinate ------------------------------------------------------
    def travel(self, st):
        """(s, v, axis (3,) global, P_j (3,) global or None): the relative coordinate, its
        rate (None without velocities) and the direction of Fs; kept for the last state
        object (the reaction loop evaluates one state with successive multipliers)."""
        if self._travel[0] is not st:
            self._travel = (st, self._travel_of(st))
        return self._travel[1]

    def _travel_of(self, st):
        if self.angular:
            s, a = self.angle.terms(st)
            return s, None if st.rd is None else self.angle.rate(st, a), a, None
        bi, bj = self.bi, self.bj
        Ai, Aj = st.A[bi], st.A[bj]
        Pi, Pj = st.r[bi] + Ai @ self.si, st.r[bj] + Aj @ self.sj
        f = Ai @ self.f
        s = float(f @ (Pj - Pi))
        if st.rd is None:
            return s, None, f, Pj
        wi, wj = Ai @ st.omega_local[bi], Aj @ st.omega_local[bj]
        vi = st.rd[bi] + cross(wi, Pi - st.r[bi])
        vj = st.rd[bj] + cross(wj, Pj - st.r[bj])
        return s, float(cross(wi, f) @ (Pj - Pi) + f @ (vj - vi)), f, Pj

    def normal_load(self, st, lam):
        """N (N): the joint's reaction on body j across the axis (module doc) from the
        multipliers ``lam`` (on the model's rows; None: not known yet, reaction 0) plus the
        preload."""
        if not self.reactions or lam is None:
            return self.preload
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
        F, M = r.force[0], r.torque[0]
        f = st.A[self.bi] @ self.frames["f_i"]
        N = float(np.linalg.norm(F - (F @ f) * f))
        if self.L:
            N += 2.0 * float(np.linalg.norm(M - (M @ f) * f)) / self.L
        return N + self.preload

    def mu(self, v):
        if self.v_s is None:
            return self.mu_k
        return self.mu_k + (self.mu_s - self.mu_k) * np.exp(-((v / self.v_s) ** 2))

    def slip_load(self, mode, st, lam):
        """(Fs, N, v) in a slip mode '+' / '-' (module doc)."""
        _, v, _, _ = self.travel(st)
        N = self.normal_load(st, lam)
        sign = 1.0 if mode == "+" else -1.0
        return -sign * self.mu(v) * N * self.lever - self.viscous * v, N, v

    def _add(self, Fs, st, F, n_local):
        """Fs along the joint's direction on body j, the opposite on i (module doc)."""
        _, _, a, Pj = self.travel(st)
        bi, bj = self.bi, self.bj
        if self.angular:
            n_local[bj] += st.A[bj].T @ (Fs * a)
            n_local[bi] -= st.A[bi].T @ (Fs * a)
            return
        f = Fs * a
        F[bj] += f
        F[bi] -= f
        n_local[bj] += st.A[bj].T @ cross(Pj - st.r[bj], f)
        n_local[bi] -= st.A[bi].T @ cross(Pj - st.r[bi], f)

    # -- the hybrid contract (mbsim.events) ----------------------------------------------------
    def apply(self, st, t, F, n_local):
        """Outside a hybrid run (a static analysis): no friction (the stick is its own
        constraint, the slip a mode of the dynamic run)."""

    def apply_in(self, mode, st, t, lam, F, n_local):
        if mode in ("+", "-"):
            self._add(self.slip_load(mode, st, lam)[0], st, F, n_local)

    def hold_count(self, mode) -> int:
        return 1 if mode == "stick" else 0

    def holds(self, mode, ctx):
        if mode != "stick":
            return []
        s = self.travel(ctx.state)[0]
        kernel, args = HOLD_ROWS[self.joint_type]
        return [HoldRow(kernel, args, self.frames, self.bi, self.bj, float(s), self.name,
                        f"{self.name}.stick")]

    def _hold_multiplier(self, system, lam):
        rows = system.model.item(f"hold:{self.name}").rows
        return float(lam[rows[0]])

    def _velocity(self, ctx):
        return self.travel(ctx.state)[1]

    def _breakaway(self, ctx):
        """mu_s N r - |lam_h| in the stuck system at ctx (> 0 while the stick holds)."""
        _, lam = ctx.accelerations()
        return (self.mu_s * self.normal_load(ctx.state, lam) * self.lever
                - abs(self._hold_multiplier(ctx.system, lam)))

    def switches(self, mode):
        if mode == "+":
            return [Switch("slip->stick", -1, self._velocity, self.name)]
        if mode == "-":
            return [Switch("slip->stick", 1, self._velocity, self.name)]
        if mode == "stick":
            return [Switch("breakaway", -1, self._breakaway, self.name)]
        return []

    def _try_stick(self, ctx):
        """'stick' when the stuck system at ctx needs |lam_h| <= mu_s N r, else the slip
        in the direction of the load the stick would resist."""
        _, lam, system = ctx.trial({self.name: "stick"})
        lam_h = self._hold_multiplier(system, lam)
        if abs(lam_h) <= self.mu_s * self.normal_load(ctx.state, lam) * self.lever:
            return "stick"
        return "+" if lam_h > 0 else "-"

    def initial_mode(self, ctx):
        v = self._velocity(ctx)
        if abs(v) <= REST_VELOCITY:
            return self._try_stick(ctx)
        return "+" if v > 0 else "-"

    def next_mode(self, mode, switch, ctx):
        if switch.name == "breakaway":
            _, lam = ctx.accelerations()
            return "+" if self._hold_multiplier(ctx.system, lam) > 0 else "-"
        return self._try_stick(ctx)

    def channels_in(self, mode, st, t, lam, modes=None):
        """friction (N or N m, on body j along the joint's direction), normal_load (N),
        slip_velocity (m/s or rad/s), mode (0 stick, +1, -1; NaN before the first), power
        (W, Fs v: <= 0)."""
        _, v, _, _ = self.travel(st)
        Fs, N = 0.0, self.normal_load(st, lam)
        if mode in ("+", "-"):
            Fs, N, v = self.slip_load(mode, st, lam)
        elif mode == "stick" and lam is not None and self.model is not None:
            rows = held_rows_from(self, lam, modes)
            if rows.size:
                Fs = -float(lam[rows[0]])
        unit = "N m" if self.angular else "N"
        return {
            "friction": (Fs, unit),
            "normal_load": (N, "N"),
            "slip_velocity": (v, "rad/s" if self.angular else "m/s"),
            "mode": (MODE_CODE.get(mode, np.nan), ""),
            "power": (Fs * v, "W"),
        }


def held_rows_from(el, lam, modes):
    """The rows of ``lam`` (multipliers on the base model's rows and then the held rows)
    that ``el`` holds, given every hybrid element's mode (``modes``; None: ``el`` is the
    only one holding)."""
    m = el.model.m
    hybrid = [f for f in el.model.forces if getattr(f, "hybrid", False)]
    if modes is None:
        return np.arange(m, len(lam)) if len(lam) > m else np.arange(0)
    for f in hybrid:
        k = f.hold_count(modes.get(f.name))
        if f is el:
            return np.arange(m, m + k)
        m += k
    return np.arange(0)
