"""The deck's vocabulary as data: keys, joint/driver/force types, physical dimensions.

The loader reads these tables and holds no per-type branches of its own where a table
can say it; adding a force type means adding a row to :data:`FORCE_TYPES` (and its
model in ``mbsim.forces``).  docs/deck.md is the prose version of these tables.
"""

from __future__ import annotations

import difflib
from typing import Any, NamedTuple

TOP_KEYS = (
    "title", "units", "gravity", "parameters", "bodies", "joints", "drivers", "forces",
    "events", "outputs", "analysis", "scenes", "studies",
)  # fmt: skip
BODY_KEYS = (
    "ground", "mass", "inertia", "r", "p", "euler_deg", "axis_angle", "omega", "omega_local",
    "rdot", "active", "shape",
)  # fmt: skip
ORIENTATION_KEYS = ("p", "euler_deg", "axis_angle")  # at most one per body
AXIS_ANGLE_KEYS = ("axis", "angle")
POINT_KEYS = ("P", "Q", "R")
OUTPUT_KEYS = ("points", "measures", "only")
OUTPUT_GROUPS = ("bodies", "points", "forces", "joints", "drivers", "monitors", "constraints",
                 "measures")  # first segment of an `outputs: only:` pattern
OUTPUT_POINT_KEYS = ("body", "point")
SCENE_KEYS = ("description", "set", "remove", "analysis")
ANALYSIS_MODES = ("assembly", "kinematic", "dynamic", "inverse", "equilibrium", "linear")

# Studies (`studies:`; run by `mbsim study`, mbsim/study.py): a list of cases, the figures
# drawn from them and the key numbers tabulated.  STUDY_STATS is implemented by
# mbsim.study.STATS (same names, checked by the tests).
STUDY_KEYS = ("description", "cases", "figures", "numbers")
STUDY_CASE_KEYS = ("label", "name", "scene", "set", "mode", "options")
STUDY_FIGURE_KEYS = ("name", "title", "y", "x", "xlabel", "ylabel", "scale", "xscale",
                     "cases", "caption", "labels")
# Components of the result channels whose width a deck fixes (docs/hdf5.md; written by
# mbsim.analyses.common and the reactions), so that a figure's `labels` (one per curve) can be
# counted when the deck is loaded: group -> {quantity: components}.  Other channels (force
# elements, constraints/lam) are counted when the figure is drawn.
STUDY_FIGURE_WIDTHS = {
    "bodies": {"r": 3, "p": 4, "rd": 3, "rdd": 3, "omega": 3, "omega_local": 3, "omegad": 3,
               "omegad_local": 3},
    "points": {"position": 3, "velocity": 3, "acceleration": 3},
    "joints": {f"{q}_{b}{frame}": 3 for q in ("force", "torque") for b in "ij"
               for frame in ("", "_local")},
    "drivers": {"torque": 1, "force": 1, "power": 1},
    "monitors": {"position_violation": 1, "velocity_violation": 1, "energy": 1,
                 "work_nonconservative": 1, "step_size": 1},
    "constraints": {"residual": 1, "condition": 1},
    "error": {"position": 1, "orientation": 1, "velocity": 1, "angular_velocity": 1},
}
STUDY_NUMBER_KEYS = ("name", "y", "stat", "scale", "unit", "cases", "from", "band")
STUDY_MODES = ("kinematic", "equilibrium", "inverse", "dynamic", "linear")
STUDY_STATS = ("final", "initial", "max", "min", "absmax", "mean", "range", "t_max", "t_min",
               "t_absmax", "period", "settle", "growth")
AXES = ("x", "y", "z")

# Physical dimensions: name -> (SI unit, as mbsim.units spells it; words for messages).
# A quantity with a unit ('30 deg') given for a field of known dimension must match it.
DIMENSIONS = {
    "mass": ("kg", "mass"),
    "inertia": ("kg*m^2", "moment of inertia"),
    "length": ("m", "length"),
    "angle": ("rad", "angle"),
    "time": ("s", "time"),
    "velocity": ("m/s", "velocity"),
    "angular_velocity": ("rad/s", "angular velocity"),
    "acceleration": ("m/s^2", "acceleration"),
    "force": ("N", "force"),
    "torque": ("N*m", "torque"),
    "stiffness": ("N/m", "stiffness"),
    "damping": ("N*s/m", "damping coefficient"),
    "rot_stiffness": ("N*m/rad", "rotational stiffness"),
    "rot_damping": ("N*m*s/rad", "rotational damping coefficient"),
}

# Deck field -> dimension, where the key alone says it.  Force fields: FORCE_TYPES.
FIELD_DIMENSIONS = {
    "mass": "mass",
    "inertia": "inertia",
    "r": "length",
    "rdot": "velocity",
    "omega": "angular_velocity",
    "omega_local": "angular_velocity",
    "angle": "angle",
    "gravity": "acceleration",
    "P": "length",
    "Q": "length",
    "R": "length",
    "point": "length",
    "distance": "length",
}

# Analysis settings of known dimension (others: any quantity, converted to SI).
ANALYSIS_DIMENSIONS = {"t_start": "time", "t_end": "time", "step": "time", "h": "time"}

# The settings each analysis reads (docs/deck.md, "analysis"): the keys of the DEFAULTS of
# its module in mbsim/analyses/ (tests/deck/test_loader.py checks that they are all here)
# and those it reads without a default (the integrators' own settings).  One table for the
# deck's `analysis:`, scenes, --set, a study case's options, sweep --param and
# mbsim.api.run_model: a key not listed is an error with a suggestion (setting_name_problems).
_TIME_GRID = ("t_start", "t_end", "step")
_INTEGRATOR_OWN = ("alpha", "beta", "rho_inf", "newton_tol", "jacobian", "repartition_ratio",
                   "drift_bound", "tangent_steps", "partition", "projection_tol", "h_min",
                   "compiled_step")
ANALYSIS_SETTINGS: dict[str, tuple[str, ...]] = {
    "assembly": ("hold",),
    "kinematic": (*_TIME_GRID, "tol", "max_iter", "cond_max"),
    "inverse": (*_TIME_GRID, "tol", "max_iter", "cond_max"),
    "dynamic": (*_TIME_GRID, "integrator", "rtol", "atol", "accuracy", "error_estimate",
                "estimate_method", "estimate_ratio", "h", "h_max", "max_steps", "tol", "sparse",
                *_INTEGRATOR_OWN),
    "equilibrium": ("method", "tol", "max_iter", "max_step", "phi_tol", "fd_step", "t",
                    "t_start", "t_end", "step", "damping", "settle_tol", "from_rest", "body",
                    "bodies", "omega", "axis", "point", "integrator", "rtol", "atol",
                    "max_steps"),
    "linear": ("about", "method", "time", "t", "fd_step", "phi_tol", "zero_tol", "re_tol"),
}  # fmt: skip
# Passed by code, not by decks: a progress callback, a starting state, a first step.
INTERNAL_SETTINGS = ("progress", "q0", "qd0", "h0")


def setting_name_problems(mode: str, keys, internal: bool = False) -> list[tuple[str, str]]:
    """[(key, message)] for the keys that are not settings of ``mode``'s analysis (with
    ``internal``, :data:`INTERNAL_SETTINGS` are accepted too); empty for an unknown mode
    (that is reported where the mode is chosen)."""
    known = ANALYSIS_SETTINGS.get(mode)
    if known is None:
        return []
    allowed = set(known) | (set(INTERNAL_SETTINGS) if internal else set())
    out = []
    for key in keys:
        if key in allowed:
            continue
        close = difflib.get_close_matches(str(key), known, n=1)
        hint = f"; did you mean {close[0]}?" if close else f" (settings: {', '.join(known)})"
        out.append((key, f"unknown setting {str(key)[:80]!r} of the {mode} analysis{hint}"))
    return out


class JointType(NamedTuple):
    """n_eq: constraint equations; needs_i / needs_j: the points each body must give
    (others may be given too); needs_j None: a one-body constraint; data: required keys."""

    n_eq: int
    needs_i: str
    needs_j: str | None
    data: tuple[str, ...] = ()


JOINT_TYPES = {
    "spherical": JointType(3, "P", "P"),
    "universal": JointType(4, "PQ", "PQ"),
    "revolute": JointType(5, "PQR", "PQ"),
    "cylindrical": JointType(4, "PQR", "PQ"),
    "translational": JointType(5, "PQR", "PQR"),
    "revolute-spherical": JointType(2, "PQ", "P", ("distance",)),
    "revolute-cylindrical": JointType(3, "PQ", "PQR"),
    "spherical-spherical": JointType(1, "P", "P", ("distance",)),
    "distance": JointType(1, "P", "P", ("distance",)),
    "strut": JointType(2, "P", "PQR"),
    "fixed": JointType(6, "PQR", "PQR"),
    "absolute": JointType(1, "P", None, ("axis", "value")),
}
JOINT_KEYS = ("type", "bodies", "points", "distance", "axis", "value", "active")


class DriverType(NamedTuple):
    """keys: the driver's own keys (besides type and function); joints: the joint types a
    rotation/translation driver may drive; dim: dimension of the function's value."""

    keys: tuple[str, ...]
    joints: tuple[str, ...]
    dim: str


DRIVER_TYPES = {
    "rotation": DriverType(("joint",), ("revolute", "cylindrical"), "angle"),
    "translation": DriverType(("joint",), ("translational", "cylindrical"), "length"),
    "distance": DriverType(("bodies", "points"), (), "length"),
    "absolute": DriverType(("body", "point", "axis"), (), "length"),
}
DRIVER_KEYS = ("type", "function", "joint", "bodies", "points", "body", "point", "axis",
               "active")

# Function-of-time forms: the one key of a mapping (besides table's `interpolation`).
FUNCTION_FORMS = ("expression", "polynomial", "table", "harmonic")
HARMONIC_KEYS = ("amplitude", "frequency", "phase", "offset")
INTERPOLATIONS = ("cubic", "linear", "akima")


class Field(NamedTuple):
    """One field of a force type.

    kind: 'number' (float), 'vector' (3 floats), 'function' (FunctionSpec of t),
      'law' (FunctionSpec of t, or a bound Expression when it uses other names),
      'laws' (one law, or a list of 3 laws), 'choice' (one of ``options``), 'flag' (true or
      false), 'joint' (the name
      of a joint whose type is in ``options``), 'measures' (read by
      ``mbsim.forces.measures.read_measures``: {name: MeasureSpec}).
    dim: key of DIMENSIONS (None: any).  names: the variables a law may use besides t and
      the parameters (None: any name; the force model checks them against its own variables
      and measures).
    """

    kind: str
    dim: str | None = None
    required: bool = False
    default: Any = None
    options: tuple[str, ...] = ()
    names: tuple[str, ...] | None = None


class ForceType(NamedTuple):
    """bodies: 'pair' (`bodies: [i, j]` with `points: {i: P, j: P}`), 'pair-joint'
    (`bodies` optional, default the bodies of `joint`, whose points the force gets), 'one'
    (`body:` and an optional `point:`, default the centroid), 'one-or-pair' (`body: b` or
    `bodies: [i, j]`, no points).
    fields: the type's own fields; one_of: groups of which exactly one must be given."""

    bodies: str
    fields: dict[str, Field]
    one_of: tuple[tuple[str, ...], ...] = ()


_MEASURES = Field("measures")
_FRAME = Field("choice", default="global", options=("global", "local"))
FORCE_TYPES = {
    "tsda": ForceType(
        "pair",
        {
            "k": Field("number", "stiffness", default=0.0),
            "c": Field("number", "damping", default=0.0),
            "L0": Field("number", "length", default=0.0),
            "law": Field("law", "force"),  # the whole force, instead of k and c
            "actuator": Field("law", "force"),
            "measures": _MEASURES,
        },
    ),
    "rsda": ForceType(
        "pair-joint",
        {
            "joint": Field("joint", required=True, options=("revolute", "cylindrical")),
            "k": Field("number", "rot_stiffness", default=0.0),
            "c": Field("number", "rot_damping", default=0.0),
            "theta0": Field("number", "angle", default=0.0),
            "law": Field("law", "torque"),
            "actuator": Field("law", "torque"),
            "measures": _MEASURES,
        },
    ),
    "force": ForceType(
        "one",
        {
            "vector": Field("vector", "force"),
            "law": Field("laws", "force"),
            "direction": Field("vector"),
            "frame": _FRAME,
            "measures": _MEASURES,
        },
        one_of=(("vector", "law"),),
    ),
    "torque": ForceType(
        "one-or-pair",
        {
            "vector": Field("vector", "torque"),
            "law": Field("laws", "torque"),
            "direction": Field("vector"),
            "frame": _FRAME,
            "measures": _MEASURES,
        },
        one_of=(("vector", "law"),),
    ),
    "tire": ForceType(  # mbsim/forces/tire.py (Haug Sec. 12.5.1)
        "one",
        {
            "kt": Field("number", "stiffness", required=True),
            "radius": Field("number", "length", required=True),  # unloaded
            "c": Field("number", "damping", default=0.0),
            "c_alpha": Field("number", required=True),  # N/rad, cornering stiffness
            "mu": Field("number", default=0.8),
            "rolling": Field("number", default=0.0),  # rolling-resistance coefficient
            "v_min": Field("number", "velocity", default=0.5),  # lateral force fades below
            "forward": Field("vector"),  # body-frame heading axis, default y'
        },
    ),
    "bushing": ForceType(  # mbsim/forces/bushing.py (ADAMS BUSHING)
        "pair",
        {
            "k": Field("vector", "stiffness"),
            "c": Field("vector", "damping"),
            "kr": Field("vector", "rot_stiffness"),
            "cr": Field("vector", "rot_damping"),
            "preload_force": Field("vector", "force"),
            "preload_torque": Field("vector", "torque"),
            "force_curves": Field("laws", "force"),  # f(d) per component, instead of k
            "torque_curves": Field("laws", "torque"),  # t(theta) per component, instead of kr
        },
    ),
    "contact": ForceType(  # mbsim/forces/contact.py (ADAMS IMPACT)
        "pair",
        {
            "geometry": Field("choice", required=True, options=("sphere-plane", "sphere-sphere")),
            "radius": Field("number", "length", required=True),  # sphere on body j
            "radius_i": Field("number", "length"),  # sphere-sphere: the sphere on body i
            "normal": Field("vector"),  # sphere-plane: plane normal, body i frame (default z)
            "k": Field("number"),  # N/m^exponent
            "exponent": Field("number", default=1.5),
            "E": Field("number"),  # Pa, Hertz stiffness (both bodies), instead of k
            "nu": Field("number", default=0.3),
            "c_max": Field("number", "damping", default=0.0),
            "depth": Field("number", "length"),  # penetration at which c reaches c_max
            "restitution": Field("number"),  # instead of c_max: e with v_impact
            "v_impact": Field("number", "velocity"),
            "restitution_law": Field(
                "choice", default="lankarani-nikravesh",
                options=("hunt-crossley", "lankarani-nikravesh", "flores"),
            ),
            "mu": Field("number", default=0.0),
            "v_slip": Field("number", "velocity", default=1e-3),
        },
    ),
    "stop": ForceType(  # mbsim/forces/contact.py: the contact law on a joint's travel or angle
        "pair-joint",
        {
            "joint": Field("joint", required=True,
                           options=("translational", "revolute", "cylindrical")),
            "motion": Field("choice", options=("translation", "rotation")),  # cylindrical
            "lower": Field("number"),  # m (translation) or rad (rotation)
            "upper": Field("number"),
            "k": Field("number", required=True),  # N/m^exponent or N m/rad^exponent
            "exponent": Field("number", default=1.5),
            "c_max": Field("number", default=0.0),
            "depth": Field("number"),
            "restitution": Field("number"),
            "v_impact": Field("number"),
            "restitution_law": Field(
                "choice", default="lankarani-nikravesh",
                options=("hunt-crossley", "lankarani-nikravesh", "flores"),
            ),
        },
    ),
    "friction": ForceType(  # mbsim/forces/friction.py: stick-slip joint friction (ADAMS FRICTION)
        "pair-joint",
        {
            "joint": Field("joint", required=True,
                           options=("translational", "revolute", "cylindrical", "spherical")),
            "mu_s": Field("number", required=True),  # static coefficient
            "mu_k": Field("number", required=True),  # kinetic coefficient, <= mu_s
            "viscous": Field("number", default=0.0),  # N s/m or N m s/rad
            "stribeck_velocity": Field("number"),  # m/s or rad/s; none: plain Coulomb
            "preload": Field("number", "force", default=0.0),  # N, added to the normal load
            "pin_radius": Field("number", "length"),  # revolute, cylindrical: torque lever
            "ball_radius": Field("number", "length"),  # spherical: torque lever
            "bearing_length": Field("number", "length"),  # moment -> load (translational, cyl.)
            "reaction": Field("flag", default=True),  # normal load from the joint reaction
        },
    ),
}
FORCE_BODY_KEYS = {
    "pair": ("bodies", "points"),
    "pair-joint": ("bodies",),
    "one": ("body", "point"),
    "one-or-pair": ("body", "bodies"),
}


def force_keys(kind: str) -> tuple[str, ...]:
    """All keys a force of type ``kind`` may have."""
    ftype = FORCE_TYPES[kind]
    return ("type", "active") + FORCE_BODY_KEYS[ftype.bodies] + tuple(ftype.fields)


def can_add(segs: list[str | int]) -> bool:
    """May a scene `set` or a --set create the key at ``segs`` when the deck lacks it?

    Only keys the format defines for that place: a top-level key, a body/joint/driver/force
    field, an analysis mode or setting.  Parameter and item names must already exist.
    """
    segs = [str(s) for s in segs]
    n = len(segs)
    if n == 1:
        return segs[0] in TOP_KEYS
    group = segs[0]
    if n == 3 and group == "bodies":
        return segs[2] in BODY_KEYS
    if n == 4 and group == "bodies" and segs[2] == "axis_angle":
        return segs[3] in AXIS_ANGLE_KEYS
    if n == 3 and group == "joints":
        return segs[2] in JOINT_KEYS
    if n == 3 and group == "drivers":
        return segs[2] in DRIVER_KEYS
    if n == 3 and group == "forces":
        return any(segs[2] in force_keys(kind) for kind in FORCE_TYPES)
    if group == "analysis":
        return n == 3 or (n == 2 and segs[1] in ANALYSIS_MODES)
    if group == "outputs":  # `--set outputs.only=[...]`, a new measures section
        return n == 2 and segs[1] in OUTPUT_KEYS
    return False
