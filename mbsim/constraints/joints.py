"""Joint and driver types: each written once, as a composition of basic constraints.

Contract of a joint type (class data, no per-type branches elsewhere):

1. ``type``: the deck name; ``n_eq``: number of equations.
2. ``needs``: the points each body must give, e.g. ``('PQR', 'PQ')`` for (body i, body j);
   ``None`` for body j of a one-body constraint.
3. ``rows``: a tuple of basic rows ``(kernel, args)``.  ``args`` map a kernel argument to a
   frame vector of the joint: ``P_i``/``P_j`` (the joint points), ``f_i``, ``g_i``, ``h_i``,
   ``f_j``, ... (unit vectors: f = P->Q, g = P->R orthogonalised, h = f x g).
4. ``target``: 'distance' when the rows' target is the deck's ``distance`` squared; None for 0.

Drivers reuse the frames of a joint (rotation, translation) or their own points (distance,
absolute); the target is the driver's function of time.  ``dphi_dx`` gives dPhi/dx for the
driven measure x, to turn a multiplier into the driver's force or torque (effort = -lam dPhi/dx).
"""

from __future__ import annotations

SPH = ("spherical", {"si": "P_i", "sj": "P_j"})


def D1(a, b):
    return ("dot1", {"ai": a, "aj": b})


def D2(a):
    return ("dot2", {"a": a, "si": "P_i", "sj": "P_j"})


class Joint:
    type = ""
    n_eq = 0
    needs: tuple[str, str | None] = ("P", "P")
    rows: tuple = ()
    target: str | None = None
    description = ""


class Spherical(Joint):
    type, n_eq, needs = "spherical", 3, ("P", "P")
    rows = (SPH,)
    description = "ball joint: P_i = P_j (Haug eq. 9.4.1)"


class Universal(Joint):
    type, n_eq, needs = "universal", 4, ("PQ", "PQ")
    rows = (SPH, D1("f_i", "f_j"))
    description = "spherical + cross arms P->Q perpendicular (Haug eq. 9.4.9)"


class Revolute(Joint):
    type, n_eq, needs = "revolute", 5, ("PQR", "PQ")
    rows = (SPH, D1("g_i", "f_j"), D1("h_i", "f_j"))
    description = "spherical + axes P->Q parallel (Haug eq. 9.4.13)"


class Cylindrical(Joint):
    type, n_eq, needs = "cylindrical", 4, ("PQR", "PQ")
    rows = (D1("g_i", "f_j"), D1("h_i", "f_j"), D2("g_i"), D2("h_i"))
    description = "axes parallel and P_j on the axis of i (Haug eq. 9.4.6)"


class Translational(Joint):
    type, n_eq, needs = "translational", 5, ("PQR", "PQR")
    rows = Cylindrical.rows + (D1("g_i", "h_j"),)
    description = "cylindrical + no relative rotation about the axis (Haug eq. 9.4.15)"


class RevoluteSpherical(Joint):
    type, n_eq, needs = "revolute-spherical", 2, ("PQ", "P")
    rows = (D2("f_i"), ("distance", {"si": "P_i", "sj": "P_j"}))
    target = "distance"
    description = "massless link, revolute (axis P->Q) on i, ball on j: f_i.d = 0, |d| = C"


class RevoluteCylindrical(Joint):
    type, n_eq, needs = "revolute-cylindrical", 3, ("PQ", "PQR")
    rows = (D1("f_i", "f_j"), D2("g_j"), D2("h_j"))
    description = ("massless link, revolute axis f_i perpendicular to cylinder axis f_j "
                   "through P_i (Haug eq. 9.4.32)")


class SphericalSpherical(Joint):
    type, n_eq, needs = "spherical-spherical", 1, ("P", "P")
    rows = (("distance", {"si": "P_i", "sj": "P_j"}),)
    target = "distance"
    description = "massless link with balls at both ends: |P_j - P_i| = C (Haug Ch. 9)"


class Distance(SphericalSpherical):
    type = "distance"
    description = "distance constraint |P_j - P_i| = C (same equation as spherical-spherical)"


class Strut(Joint):
    type, n_eq, needs = "strut", 2, ("P", "PQR")
    rows = (D2("g_j"), D2("h_j"))
    description = "McPherson strut: P_i stays on the line through P_j along f_j (2 equations)"


class Fixed(Joint):
    type, n_eq, needs = "fixed", 6, ("PQR", "PQR")
    rows = (SPH, D1("f_i", "g_j"), D1("f_i", "h_j"), D1("g_i", "h_j"))
    description = "weld: spherical + the three frames locked"


class Absolute(Joint):
    type, n_eq, needs = "absolute", 1, ("P", None)
    rows = (("absolute", {"s": "P_i"}),)
    description = "one global coordinate (axis x|y|z) of a body point = value"


JOINTS: dict[str, type[Joint]] = {
    c.type: c
    for c in (Spherical, Universal, Revolute, Cylindrical, Translational, RevoluteSpherical,
              RevoluteCylindrical, SphericalSpherical, Distance, Strut, Fixed, Absolute)
}


class Driver:
    type = ""
    joint_types: tuple[str, ...] = ()  # joints whose frames it uses (empty: own points)
    rows: tuple = ()
    squared = False  # target is f(t)^2 (distance)
    unit = ""
    effort_unit = ""
    description = ""

    @staticmethod
    def dphi_dx(x):
        return 1.0


class RotationDriver(Driver):
    type = "rotation"
    joint_types = ("revolute", "cylindrical")
    rows = (("angle", {"gi": "g_i", "hi": "h_i", "gj": "g_j"}),)
    unit, effort_unit = "rad", "N m"
    description = "angle from g_i to g_j about f_i of a revolute/cylindrical joint = f(t)"


class TranslationDriver(Driver):
    type = "translation"
    joint_types = ("translational", "cylindrical")
    rows = (D2("f_i"),)
    unit, effort_unit = "m", "N"
    description = "f_i . (P_j - P_i) of a translational/cylindrical joint = f(t)"


class DistanceDriver(Driver):
    type = "distance"
    rows = (("distance", {"si": "P_i", "sj": "P_j"}),)
    squared = True
    unit, effort_unit = "m", "N"
    description = "|P_j - P_i| = f(t)"

    @staticmethod
    def dphi_dx(x):
        return 2.0 * x


class AbsoluteDriver(Driver):
    type = "absolute"
    rows = (("absolute", {"s": "P_i"}),)
    unit, effort_unit = "m", "N"
    description = "global x|y|z of a body point = f(t)"


DRIVERS: dict[str, type[Driver]] = {
    c.type: c for c in (RotationDriver, TranslationDriver, DistanceDriver, AbsoluteDriver)
}
