"""Compliant contact: a sphere against a plane or against a sphere, with the impact law of
ADAMS IMPACT or a restitution-based (Hunt-Crossley family) damping, and regularised Coulomb
friction.

Geometry (body coordinates from the deck; i carries the plane or the first sphere, j the sphere):

- ``sphere-plane``: plane through P_i with unit normal n = A_i n' (``normal``, default z'),
  sphere of radius R centred at c = P_j.  Distance dist = n . (c - P_i); penetration
  g = R - dist; n points from the plane to the sphere.
- ``sphere-sphere``: centres c_i = P_i, c_j = P_j, radii R_i, R_j; n = (c_j - c_i)/|c_j - c_i|;
  g = R_i + R_j - |c_j - c_i|.

The contact point C is the middle of the overlap on the line through the sphere centre(s)
along n.  Penetration rate gd = dg/dt = -n . (v_j(C) - v_i(C)) (exact: C lies on that line);
tangential slip v_t = v_j(C) - v_i(C) + gd n.

Normal force (on body j along +n, the opposite on body i, both at C), for g > 0 only:

    ADAMS IMPACT   F = k g^e + STEP(g, 0, 0, depth, c_max) gd
    restitution    F = k g^e (1 + alpha gd),    alpha from (e, v_impact):
        hunt-crossley        alpha = 3 (1 - e) / (2 v)       Hunt & Crossley 1975 (as Marhefka
                                                              & Orin 1999 write it)
        lankarani-nikravesh  alpha = 3 (1 - e^2) / (4 v)     Lankarani & Nikravesh 1990,
                                                              J. Mech. Des. 112:369
        flores               alpha = 8 (1 - e) / (5 e v)     Flores et al. 2011, Mech. Mach.
                                                              Theory 46:1251

F = max(F, 0): no adhesion.  STEP is ADAMS' cubic step: 0 at g = 0, c_max from g = depth on.
In a dynamic run the first touch of each impact is an event (:class:`Impacts`) and alpha is
computed from that impact's own approach speed, so the coefficient of restitution is e (to the
law's accuracy) at every impact; the deck's v_impact serves where there is no event (the
other analyses, a contact already closed at t_start).  Hunt-Crossley and Lankarani-Nikravesh
are derived for e near 1; Flores' law holds over the whole range.

Stiffness: ``k`` (N/m^e), or Hertz from ``E`` and ``nu`` (both bodies of one material):
k = 4/3 E* sqrt(R*), 1/E* = 2 (1 - nu^2)/E, R* = R (sphere-plane) or R_i R_j / (R_i + R_j),
exponent 3/2 (Johnson, Contact Mechanics, eq. 4.22).

Friction (``mu`` > 0): F_t = -mu F STEP(|v_t|, 0, 0, v_slip, 1) v_t/|v_t| on body j, opposite on
body i, at C.  It is REGULARISED: below v_slip it is a steep viscous law, so a body resting on
the contact under a tangential load creeps (joints stick exactly with the ``friction`` type).

Energy: the elastic part k g^(e+1)/(e+1) is the potential; the channels ``damping_power`` and
``friction_power`` are the power the contact dissipates (>= 0), for an energy balance.

Step size: the integrator must resolve each impact; an undamped Hertzian impact of mass m at
speed v lasts t_c = 3.2181 (m/k)^(2/5) v^(-1/5) (see tests/forces/test_contact.py), so limit the
step to a small fraction of t_c (``analysis: dynamic: h_max``) when the error control alone
could step over a contact.
"""

from __future__ import annotations

import math

import numpy as np

from mbsim.errors import DeckError
from mbsim.events import Hybrid, Switch
from mbsim.forces import register
from mbsim.forces.base import ForceElement
from mbsim.forces.elements import _body_indices
from mbsim.forces.measures import axis_travel
from mbsim.rotations import cross

RESTITUTION_ALPHA = {  # alpha (s/m) from the coefficient of restitution e and the speed v
    "hunt-crossley": lambda e, v: 3.0 * (1.0 - e) / (2.0 * v),
    "lankarani-nikravesh": lambda e, v: 3.0 * (1.0 - e * e) / (4.0 * v),
    "flores": lambda e, v: 8.0 * (1.0 - e) / (5.0 * e * v),
}


def step(x: float, x0: float, h0: float, x1: float, h1: float) -> float:
    """ADAMS STEP: cubic from (x0, h0) to (x1, h1), constant outside, zero slope at both ends."""
    if x <= x0:
        return h0
    if x >= x1:
        return h1
    s = (x - x0) / (x1 - x0)
    return h0 + (h1 - h0) * s * s * (3.0 - 2.0 * s)


def impact_force(
    g: float, gd: float, k: float, e: float, c_max: float, depth: float | None, alpha: float
) -> tuple[float, float]:
    """(F >= 0, its elastic part k g^e) of the compliant law at penetration g > 0 and
    penetration rate gd: ADAMS IMPACT (c_max, depth) or restitution damping (alpha)."""
    fe = k * g**e
    if alpha:
        f = fe * (1.0 + alpha * gd)
    elif c_max:
        f = fe + step(g, 0.0, 0.0, depth, c_max) * gd
    else:
        f = fe
    return max(f, 0.0), fe


def _damping(el, d: dict, where) -> None:
    """el.c_max, el.depth, el.alpha from the deck fields (c_max and depth, or restitution)."""
    el.c_max = _positive(d, "c_max", where, allow_zero=True)
    el.depth = None if d.get("depth") is None else _positive(d, "depth", where)
    if el.c_max > 0 and el.depth is None:
        raise DeckError("c_max needs depth (the penetration where c reaches c_max)", where)
    el.alpha, el.v_nominal, el.restitution = 0.0, None, None
    el.restitution_law = d.get("restitution_law")
    if d.get("restitution") is not None:
        if el.c_max > 0:
            raise DeckError(
                "give either c_max and depth or restitution, not both",
                where.child("restitution"),
            )
        e = float(d["restitution"])
        if not 0.0 < e <= 1.0:
            raise DeckError(
                f"restitution must lie in (0, 1], got {e:g}", where.child("restitution")
            )
        if d.get("v_impact") is None:
            raise DeckError("restitution needs v_impact (the approach speed it holds at)", where)
        v = _positive(d, "v_impact", where)
        el.v_nominal, el.restitution = v, e
        el.alpha = RESTITUTION_ALPHA[d["restitution_law"]](e, v)


def impact_duration(m: float, k: float, e: float, v: float) -> float:
    """Duration of an undamped impact m g'' = -k g^e at speed v: with energy conservation
    g_max = ((e + 1) m v^2 / (2 k))^(1/(e+1)) and t_c = 2 (g_max / v) int_0^1 du /
    sqrt(1 - u^(e+1)) = 2 (g_max / v) B(1/(e+1), 1/2) / (e + 1) (3.2181 (m/k)^(2/5) v^(-1/5)
    for e = 3/2)."""
    from scipy.special import beta

    g_max = ((e + 1.0) * m * v * v / (2.0 * k)) ** (1.0 / (e + 1.0))
    return 2.0 * g_max / v * beta(1.0 / (e + 1.0), 0.5) / (e + 1.0)


def _reduced_mass(model, bi: int, bj: int, inertia: bool = False) -> float:
    """m_i m_j / (m_i + m_j), ground counted as infinite; ``inertia``: the smallest principal
    moments instead of the masses (for a stop on an angle: the shortest impact, the safe
    step limit)."""
    ms = []
    for b in (bi, bj):
        if model.is_ground[b]:
            continue
        ms.append(
            float(np.linalg.eigvalsh(model.J_local[b]).min()) if inertia else float(model.mass[b])
        )
    return 1.0 / sum(1.0 / m for m in ms) if ms else np.inf


def _duration_note(model, el, inertia=False) -> str:
    m = _reduced_mass(model, el.bi, el.bj, inertia)
    if not np.isfinite(m):
        return ""
    v = getattr(el, "v_nominal", None) or 1.0
    tc = impact_duration(m, el.k, el.e, v)
    speed = f"{v:g} {'rad/s' if inertia else 'm/s'}"
    return f"; an undamped impact at {speed} lasts {tc:.3g} s: keep h_max below {tc / 10:.2g} s"


def hertz_stiffness(E: float, nu: float, R_eff: float) -> float:
    """k = 4/3 E* sqrt(R*) (N/m^1.5), E* = E / (2 (1 - nu^2)) for two bodies of one material."""
    return 4.0 / 3.0 * E / (2.0 * (1.0 - nu * nu)) * np.sqrt(R_eff)


def _positive(d: dict, key: str, where, allow_zero=False) -> float:
    v = float(d[key])
    if v < 0 or (v == 0 and not allow_zero):
        raise DeckError(
            f"{key} must be {'>= 0' if allow_zero else 'positive'}, got {v:g}", where.child(key)
        )
    return v


class Impacts(Hybrid):
    """The part of contact and stop that uses events (:mod:`mbsim.events`): the first touch
    of each impact and its end are events, and the approach speed at the touch is the
    impact's own, so that a restitution law's damping alpha = law(e, v) holds at every
    impact (the deck's ``v_impact`` serves the analyses without events and a contact that
    is closed at t_start).  Modes: None (apart) or :class:`Impact` (in contact since a
    touch at speed v).  The touch is also looked for inside each step (PROBES points of
    the dense output), so that an impact shorter than a step is not stepped over unseen
    once it is under way at one of them."""

    PROBES = 4
    sphere_pair = False  # two spheres (Contact: sphere-sphere): see step_limit

    def _alpha(self, mode) -> float:
        if self.restitution is None or mode is None or not mode.v > 0:
            return self.alpha
        return RESTITUTION_ALPHA[self.restitution_law](self.restitution, mode.v)

    def initial_mode(self, ctx):
        g, gd = self.penetration(ctx.state)
        return Impact(self.v_nominal or 0.0) if g > 0 else None

    def switches(self, mode):
        def pen(ctx):
            return self.penetration(ctx.state)[0]

        if mode is None:
            return [Switch("touch", 1, pen, self.name, probe=self.PROBES)]
        return [Switch("release", -1, pen, self.name)]

    @staticmethod
    def mode_text(mode) -> str:
        return "apart" if mode is None else str(mode)

    def step_limit(self, mode, ctx) -> float:
        """Apart, two spheres could pass through each other inside one step unseen (a
        plane is a half-space and a stop one-sided: their penetration stays positive past
        the touch, so a step's end sees it).  The next step is limited so that at the
        approach speed it carries the spheres at most DEPTH_PAST x the smaller radius past
        the touch (half of that: the speed may grow during the step): a step's end or its
        probes then see every overlap deeper than that."""
        if mode is not None or not self.sphere_pair:
            return math.inf
        g, gd = self.penetration(ctx.state)
        if gd <= 0.0:
            return math.inf
        return 0.5 * (-g + self.DEPTH_PAST * min(self.R, self.Ri)) / gd

    DEPTH_PAST = 0.25

    def next_mode(self, mode, switch, ctx):
        if switch.name == "touch":
            return Impact(max(self.penetration(ctx.state)[1], 0.0))
        return None


class Impact:
    """The mode of a contact or stop in contact: the approach speed v of the touch."""

    __slots__ = ("v",)

    def __init__(self, v):
        self.v = float(v)

    def __eq__(self, other):
        return isinstance(other, Impact) and other.v == self.v

    def __hash__(self):
        return hash(self.v)

    def __str__(self):
        return f"contact at {self.v:.4g}"


@register
class Contact(Impacts, ForceElement):
    type = "contact"
    description = (
        "sphere-plane or sphere-sphere contact, F = k g^e + STEP(g, 0, 0, d, c_max) gd "
        "(ADAMS IMPACT) or restitution damping; Hertz stiffness; regularised friction"
    )

    @classmethod
    def from_spec(cls, spec, body_index):
        el = cls()
        d, where = spec.data, spec.where
        el.bi, el.bj = _body_indices(spec, body_index, 2)
        el.si, el.sj = (
            np.asarray(spec.points[n].P, float).copy() if n in spec.points else np.zeros(3)
            for n in spec.bodies
        )
        el.geometry = d["geometry"]
        el.R = _positive(d, "radius", where)
        el.plane = el.geometry == "sphere-plane"
        el.sphere_pair = not el.plane
        if el.plane:
            if d.get("radius_i") is not None:
                raise DeckError("radius_i goes with sphere-sphere", where.child("radius_i"))
            n = np.array(d.get("normal", (0.0, 0.0, 1.0)), float).reshape(3)
            if not np.linalg.norm(n) > 0:
                raise DeckError("the normal must not be the zero vector", where.child("normal"))
            el.n_local = n / np.linalg.norm(n)
            el.Ri, R_eff = 0.0, el.R
        else:
            if d.get("normal") is not None:
                raise DeckError("normal goes with sphere-plane", where.child("normal"))
            if d.get("radius_i") is None:
                raise DeckError("sphere-sphere needs radius_i (the sphere on body i)", where)
            el.Ri = _positive(d, "radius_i", where)
            R_eff = el.Ri * el.R / (el.Ri + el.R)
        el.e = _positive(d, "exponent", where)
        if (d.get("k") is None) == (d.get("E") is None):
            raise DeckError("give exactly one of k (stiffness) and E (Hertz)", where)
        if d.get("E") is not None:
            if el.e != 1.5:
                raise DeckError(
                    f"a Hertz contact (E) has exponent 1.5, got {el.e:g}", where.child("exponent")
                )
            nu = float(d["nu"])
            if not -1.0 < nu < 0.5:
                raise DeckError(f"nu must lie in (-1, 0.5), got {nu:g}", where.child("nu"))
            el.k = hertz_stiffness(_positive(d, "E", where), nu, R_eff)
        else:
            el.k = _positive(d, "k", where)
        _damping(el, d, where)
        el.mu = _positive(d, "mu", where, allow_zero=True)
        el.v_slip = _positive(d, "v_slip", where)
        return el

    def __repr__(self) -> str:
        return f"<contact {self.name}>"

    def describe(self, model) -> str:
        """One line for ``mbsim info``: the law, and the step limit its impacts need."""
        return f"{self.geometry}, k = {self.k:.4g} N/m^{self.e:g}" + _duration_note(model, self)

    # -- geometry ----------------------------------------------------------------------------
    def geometry_of(self, st):
        """(g, n (3,), C (3,)): penetration (negative: the gap), normal i -> j, contact point."""
        Ai, Aj = st.A[self.bi], st.A[self.bj]
        Pi = st.r[self.bi] + Ai @ self.si
        c = st.r[self.bj] + Aj @ self.sj
        if self.plane:
            n = Ai @ self.n_local
            dist = float(n @ (c - Pi))
            return self.R - dist, n, c - 0.5 * (dist + self.R) * n
        D = c - Pi
        L = float(np.sqrt(D @ D))
        n = D / L if L > 0 else np.array([0.0, 0.0, 1.0])  # coincident centres: any direction
        g = self.Ri + self.R - L
        return g, n, Pi + (self.Ri - 0.5 * g) * n

    def penetration(self, st):
        """(g, gd): penetration and its rate (Impacts)."""
        s = self.state(st, loads=False)
        return s["g"], s["gd"]

    def state(self, st, alpha=None, loads=True):
        """dict: g, gd (penetration rate), n, C (global), fn (normal force >= 0), fe (its
        elastic part), ft (3,) friction on body j, vt (3,) slip velocity; alpha: the
        restitution damping of the current impact (default the deck's)."""
        g, n, C = self.geometry_of(st)
        out = dict(g=g, n=n, C=C, gd=0.0, fn=0.0, fe=0.0, ft=np.zeros(3), vt=np.zeros(3))
        if st.rd is None:
            return out
        bi, bj = self.bi, self.bj
        wi = st.A[bi] @ st.omega_local[bi]
        wj = st.A[bj] @ st.omega_local[bj]
        v = (st.rd[bj] + cross(wj, C - st.r[bj])) - (st.rd[bi] + cross(wi, C - st.r[bi]))
        gd = -float(n @ v)
        vt = v + gd * n
        out.update(gd=gd, vt=vt)
        if g <= 0.0 or not loads:
            return out
        alpha = self.alpha if alpha is None else alpha
        fn, fe = impact_force(g, gd, self.k, self.e, self.c_max, self.depth, alpha)
        out.update(fn=fn, fe=fe)
        s = float(np.sqrt(vt @ vt))
        if self.mu and s > 0:
            out["ft"] = -self.mu * fn * step(s, 0.0, 0.0, self.v_slip, 1.0) / s * vt
        return out

    # -- contract ----------------------------------------------------------------------------
    def apply(self, st, t, F, n_local):
        self.apply_in(None, st, t, None, F, n_local)

    def apply_in(self, mode, st, t, lam, F, n_local):
        s = self.state(st, self._alpha(mode))
        if s["fn"] == 0.0:
            return
        f = s["fn"] * s["n"] + s["ft"]  # on body j at C, the opposite on body i
        C, bi, bj = s["C"], self.bi, self.bj
        F[bj] += f
        F[bi] -= f
        n_local[bj] += st.A[bj].T @ cross(C - st.r[bj], f)
        n_local[bi] -= st.A[bi].T @ cross(C - st.r[bi], f)

    def potential(self, st):
        """k g^(e+1) / (e+1) for g > 0."""
        g, _, _ = self.geometry_of(st)
        return self.k * g ** (self.e + 1.0) / (self.e + 1.0) if g > 0 else 0.0

    def channels(self, st, t):
        return self.channels_in(None, st, t, None)

    def channels_in(self, mode, st, t, lam, modes=None):
        s = self.state(st, self._alpha(mode))
        g = s["g"]
        return {
            "gap": (-g, "m"),
            "penetration": (max(g, 0.0), "m"),
            "penetration_rate": (s["gd"], "m/s"),
            "normal_force": (s["fn"], "N"),
            "friction_force": (s["ft"], "N"),
            "point": (s["C"], "m"),
            "energy": (self.potential(st), "J"),
            "damping_power": ((s["fn"] - s["fe"]) * s["gd"], "W"),
            "friction_power": (-float(s["ft"] @ s["vt"]), "W"),
        }


@register
class JointStop(Impacts, ForceElement):
    """End stops on a joint's travel with the contact's normal law.

    Translational joint: travel s = f_i . (P_j - P_i) (f_i: the joint axis P->Q on body i);
    the load Fs (positive: increases s) acts as the force Fs f_i on body j and -Fs f_i on body
    i, both at P_j (the exact gradient of V(s): the dependence of s on body i's rotation is the
    moment of that force about P_j).  Revolute or cylindrical joint: s = the angle theta of the
    rsda (g_i to g_j about f_i, within pi of the middle of the range, or of lower + pi/2 or
    upper - pi/2 for a one-sided stop) and the torque Fs a on j, -Fs a on i (a: the angle's
    exact gradient axis).

    Penetration g = s - upper above the range (Fs = -F(g, sd)), g = lower - s below it
    (Fs = +F(g, -sd)); F is :func:`impact_force` (k, exponent, c_max/depth or restitution).
    Inside the range the stop carries nothing.  Potential k g^(e+1)/(e+1).
    """

    type = "stop"
    description = (
        "end stops on a translational joint's travel or a revolute/cylindrical joint's angle, "
        "with the contact law (k g^e, STEP-ramped damping or restitution)"
    )

    @classmethod
    def from_spec(cls, spec, body_index):
        from mbsim.forces.measures import Angle
        from mbsim.model import joint_frame

        el = cls()
        d, where = spec.data, spec.where
        el.bi, el.bj = _body_indices(spec, body_index, 2)
        fi, fj = (joint_frame(spec.points.get(n)) for n in spec.bodies)
        el.lower = -np.inf if d.get("lower") is None else float(d["lower"])
        el.upper = np.inf if d.get("upper") is None else float(d["upper"])
        if d.get("lower") is None and d.get("upper") is None:
            raise DeckError("a stop needs lower, upper or both", where)
        if not el.lower < el.upper:
            raise DeckError(
                f"lower must be below upper, got {el.lower:g} >= {el.upper:g}", where.child("lower")
            )
        jtype, motion = d.get("joint_type"), d.get("motion")
        natural = {"translational": "translation", "revolute": "rotation"}.get(jtype)
        if motion is None and natural is None:
            raise DeckError(
                f"a stop on a {jtype} joint needs motion: translation | rotation", where
            )
        if motion is not None and natural is not None and motion != natural:
            raise DeckError(
                f"a {jtype} joint allows only motion: {natural}, got {motion}",
                where.child("motion"),
            )
        el.angular = (motion or natural) == "rotation"
        if el.angular:
            if np.isfinite(el.upper - el.lower) and el.upper - el.lower >= 2 * np.pi:
                raise DeckError("an angle range must be shorter than 2 pi", where.child("upper"))
            # the angle is taken within pi of mid: the middle of the range, or pi/2 inside a
            # one-sided stop, so that a penetration up to pi - (upper - lower)/2 (pi/2) is seen
            if np.isfinite(el.upper - el.lower):
                mid = 0.5 * (el.lower + el.upper)
            elif np.isfinite(el.lower):
                mid = el.lower + 0.5 * np.pi
            else:
                mid = el.upper - 0.5 * np.pi
            el.angle = Angle(el.bi, el.bj, fi, fj, mid)
        else:
            el.si, el.sj, el.f = fi["P"].copy(), fj["P"].copy(), fi["f"].copy()
        el.k = _positive(d, "k", where)
        el.e = _positive(d, "exponent", where)
        _damping(el, d, where)
        return el

    def __repr__(self) -> str:
        return f"<stop {self.name}>"

    def describe(self, model) -> str:
        """One line for ``mbsim info``: the range, and the step limit its impacts need."""
        unit = "rad" if self.angular else "m"
        return f"{self.lower:g} .. {self.upper:g} {unit}, k = {self.k:.4g}" + _duration_note(
            model, self, inertia=self.angular
        )

    def travel(self, st):
        """(s, axis (3,) global, Pj (3,) global or None, sd or None)."""
        if self.angular:
            s, a = self.angle.terms(st)
            return s, a, None, None if st.rd is None else self.angle.rate(st, a)
        s, sd, f, Pj = axis_travel(st, self.bi, self.bj, self.si, self.sj, self.f)
        return s, f, Pj, sd

    def penetration(self, st):
        """(g, gd): penetration beyond the nearer limit (negative inside the range) and its
        rate (Impacts)."""
        s, _, _, sd = self.travel(st)
        sd = 0.0 if sd is None else sd
        if s - self.upper >= self.lower - s:
            return s - self.upper, sd
        return self.lower - s, -sd

    def load(self, st, alpha=None):
        """(s, sd, g (penetration, 0 inside), Fs, elastic part of Fs, axis, Pj); alpha: the
        restitution damping of the current impact (default the deck's)."""
        alpha = self.alpha if alpha is None else alpha
        s, a, Pj, sd = self.travel(st)
        sd0 = 0.0 if sd is None else sd
        Fs = fe = g = 0.0
        if s > self.upper:
            g = s - self.upper
            F, f_el = impact_force(g, sd0, self.k, self.e, self.c_max, self.depth, alpha)
            Fs, fe = -F, -f_el
        elif s < self.lower:
            g = self.lower - s
            F, f_el = impact_force(g, -sd0, self.k, self.e, self.c_max, self.depth, alpha)
            Fs, fe = F, f_el
        return s, sd0, g, Fs, fe, a, Pj

    def apply(self, st, t, F, n_local):
        self.apply_in(None, st, t, None, F, n_local)

    def apply_in(self, mode, st, t, lam, F, n_local):
        _, _, g, Fs, _, a, Pj = self.load(st, self._alpha(mode))
        if Fs == 0.0:
            return
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

    def potential(self, st):
        s = self.travel(st)[0]
        g = max(s - self.upper, self.lower - s, 0.0)
        return self.k * g ** (self.e + 1.0) / (self.e + 1.0) if g > 0 else 0.0

    def channels(self, st, t):
        return self.channels_in(None, st, t, None)

    def channels_in(self, mode, st, t, lam, modes=None):
        s, sd, g, Fs, fe, _, _ = self.load(st, self._alpha(mode))
        unit = "rad" if self.angular else "m"
        return {
            "travel": (s, unit),
            "penetration": (g, unit),
            "load": (Fs, "N m" if self.angular else "N"),
            "energy": (self.potential(st), "J"),
            "damping_power": (-(Fs - fe) * sd, "W"),
        }
