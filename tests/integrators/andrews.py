"""Andrews' squeezing mechanism in the test set's own minimal coordinates: an independent
reference for models/andrews.yaml.

The seven angles y = (beta, theta, gamma, phi, delta, Omega, epsilon) with the six loop
constraints g(y) = 0 and M(y) y'' = f(y, y') - g_y^T lam (Hairer & Wanner, Solving ODEs II,
Sec. VII.7, eqs. 7.4-7.11; the Bari Test Set for IVP Solvers, problem ``andrews``).  Nothing
here uses mbsim: the equations are the test set's, the body positions follow from the angles
by plane trigonometry, and :data:`Y_REF` is the test set's published solution at t = 0.03 s
(PSIDE at rtol = atol = 1e-14, Cray double precision).  :func:`reference` integrates the same
equations as an index-1 ODE (the constraints differentiated twice, the Lagrange multipliers
from the augmented system) with scipy's DOP853 at rtol 1e-13; it meets :data:`Y_REF` to
about 1e-12 rad in every angle (test_andrews_reference_meets_the_test_set).
"""

from __future__ import annotations

import numpy as np
from scipy.integrate import solve_ivp

P = dict(m1=0.04325, m2=0.00365, m3=0.02373, m4=0.00706, m5=0.07050, m6=0.00706, m7=0.05498,
         xa=-0.06934, ya=-0.00227, xb=-0.03635, yb=0.03273, xc=0.014, yc=0.072, c0=4530.0,
         i1=2.194e-6, i2=4.410e-7, i3=5.255e-6, i4=5.667e-7, i5=1.169e-5, i6=5.667e-7,
         i7=1.912e-5, d=28e-3, da=115e-4, e=2e-2, ea=1421e-5, rr=7e-3, ra=92e-5, l0=7785e-5,
         ss=35e-3, sa=1874e-5, sb=1043e-5, sc=18e-3, sd=2e-2, ta=2308e-5, tb=916e-5, u=4e-2,
         ua=1228e-5, ub=449e-5, zf=2e-2, zt=4e-2, fa=1421e-5, mom=33e-3)
"""The test set's parameters (SI)."""

Y0 = np.array([-0.0617138900142764496358948458001, 0.0, 0.455279819163070380255912382449,
               0.222668390165885884674473185609, 0.487364979543842550225598953530,
               -0.222668390165885884674473185609, 1.23054744454982119249735015568])
"""(7,) the consistent initial angles, rad (at rest)."""

T_REF = 0.03
Y_REF = np.array([0.1581077119629904e2, -0.1575637105984298e2, 0.4082224013073101e-1,
                  -0.5347301163226948, 0.5244099658805304, 0.5347301163226948,
                  0.1048080741042263e1])
"""(7,) the angles at T_REF published with the test set (its ``andsoln``), rad."""

BODIES = ("K1", "K2", "K3", "K4", "K5", "K6", "K7")


def _mass_force_constraints(y, yd):
    """M (7, 7), f (7,), g_y (6, 7), h (6,) with g_y y'' + h = d2g/dt2 (test set andfunc)."""
    p = P
    be, th, ga, ph, de, om, ep = y
    bep, thp, gap, php, dep, omp, epp = yd
    bt, pd, oe = be + th, ph + de, om + ep
    btp, pdp, oep = bep + thp, php + dep, omp + epp
    m1, m2, m3, m4, m5, m6, m7 = (p[f"m{i}"] for i in range(1, 8))
    i1, i2, i3, i4, i5, i6, i7 = (p[f"i{i}"] for i in range(1, 8))
    rr, d, da, ra, e, ea, zt = p["rr"], p["d"], p["da"], p["ra"], p["e"], p["ea"], p["zt"]
    zf, fa, u, ss = p["zf"], p["fa"], p["u"], p["ss"]
    M = np.zeros((7, 7))
    M[0, 0] = m1 * ra**2 + m2 * (rr**2 - 2 * da * rr * np.cos(th) + da**2) + i1 + i2
    M[1, 0] = M[0, 1] = m2 * (da**2 - da * rr * np.cos(th)) + i2
    M[1, 1] = m2 * da**2 + i2
    M[2, 2] = m3 * (p["sa"] ** 2 + p["sb"] ** 2) + i3
    M[3, 3] = m4 * (e - ea) ** 2 + i4
    M[4, 3] = M[3, 4] = m4 * ((e - ea) ** 2 + zt * (e - ea) * np.sin(ph)) + i4
    M[4, 4] = (m4 * (zt**2 + 2 * zt * (e - ea) * np.sin(ph) + (e - ea) ** 2)
               + m5 * (p["ta"] ** 2 + p["tb"] ** 2) + i4 + i5)
    M[5, 5] = m6 * (zf - fa) ** 2 + i6
    M[6, 5] = M[5, 6] = m6 * ((zf - fa) ** 2 - u * (zf - fa) * np.sin(om)) + i6
    M[6, 6] = (m6 * ((zf - fa) ** 2 - 2 * u * (zf - fa) * np.sin(om) + u**2)
               + m7 * (p["ua"] ** 2 + p["ub"] ** 2) + i6 + i7)
    xd = p["sd"] * np.cos(ga) + p["sc"] * np.sin(ga) + p["xb"]
    yd_ = p["sd"] * np.sin(ga) - p["sc"] * np.cos(ga) + p["yb"]
    lang = np.hypot(xd - p["xc"], yd_ - p["yc"])
    force = -p["c0"] * (lang - p["l0"]) / lang
    fx, fy = force * (xd - p["xc"]), force * (yd_ - p["yc"])
    f = np.array([
        p["mom"] - m2 * da * rr * thp * (thp + 2 * bep) * np.sin(th),
        m2 * da * rr * bep**2 * np.sin(th),
        fx * (p["sc"] * np.cos(ga) - p["sd"] * np.sin(ga))
        + fy * (p["sd"] * np.cos(ga) + p["sc"] * np.sin(ga)),
        m4 * zt * (e - ea) * dep**2 * np.cos(ph),
        -m4 * zt * (e - ea) * php * (php + 2 * dep) * np.cos(ph),
        -m6 * u * (zf - fa) * epp**2 * np.cos(om),
        m6 * u * (zf - fa) * omp * (omp + 2 * epp) * np.cos(om)])
    G = np.zeros((6, 7))
    cb, sbe, cbt, sbt = np.cos(be), np.sin(be), np.cos(bt), np.sin(bt)
    for r in (0, 2, 4):
        G[r, 0], G[r, 1] = -rr * sbe + d * sbt, d * sbt
        G[r + 1, 0], G[r + 1, 1] = rr * cb - d * cbt, -d * cbt
    G[0, 2], G[1, 2] = -ss * np.cos(ga), -ss * np.sin(ga)
    G[2, 3] = -e * np.cos(pd)
    G[2, 4] = -e * np.cos(pd) + zt * np.sin(de)
    G[3, 3] = -e * np.sin(pd)
    G[3, 4] = -e * np.sin(pd) - zt * np.cos(de)
    G[4, 5] = zf * np.sin(oe)
    G[4, 6] = zf * np.sin(oe) - u * np.cos(ep)
    G[5, 5] = -zf * np.cos(oe)
    G[5, 6] = -zf * np.cos(oe) - u * np.sin(ep)
    # the velocity-squared part of d2g/dt2 (g of the test set, differentiated twice)
    hx = -rr * cb * bep**2 + d * cbt * btp**2
    hy = -rr * sbe * bep**2 + d * sbt * btp**2
    h = np.array([
        hx + ss * np.sin(ga) * gap**2, hy - ss * np.cos(ga) * gap**2,
        hx + e * np.sin(pd) * pdp**2 + zt * np.cos(de) * dep**2,
        hy - e * np.cos(pd) * pdp**2 + zt * np.sin(de) * dep**2,
        hx + zf * np.cos(oe) * oep**2 + u * np.sin(ep) * epp**2,
        hy + zf * np.sin(oe) * oep**2 - u * np.cos(ep) * epp**2])
    return M, f, G, h


def constraints(y):
    """(6,) g(y) of the test set (m): point E of K2 on K3, K4 and K6."""
    p = P
    be, th, ga, ph, de, om, ep = y
    ex = p["rr"] * np.cos(be) - p["d"] * np.cos(be + th)
    ey = p["rr"] * np.sin(be) - p["d"] * np.sin(be + th)
    return np.array([
        ex - p["ss"] * np.sin(ga) - p["xb"], ey + p["ss"] * np.cos(ga) - p["yb"],
        ex - p["e"] * np.sin(ph + de) - p["zt"] * np.cos(de) - p["xa"],
        ey + p["e"] * np.cos(ph + de) - p["zt"] * np.sin(de) - p["ya"],
        ex - p["zf"] * np.cos(om + ep) - p["u"] * np.sin(ep) - p["xa"],
        ey - p["zf"] * np.sin(om + ep) + p["u"] * np.cos(ep) - p["ya"]])


def rhs(t, z):
    """z = (y, y') (14,): the index-1 ODE, y'' and lam from [M g_y^T; g_y 0]."""
    y, yd = z[:7], z[7:]
    M, f, G, h = _mass_force_constraints(y, yd)
    K = np.zeros((13, 13))
    K[:7, :7], K[:7, 7:], K[7:, :7] = M, G.T, G
    ydd = np.linalg.solve(K, np.concatenate([f, -h]))[:7]
    return np.concatenate([yd, ydd])


def solve(t_eval, rtol=1e-13):
    """(len(t_eval), 7) angles at t_eval (from 0, sorted) by DOP853 at rtol, atol = rtol."""
    sol = solve_ivp(rhs, (0.0, float(t_eval[-1])), np.concatenate([Y0, np.zeros(7)]),
                    method="DOP853", rtol=rtol, atol=rtol, t_eval=t_eval)
    assert sol.success, sol.message
    return sol.y[:7].T


def centroids(y):
    """{body: (3,) centroid} of models/andrews.yaml's bodies at the angles y (m): the deck's
    placement of the centroids (its comments), by plane trigonometry."""
    p = P
    be, th, ga, ph, de, om, ep = y
    bt, pd, oe = be + th, ph + de, om + ep
    A, B = np.array([p["xa"], p["ya"]]), np.array([p["xb"], p["yb"]])

    def along(a, x, yy):  # R(a) (x, y)
        return np.array([x * np.cos(a) - yy * np.sin(a), x * np.sin(a) + yy * np.cos(a)])

    Pp = along(be, p["rr"], 0.0)
    F = A + along(de, p["zt"], 0.0)
    Gp = A + along(ep, 0.0, -p["u"])
    c = {"K1": along(be, p["ra"], 0.0),
         "K2": Pp - along(bt, p["da"], 0.0),
         "K3": B + along(ga, p["sa"], p["sb"]),
         "K4": F + along(pd, 0.0, -(p["e"] - p["ea"])),
         "K5": A + along(de, p["ta"], p["tb"]),
         "K6": Gp + along(oe, p["zf"] - p["fa"], 0.0),
         "K7": A + along(ep, p["ua"], p["ub"])}
    return {b: np.array([x[0], x[1], 0.0]) for b, x in c.items()}


def position_error(res, y, k=-1):
    """max over the bodies of |r_mbsim - r_ref| (m) at output k of a Result, y the angles."""
    ref = centroids(y)
    return max(float(np.linalg.norm(res.channel(f"bodies/{b}/r").data[k] - ref[b]))
               for b in BODIES)
