"""Models with known answers for the dynamics tests, built as specs (no YAML).

Each builder returns a compiled Model; ``consistent_state`` turns given velocities into a
state on the constraint manifold, so that the tests do not depend on the initial-condition
analysis.  ``Tsda`` is a local translational spring-damper (Haug Sec. 11.5) used where the
deck registry's ``tsda`` may not exist yet; it follows the ForceElement contract.
"""

from __future__ import annotations

import dataclasses
import functools

import numpy as np

from mbsim.analyses.assembly import assemble
from mbsim.deck.spec import ForceSpec
from mbsim.model import compile_model
from mbsim.rotations import from_axis_angle, omega_to_pd
from tests.helpers import body, joint, pts, slider_crank_spec, spec
from tests.reference import equations as eq


def tsda(name, bi, bj, si=(0, 0, 0), sj=(0, 0, 0), k=0.0, c=0.0, L0=0.0):
    """A registry ``tsda`` force element spec between body points (Haug Sec. 11.3)."""
    return ForceSpec(
        name,
        "tsda",
        (bi, bj),
        {bi: pts(si), bj: pts(sj)},
        {"k": float(k), "c": float(c), "L0": float(L0)},
    )


def with_forces(model, *forces):
    return dataclasses.replace(model, forces=tuple(model.forces) + tuple(forces))


def consistent_state(model, q=None, omega=None, rdot=None, t=0.0):
    """Assemble q and find qd with Phi_q qd = nu and the given body velocities.

    omega, rdot: {body name: (3,) global vector}.  The given values are stacked under the
    velocity equations and solved in least squares; the result satisfies both when they are
    consistent (a test then checks Phi_q qd = nu to round-off)."""
    asm = assemble(model, q, t, tol=1e-14)  # to round-off: the references start exactly here
    q = asm.q
    T = eq.constraints(model, q, t, nu=True)
    rows, rhs = [T.jac[asm.active_rows]], [T.nu[asm.active_rows]]
    for name, w in (omega or {}).items():
        b = model.body_index(name)
        p = q[7 * b + 3 : 7 * b + 7]
        R = np.zeros((3, model.nq))
        # omega = 2 E(p) pd (Haug eq. 6.3.17)
        from mbsim.rotations import E

        R[:, 7 * b + 3 : 7 * b + 7] = 2 * E(p)
        rows.append(R)
        rhs.append(np.asarray(w, float))
    for name, v in (rdot or {}).items():
        b = model.body_index(name)
        R = np.zeros((3, model.nq))
        R[:, 7 * b : 7 * b + 3] = np.eye(3)
        rows.append(R)
        rhs.append(np.asarray(v, float))
    qd = np.linalg.lstsq(np.vstack(rows), np.concatenate(rhs), rcond=None)[0]
    return q, qd


# ---------------------------------------------------------------- the models


def free_body(J=(1.0, 2.0, 3.0), mass=2.0):
    """One asymmetric free body, no joints, no ground: only its normalisation row."""
    return compile_model(spec([body("b", mass, J)]))


def top(m=1.0, l=0.1, I1c=2e-3, I3=4e-3, g=9.81):
    """Symmetric top: spherical joint between the ground origin and the tip (0, 0, -l) of
    the body; symmetry axis z'; gravity -z."""
    bodies = [body("ground", ground=True), body("top", m, (I1c, I1c, I3), (0, 0, l))]
    joints = [
        joint(
            "tip", "spherical", "ground", "top", {"ground": pts((0, 0, 0)), "top": pts((0, 0, -l))}
        )
    ]
    return compile_model(spec(bodies, joints, gravity=(0, 0, -g)))


def top_state(model, theta, omega3, l=0.1, g=9.81):
    """Steady-precession initial state at nutation angle theta, spin omega3 = e3 . omega.

    Closed form (Goldstein Sec. 5.7): m g l = Omega (I3 omega3 - I1 Omega cos theta), I1 about
    the tip; the slow root is returned with the state."""
    m = model.mass[1]
    I1 = model.J_local[1, 0, 0] + m * l * l
    I3 = model.J_local[1, 2, 2]
    a, b, c = I1 * np.cos(theta), -I3 * omega3, m * g * l
    Om = (-b - np.sqrt(b * b - 4 * a * c)) / (2 * a)  # slow precession
    p = from_axis_angle((1, 0, 0), theta)  # symmetry axis tilted by theta towards -y
    from mbsim.rotations import A as rot_A

    e3 = rot_A(p)[:, 2]
    # omega = Omega z + psid e3 with e3 . omega = omega3
    psid = omega3 - Om * e3[2]
    w = Om * np.array([0, 0, 1.0]) + psid * e3
    q = model.q0.copy()
    q[10:14] = p
    q[7:10] = l * e3
    qd = np.zeros(model.nq)
    qd[7:10] = np.cross(w, l * e3)
    qd[10:14] = omega_to_pd(p, w)
    return q, qd, Om


def slider_crank(ell=0.3, g=9.81):
    """Undriven spatial slider-crank, reference geometry §1 (tests/helpers.py)."""
    return compile_model(slider_crank_spec(ell, driven=False, g=g))


def slider_crank_state(model, omega0):
    """Crank spinning at omega0 about -x (reference §1.5), the rest from the velocity equations."""
    return consistent_state(model, omega={"crank": (-omega0, 0, 0)})


GOVERNOR_OMEGA = 11.0174  # rad/s, Haug Sec. 12.6.2


def governor(g=9.80, k=1000.0, c=30.0, L0=0.15):
    """Flyball governor, Haug Tables 12.6.1-12.6.6 (Ball 1 e3 = -0.3827: typo fixed, reference
    geometry §4 #1); y up, gravity -y; TSDA between spindle and collar origins."""
    bodies = [
        body("ground", ground=True),
        body("spindle", 200.0, (25.0, 50.0, 25.0), (0, 0.2, 0)),
        body("ball1", 1.0, (0.1, 0.1, 0.1), (0.11314, 0.08686, 0), (0.9239, 0, 0, -0.3827)),
        body("ball2", 1.0, (0.1, 0.1, 0.1), (-0.11314, 0.08686, 0), (0.9239, 0, 0, 0.3827)),
        body("collar", 1.0, (0.15, 0.125, 0.15), (0, 0.05, 0)),
    ]
    P0 = (0, 0, 0)
    joints = [
        joint(
            "DIST1",
            "distance",
            "ball1",
            "collar",
            {"ball1": pts((-0.08, 0, 0)), "collar": pts(P0)},
            distance=0.10922,
        ),
        joint(
            "DIST2",
            "distance",
            "ball2",
            "collar",
            {"ball2": pts((0.08, 0, 0)), "collar": pts(P0)},
            distance=0.10922,
        ),
        joint(
            "REV1",
            "revolute",
            "ground",
            "spindle",
            {
                "ground": pts(P0, (0, 1, 0), (0, 0, 1)),
                "spindle": pts((0, -0.2, 0), (0, -1.2, 0), (0, -0.2, 1)),
            },
        ),
        joint(
            "REV2",
            "revolute",
            "spindle",
            "ball1",
            {
                "spindle": pts(P0, (0, 0, 1), (1, 0, 0)),
                "ball1": pts((-0.16, 0, 0), (-0.16, 0, 1), (1, 0, 0)),
            },
        ),
        joint(
            "REV3",
            "revolute",
            "spindle",
            "ball2",
            {
                "spindle": pts(P0, (0, 0, 1), (1, 0, 0)),
                "ball2": pts((0.16, 0, 0), (0.16, 0, 1), (1, 0, 0)),
            },
        ),
        joint(
            "TRANS1",
            "translational",
            "spindle",
            "collar",
            {"spindle": pts(P0, (0, 1, 0), (0, 0, 1)), "collar": pts(P0, (0, 1, 0), (0, 0, 1))},
        ),
    ]
    forces = [tsda("spring", "spindle", "collar", k=k, c=c, L0=L0)]
    return compile_model(spec(bodies, joints, forces=forces, gravity=(0, -g, 0)))


def governor_state(model, omega=GOVERNOR_OMEGA):
    """Steady state of Table 12.6.6: every body turning with the spindle about y."""
    w = np.array([0.0, omega, 0.0])
    asm = assemble(model)
    q = asm.q
    qd = np.zeros(model.nq)
    for b in range(1, model.nb):
        r, p = q[7 * b : 7 * b + 3], q[7 * b + 3 : 7 * b + 7]
        qd[7 * b : 7 * b + 3] = np.cross(w, r)
        qd[7 * b + 3 : 7 * b + 7] = omega_to_pd(p, w)
    return q, qd


def chain(n, g=9.81, angle=0.3):
    """Spherical chain (benchmark spec): link i, 1 kg, 0.5 m, rod axis y', J' = diag(1/48, 1e-4,
    1/48), joint points (0, +-0.25, 0); link i rotated `angle` about (cos phi_i, 0, sin phi_i),
    phi_i = 2 pi i / n, about its top joint (the chain hangs from the origin)."""
    bodies = [body("ground", ground=True)]
    joints = []
    top = np.zeros(3)
    from mbsim.rotations import A as rot_A

    for i in range(n):
        ph = 2 * np.pi * i / n
        p = from_axis_angle((np.cos(ph), 0, np.sin(ph)), angle)
        Ai = rot_A(p)
        r = top - Ai @ np.array([0, 0.25, 0])
        bodies.append(body(f"link{i}", 1.0, (1 / 48, 1e-4, 1 / 48), r, p))
        prev = "ground" if i == 0 else f"link{i - 1}"
        Pprev = (0, 0, 0) if i == 0 else (0, -0.25, 0)
        joints.append(
            joint(
                f"S{i}",
                "spherical",
                prev,
                f"link{i}",
                {prev: pts(Pprev), f"link{i}": pts((0, 0.25, 0))},
            )
        )
        top = r + Ai @ np.array([0, -0.25, 0])
    return compile_model(spec(bodies, joints, gravity=(0, -g, 0)))


# ------------------------------------------- issue 11: problems with independent references


def top_spinning_state(model, theta, omega3, l=0.1):
    """Heavy top released with spin only: symmetry axis tilted by theta about x, angular
    velocity omega3 e3 (no precession rate), so it nutates (the "fast heavy top" of issue 11
    with omega3 ~ 150 rad/s)."""
    from mbsim.rotations import A as rot_A

    p = from_axis_angle((1, 0, 0), theta)
    e3 = rot_A(p)[:, 2]
    q = model.q0.copy()
    q[10:14] = p
    q[7:10] = l * e3
    return consistent_state(model, q, omega={"top": omega3 * e3})


PENDULUM = {"L": 0.5, "m": 1.0, "Ic": 0.01, "g": 9.81}
PENDULUM_THETA0 = np.radians(150.0)


def pendulum(L=0.5, m=1.0, Ic=0.01, g=9.81, theta0=PENDULUM_THETA0):
    """Planar compound pendulum "bob": revolute about global z at the origin (body point
    (0, L, 0) above its centroid), centroidal moment Ic about z, gravity -y; started at rest
    at theta0 from the downward vertical."""
    p0 = from_axis_angle((0, 0, 1), theta0)
    r0 = (L * np.sin(theta0), -L * np.cos(theta0), 0.0)
    bodies = [body("ground", ground=True), body("bob", m, (Ic, Ic, Ic), r0, p0)]
    joints = [
        joint("pivot", "revolute", "ground", "bob",
              {"ground": pts((0, 0, 0), (0, 0, 1), (1, 0, 0)),
               "bob": pts((0, L, 0), (0, L, 1))})
    ]
    return compile_model(spec(bodies, joints, gravity=(0, -g, 0)))


FOURBAR = {"L": 0.2, "m_crank": 0.5, "M": 2.0, "spacing": 0.3, "g": 9.81}


def fourbar_crank_inertia(L=0.2, m_crank=0.5):
    """Centroidal moments of a crank: a slender bar along x' (m L^2 / 12 about y', z')."""
    return (1e-4, m_crank * L * L / 12, m_crank * L * L / 12)


def parallel_fourbar_parts(N=4, theta0=-np.pi / 2, L=0.2, m_crank=0.5, M=2.0, spacing=0.3,
                           mount="ground"):
    """(bodies, joints) of :func:`parallel_fourbar` without the ground: the N cranks, the
    coupler and the 2N revolutes, the pivots G<i> on the body ``mount``."""
    xs = [i * spacing for i in range(N)]
    xbar = float(np.mean(xs))
    c, s = np.cos(theta0), np.sin(theta0)
    p0 = from_axis_angle((0, 0, 1), theta0)
    Jc = fourbar_crank_inertia(L, m_crank)
    W = xs[-1] - xs[0]
    bodies = [body(f"crank{i}", m_crank, Jc, (x + L / 2 * c, L / 2 * s, 0), p0)
              for i, x in enumerate(xs)]
    bodies.append(body("coupler", M, (1e-3, M * W * W / 12, M * W * W / 12 + 1e-3),
                       (xbar + L * c, L * s, 0)))
    joints = []
    for i, x in enumerate(xs):
        joints.append(joint(f"G{i}", "revolute", mount, f"crank{i}",
                            {mount: pts((x, 0, 0), (x, 0, 1), (x + 1, 0, 0)),
                             f"crank{i}": pts((-L / 2, 0, 0), (-L / 2, 0, 1))}))
        joints.append(joint(f"C{i}", "revolute", f"crank{i}", "coupler",
                            {f"crank{i}": pts((L / 2, 0, 0), (L / 2, 0, 1), (L / 2 + 1, 0, 0)),
                             "coupler": pts((x - xbar, 0, 0), (x - xbar, 0, 1))}))
    return bodies, joints


def parallel_fourbar(N=4, theta0=-np.pi / 2, L=0.2, m_crank=0.5, M=2.0, spacing=0.3, g=9.81):
    """N parallel cranks (N >= 2, N - 1 four-bar loops) carrying one coupler: crank<i>
    turns about global z on revolute G<i> at (x_i, 0, 0), x_i = i spacing; its tip carries
    the coupler on revolute C<i>.  All revolute axes along z, gravity -y in the plane.  Every
    crank after the second adds 4 redundant equations in 3-D; at theta = 0, pi (cranks
    along the ground line) the constraint Jacobian loses one more rank (singular position).
    Started at crank angle theta0 (all cranks parallel, coupler level)."""
    bodies, joints = parallel_fourbar_parts(N, theta0, L, m_crank, M, spacing)
    return compile_model(spec([body("ground", ground=True)] + bodies, joints,
                              gravity=(0, -g, 0)))


def parallel_fourbar_motion(model, th, thd, thdd, base=(0.0, 0.0, 0.0), direction=(1, 0, 0)):
    """q, qd, qdd of the linkage of FOURBAR's data (parallel_fourbar_parts) at crank angle th,
    rate thd and acceleration thdd: the cranks turned by th about z with their pivots at
    (x_i, 0, 0), the coupler translating on a circle of radius L; every body but the ground
    moved by base = (s, s', s'') along ``direction`` (a mount that slides)."""
    L, xs = FOURBAR["L"], [i * FOURBAR["spacing"] for i in range(4)]
    d = np.asarray(direction, float)
    s0, s1, s2 = base
    q, qd, qdd = (np.zeros(model.nq) for _ in range(3))
    c, s = np.cos(th), np.sin(th)
    for b, name in enumerate(model.body_names):
        o = 7 * b
        q[o + 3] = 1.0
        if name == "ground":
            continue
        q[o:o + 3], qd[o:o + 3], qdd[o:o + 3] = s0 * d, s1 * d, s2 * d
        if not (name == "coupler" or name.startswith("crank")):
            continue
        x0, f = (np.mean(xs), L) if name == "coupler" else (xs[int(name[-1])], L / 2)
        q[o:o + 3] += (x0 + f * c, f * s, 0)
        qd[o:o + 3] += (-f * s * thd, f * c * thd, 0)
        qdd[o:o + 3] += (-f * (s * thdd + c * thd ** 2), f * (c * thdd - s * thd ** 2), 0)
        if name != "coupler":
            e = np.array([np.cos(th / 2), 0, 0, np.sin(th / 2)])
            de = np.array([-np.sin(th / 2), 0, 0, np.cos(th / 2)])
            q[o + 3:o + 7] = e
            qd[o + 3:o + 7] = 0.5 * thd * de
            qdd[o + 3:o + 7] = 0.5 * thdd * de - 0.25 * thd ** 2 * e
    return q, qd, qdd


def parallel_fourbar_reference(t, thetad0=20.0, theta0=-np.pi / 2, N=4):
    """The exact one-DOF reduction (references.parallel_fourbar) of the linkage of FOURBAR's
    data, which is also models/parallel_fourbar.yaml's, from crank angle theta0 at rate
    thetad0: {body: (r, A)} and ``theta`` at the times t."""
    from tests.integrators import references as R

    P = FOURBAR
    return R.parallel_fourbar(t, theta0, thetad0, N, P["L"], P["m_crank"],
                              fourbar_crank_inertia(P["L"], P["m_crank"])[2], P["M"], P["g"],
                              [i * P["spacing"] for i in range(N)])


def parallel_fourbar_state(model, thetad0):
    """Consistent state with every crank turning at thetad0 about +z."""
    return consistent_state(model, omega={"crank0": (0, 0, thetad0)})


@dataclasses.dataclass(frozen=True)
class Problem:
    """A dynamics problem with an independent reference (tests/integrators/references.py):
    model, consistent initial state, run length and output step, and ``reference(t)`` ->
    {body: (r (nt, 3), A (nt, 3, 3))}.  rotating: orientation errors are part of the check;
    moving: positions change (False for the free body, whose uniform motion any integrator
    reproduces to round-off)."""

    name: str
    model: object
    q0: np.ndarray
    qd0: np.ndarray
    t_end: float
    step: float
    reference: object
    rotating: bool = True
    moving: bool = True


def _memo(fn):
    """fn(t) cached by the output times: the references integrate at rtol 1e-13 in Python
    (seconds for the heavy top), and every test of a problem asks for the same times."""
    cache = {}

    def wrapped(t):
        key = np.round(np.asarray(t, float), 12).tobytes()
        if key not in cache:
            cache[key] = fn(np.asarray(t, float))
        return cache[key]

    return wrapped


@functools.lru_cache(maxsize=None)
def reference_problem(name):
    """The five reference problems of issue 11 by name (see REFERENCE_PROBLEMS), built once."""
    pb = _reference_problem(name)
    return dataclasses.replace(pb, reference=_memo(pb.reference))


def _reference_problem(name):
    from tests.integrators import references as R

    if name == "free_body":
        J, w0, v0 = (1.0, 2.0, 3.0), (0.4, 0.2, 1.0), (0.1, -0.2, 0.3)
        model = free_body(J=J)
        q = model.q0.copy()
        qd = np.zeros(7)
        qd[:3] = v0
        qd[3:] = omega_to_pd(q[3:], w0)  # p = (1, 0, 0, 0): global = body frame
        ref = functools.partial(R.free_body, J=J, p0=q[3:], pd0=qd[3:], r0=q[:3], v0=qd[:3])
        return Problem(name, model, q, qd, 10.0, 0.1, ref, moving=False)
    if name == "heavy_top":
        model = top()
        q, qd = top_spinning_state(model, np.radians(30.0), 150.0)
        ref = functools.partial(R.heavy_top, m=1.0, l=0.1, I1c=2e-3, I3=4e-3, g=9.81,
                                p0=q[10:14], pd0=qd[10:14])
        return Problem(name, model, q, qd, 2.0, 0.01, ref)
    if name == "pendulum":
        P = PENDULUM
        model = pendulum(**P)
        q, qd = consistent_state(model)
        ref = functools.partial(R.pendulum, theta0=np.radians(150.0), L=P["L"], m=P["m"],
                                Ic=P["Ic"], g=P["g"])
        return Problem(name, model, q, qd, 3.0, 0.01, ref)
    if name == "slider_crank":
        from mbsim.rotations import A as rot_A

        model = slider_crank()
        q, qd = slider_crank_state(model, 2 * np.pi)
        c, r = 7 * model.body_index("crank"), 7 * model.body_index("rod")
        phi0 = 2 * np.arctan2(q[c + 4], q[c + 3])  # crank p = (cos phi/2, sin phi/2, 0, 0)
        A_rod0 = rot_A(q[r + 3 : r + 7])
        ref = functools.partial(R.slider_crank, phi0=phi0, phid0=-2 * np.pi, A_rod0=A_rod0)
        return Problem(name, model, q, qd, 1.0, 0.01, ref)
    if name == "parallel_fourbar":
        model = parallel_fourbar(4)
        q, qd = parallel_fourbar_state(model, 20.0)
        ref = functools.partial(parallel_fourbar_reference, thetad0=20.0)
        return Problem(name, model, q, qd, 1.0, 0.01, ref)
    raise KeyError(name)


REFERENCE_PROBLEMS = ("free_body", "heavy_top", "pendulum", "slider_crank", "parallel_fourbar")
