"""Deck file -> validated :class:`~mbsim.deck.spec.DeckSpec` (the format: docs/deck.md).

Steps: read the text; compose the YAML into a line-aware tree (:mod:`mbsim.deck.tree`);
apply the scene (remove, set, analysis) and then the ``--set`` overrides to that tree;
validate it section by section, converting numbers to SI floats.  Every problem is a
one-line :class:`DeckError` naming file, key path and line.

The first two steps are done once per deck (:func:`parse_deck` -> :class:`ParsedDeck`);
studies and sweeps then build each case's spec from the parsed tree
(:meth:`ParsedDeck.spec`): the scene and overrides are applied copy-on-write, so neither
the file nor the whole tree is read or copied again per case.
"""

from __future__ import annotations

import math
import re
from collections.abc import Mapping
from pathlib import Path

import numpy as np

from mbsim import rotations
from mbsim.deck import limits, schema
from mbsim.deck import shapes as _shapes
from mbsim.deck.schema import FIELD_DIMENSIONS as DIM
from mbsim.deck.spec import (
    BodySpec,
    DeckSpec,
    DriverSpec,
    ForceSpec,
    JointSpec,
    OutputSpec,
    PointSet,
)  # fmt: skip
from mbsim.deck.tree import (
    Node,
    PathError,
    apply_override,
    apply_scene,
    compose,
    cow,
    scene_names,
    set_path,
    to_plain,
)  # fmt: skip
from mbsim.deck.values import NAME_RE, Reader, describe
from mbsim.errors import DeckError, Where
from mbsim.expr import FUNCTIONS, RESERVED
from mbsim.options import HOLD_COORDS, resolve_options


def load_deck(
    path: str | Path, overrides: Mapping[str, str] | None = None, scene: str | None = None,
    studies: bool = True,
) -> DeckSpec:  # fmt: skip
    """Read and validate the deck file at ``path``.

    Parameters
    ----------
    path : deck file (YAML).
    overrides : {key path: value} from ``mbsim run --set PATH=VALUE``; values are YAML text.
    scene : name of an entry of the deck's ``scenes:`` to apply before the overrides.
    studies : False: leave the ``studies:`` section unvalidated (``DeckSpec.studies`` empty),
        for a run that does not use it (``mbsim run``; ``mbsim check`` validates it).
    """
    return parse_deck(path, scene).spec(scene, overrides, studies=studies)


def parse_deck(path: str | Path, scene: str | None = None) -> ParsedDeck:
    """Read the deck file at ``path`` and compose it, once (see :class:`ParsedDeck`);
    ``scene``: as for :func:`parse_deck_text`."""
    file = str(path)
    try:
        size = Path(path).stat().st_size if Path(path).is_file() else 0
        if size > limits.DECK_BYTES.value:  # before reading it: a 1 GB 'deck' is refused at once
            raise DeckError(limits.DECK_BYTES.exceeded(size), Where(file))
        data = Path(path).read_bytes()
    except FileNotFoundError:
        raise DeckError("no such deck file", Where(file)) from None
    except IsADirectoryError:
        raise DeckError("is a directory, not a deck file", Where(file)) from None
    except OSError as exc:
        raise DeckError(f"cannot read the deck: {exc.strerror or exc}", Where(file)) from None
    try:
        text = data.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        line = data.count(b"\n", 0, exc.start) + 1
        raise DeckError(
            f"not a text file: byte 0x{data[exc.start]:02x} at offset {exc.start} is not UTF-8",
            Where(file, "", line),
        ) from None
    return parse_deck_text(text, file, scene)


def load_deck_text(
    text: str, file: str = "<deck>", overrides: Mapping[str, str] | None = None,
    scene: str | None = None,
) -> DeckSpec:  # fmt: skip
    """Validate deck ``text``; ``file`` is the name used in messages (see :func:`load_deck`)."""
    return parse_deck_text(text, file, scene).spec(scene, overrides)


def parse_deck_text(text: str, file: str = "<deck>", scene: str | None = None) -> ParsedDeck:
    """Compose deck ``text`` once (see :class:`ParsedDeck`); every scene but ``scene`` (the
    one about to be applied, which reports its own errors) is checked to apply."""
    root = compose(text, file)
    if root is None or root.kind != "map":
        got = "an empty file" if root is None else describe(root)
        raise DeckError(
            f"expected a mapping of top-level keys (bodies, joints, ...), got {got}",
            Where(file, "", None if root is None else root.line),
        )
    parsed = ParsedDeck(file, text, root)
    parsed.check_scenes(skip=scene)
    return parsed


_PARSED: dict[tuple[str, str], ParsedDeck] = {}  # (file, text) -> parsed deck, newest last
PARSED_KEPT = 4  # decks remembered per process


def parse_deck_cached(text: str, file: str = "<deck>") -> ParsedDeck:
    """:func:`parse_deck_text`, remembered per (file, text) in this process: a sweep or
    study worker parses its deck once, not once per case (a forked worker inherits the
    decks its parent remembered, :func:`remember_deck`)."""
    parsed = _PARSED.get((file, text))
    return parsed if parsed is not None else remember_deck(parse_deck_text(text, file))


def remember_deck(parsed: ParsedDeck) -> ParsedDeck:
    """Keep `parsed` for :func:`parse_deck_cached` (the last PARSED_KEPT decks)."""
    _PARSED.pop((parsed.file, parsed.text), None)
    _PARSED[(parsed.file, parsed.text)] = parsed
    while len(_PARSED) > PARSED_KEPT:
        del _PARSED[next(iter(_PARSED))]
    return parsed


class ParsedDeck:
    """A deck composed once; each variant (a scene, ``--set`` overrides) is validated from it.

    ``root`` is the tree as written and is never edited: :meth:`spec` applies the scene and
    the overrides to a copy-on-write view (:func:`mbsim.deck.tree.cow`: only the containers
    on the edited paths are copied), so a study or sweep case costs its own edits and the
    validation of the model sections, not a new read, parse or deep copy of the deck.
    Errors are those of :func:`load_deck` (same code path, same file, key path and line).
    """

    def __init__(self, file: str, text: str, root: Node):
        self.file = file  # the name used in messages
        self.text = text  # the YAML text (stored in results)
        self.root = root  # the tree as written: read only
        self._checked: set[str] = set()  # scenes known to apply

    def check_scenes(self, skip: str | None = None) -> None:
        """Every scene (but ``skip``) must apply, not only the one asked for."""
        for name in scene_names(self.root):
            if name != skip and name not in self._checked:
                apply_scene(cow(self.root), name, self.file)
                self._checked.add(name)

    def spec(self, scene: str | None = None, overrides: Mapping[str, str] | None = None,
             studies: bool = True) -> DeckSpec:  # fmt: skip
        """The validated deck with ``scene`` and then ``overrides`` applied (as
        :func:`load_deck`).  ``studies=False`` skips validating the ``studies:`` section
        (``DeckSpec.studies`` is then empty): a study or sweep case, whose studies are those
        of the deck as written, validated once by the spec that planned the cases."""
        self.check_scenes(skip=scene)
        root = cow(self.root)
        if scene is not None:
            apply_scene(root, scene, self.file)
            self._checked.add(scene)
        for key, value in (overrides or {}).items():
            apply_override(root, key, value, self.file)
        _drop_inactive(root, self.file)
        base = self.root if studies and "studies" in self.root.value else None
        return _build(root, Reader(self.file), self.text, scene, base, studies)

    def variant(self, scene: str | None = None) -> Node:
        """A copy-on-write tree of the deck with ``scene`` applied (no validation), for
        checking key paths (:func:`mbsim.sweep.plan_sweep`)."""
        root = cow(self.root)
        if scene is not None:
            apply_scene(root, scene, self.file)
        return root


def _drop_inactive(root: Node, file: str) -> None:
    """Items with ``active: false`` are left out of the model (a scene or --set may switch
    them on or off: ``--set joints.BC.active=true``); ``active`` itself must be a boolean.

    ``root`` is edited (a copy-on-write tree); the sections and items below it are not: an
    edited section or item is replaced by a copy."""
    for section in ("bodies", "joints", "drivers", "forces", "events"):
        sec = root.value.get(section)
        if sec is None or sec.kind != "map":
            continue
        kept: dict[str, Node] = {}
        for name, item in sec.value.items():
            if item.kind != "map" or "active" not in item.value:
                kept[name] = item
                continue
            flag = item.value["active"]
            if flag.kind != "scalar" or not isinstance(flag.value, bool):
                raise DeckError(f"expected true or false, got {flag.text or describe(flag)}",
                                Where(file, f"{section}.{name}.active",
                                      item.key_lines.get("active")))
            if flag.value:
                kept[name] = item = cow(item)
                del item.value["active"]
        if len(kept) != len(sec.value) or any(kept[n] is not sec.value[n] for n in kept):
            sec = root.value[section] = cow(sec)
            sec.value = kept


# -- the deck -----------------------------------------------------------------------------------
def _build(root: Node, rd: Reader, text: str, scene: str | None,
           base: Node | None = None, studies: bool = True) -> DeckSpec:  # fmt: skip
    top = rd.fields(root, Where(rd.file, "", root.line), schema.TOP_KEYS, ("bodies",), "a deck")
    title = ""
    if "title" in top:
        title = str(to_plain(top["title"][0]) or "")
    if "units" in top and rd.name(*top["units"], what="units") not in ("SI", "si"):
        node, w = top["units"]
        raise rd.error(
            w,
            f"only SI units are supported, got {describe(node)} (write values "
            "with other units as strings: '12 in', '30 deg')",
            node,
        )
    if "parameters" in top:
        _parameters(rd, *top["parameters"])
    gravity = rd.vector(*top["gravity"], 3, "acceleration") if "gravity" in top else np.zeros(3)
    bodies = _section(rd, top, "bodies", _body)
    if not bodies:
        raise rd.error(top["bodies"][1], "expected at least one body")
    joints = _section(rd, top, "joints", _joint, bodies)
    drivers = _section(rd, top, "drivers", _driver, bodies, joints)
    forces = _section(rd, top, "forces", _force, bodies, joints)
    events = {}
    if "events" in top:
        from mbsim.events import read_events

        events = read_events(rd, *top["events"], bodies, joints)
    outputs = _outputs(rd, *top["outputs"], bodies) if "outputs" in top else {}
    out_measures, out_only = (_output_extras(rd, *top["outputs"], bodies, joints)
                              if "outputs" in top else ({}, None))
    analysis = _analysis(rd, *top["analysis"], bodies) if "analysis" in top else {}
    if "scenes" in top:
        for _name, node, w in rd.items(*top["scenes"]):
            rd.fields(node, w, schema.SCENE_KEYS, what="a scene")
    cases = {}
    if studies and "studies" in top and not (top["studies"][0].kind == "scalar"
                                             and top["studies"][0].value is None):  # fmt: skip
        cases = _studies(rd, *top["studies"], base if base is not None else root)
    return DeckSpec(
        title=title, file=rd.file, text=text, gravity=gravity, parameters=dict(rd.params),
        bodies=bodies, joints=joints, drivers=drivers, forces=forces, outputs=outputs,
        analysis=analysis, raw=to_plain(root), warnings=rd.warnings, scene=scene,
        studies=cases, output_measures=out_measures, output_only=out_only, events=events,
    )  # fmt: skip


def _section(rd: Reader, top: dict, key: str, build, *known) -> dict:
    if key not in top:
        return {}
    node, where = top[key]
    if node.kind == "scalar" and node.value is None:
        return {}  # `joints:` with nothing under it
    return {name: build(rd, name, child, w, *known) for name, child, w in rd.items(node, where)}


def _parameters(rd: Reader, node: Node, where: Where) -> None:
    """Evaluated in order; a parameter may use the ones before it."""
    items = rd.items(node, where) if not (node.kind == "scalar" and node.value is None) else []
    if len(items) > limits.PARAMETERS.value:
        raise rd.error(where, limits.PARAMETERS.exceeded(len(items)))
    names = [k for k, _, _ in items]
    for i, (name, child, w) in enumerate(items):
        if not NAME_RE.fullmatch(name) or name in RESERVED or name in FUNCTIONS or name == "t":
            why = "is reserved" if NAME_RE.fullmatch(name) else "is not a name"
            raise rd.error(
                w,
                f"parameter name {name!r} {why} (use letters, digits, _; not t, "
                "pi, e or a function name)",
            )
        try:
            rd.params[name] = rd.number(child, w)
        except DeckError:
            text = child.value if child.kind == "scalar" and isinstance(child.value, str) else ""
            later = [n for n in names[i:] if n in NAME_RE.findall(text)]
            if not later:
                raise
            what = "itself" if later[0] == name else f"{later[0]!r}, which comes later"
            raise rd.error(
                w,
                f"parameter {name!r} uses {what}; a parameter may only use "
                "parameters defined before it",
                child,
            ) from None


# -- bodies -------------------------------------------------------------------------------------
def _body(rd: Reader, name: str, node: Node, where: Where) -> BodySpec:
    got = rd.fields(node, where, schema.BODY_KEYS, what="a body")
    ground = False
    if "ground" in got:
        gnode, gw = got["ground"]
        if not isinstance(gnode.value, bool):
            raise rd.error(gw, f"expected true or false, got {describe(gnode)}", gnode)
        ground = gnode.value
    for key in () if ground else ("mass", "inertia"):  # as Reader.fields words it
        if key not in got:
            raise rd.error(where, f"missing required key {key!r} for a body (give mass and "
                           f"inertia, or ground: true)")
    if ground:
        moving = [k for k in ("omega", "omega_local", "rdot") if k in got]
        if moving:
            raise rd.error(got[moving[0]][1], f"a ground body does not move; remove {moving[0]!r}")
    mass = rd.number(*got["mass"], "mass") if "mass" in got else 1.0
    if mass <= 0:
        raise rd.error(got["mass"][1], f"mass must be > 0, got {mass:g}", got["mass"][0])
    inertia = _inertia(rd, *got["inertia"]) if "inertia" in got else np.eye(3)
    vec = {
        k: rd.vector(*got[k], 3, DIM[k]) for k in ("r", "rdot", "omega", "omega_local") if k in got
    }
    if "omega" in got and "omega_local" in got:
        raise rd.error(
            got["omega_local"][1], "give omega (global frame) or omega_local (body frame), not both"
        )
    return BodySpec(
        name=name, mass=mass, inertia=inertia, r=vec.get("r", np.zeros(3)),
        p=_orientation(rd, got), rdot=vec.get("rdot"), omega=vec.get("omega"),
        omega_local=vec.get("omega_local"), ground=ground, where=where,
        shapes=_shapes.read_shapes(rd, *got["shape"]) if "shape" in got else None,
    )  # fmt: skip


def _inertia(rd: Reader, node: Node, where: Where) -> np.ndarray:
    """J' from Ixx Iyy Izz [Ixy Iyz Izx]; products enter with a + sign (Haug's tables)."""
    n = len(node.value) if node.kind == "seq" else 0
    vals = rd.vector(node, where, 6 if n == 6 else 3, "inertia")
    ixx, iyy, izz = vals[:3]
    ixy, iyz, izx = vals[3:] if n == 6 else (0.0, 0.0, 0.0)
    J = np.array([[ixx, ixy, izx], [ixy, iyy, iyz], [izx, iyz, izz]])
    eig = np.linalg.eigvalsh(J)
    trace = float(np.trace(J))
    if eig[0] < -1e-12 * abs(trace) or trace <= 0 and eig[0] < 0:
        raise rd.error(
            where,
            f"inertia has a negative principal moment ({eig[0]:.4g} kg m²); "
            "the tensor must be positive (semi)definite",
            node,
        )
    tol = 1e-12 * max(trace, 0.0)
    if eig[0] <= tol:
        rd.warn(
            where,
            f"inertia has a zero principal moment (principal moments "
            f"{', '.join(f'{e:.4g}' for e in eig)}); the body can only be used where "
            "constraints hold it",
        )
    elif eig[0] + eig[1] < eig[2] * (1 - 1e-9):
        rd.warn(
            where,
            f"principal moments {', '.join(f'{e:.4g}' for e in eig)} violate the "
            "triangle inequality (no real body has them)",
        )
    return J


def _orientation(rd: Reader, got: dict) -> np.ndarray:
    given = [k for k in schema.ORIENTATION_KEYS if k in got]
    if len(given) > 1:
        raise rd.error(
            got[given[1]][1], f"give one of p, euler_deg, axis_angle; got {' and '.join(given)}"
        )
    if not given:
        return np.array([1.0, 0.0, 0.0, 0.0])
    key = given[0]
    node, where = got[key]
    if key == "euler_deg":  # plain numbers are degrees; a quantity ('1 rad') is converted
        if node.kind != "seq" or len(node.value) != 3:
            raise rd.error(where, f"expected 3 numbers, got {describe(node)}", node)
        angles = []
        for i, v in enumerate(node.value):
            x, with_unit = rd.number_info(
                v, Where(rd.file, f"{where.path}[{i}]", where.line), "angle"
            )
            angles.append(x if with_unit else math.radians(x))
        return rotations.from_euler313(*angles)
    if key == "axis_angle":
        aa = rd.fields(node, where, schema.AXIS_ANGLE_KEYS, schema.AXIS_ANGLE_KEYS, "axis_angle")
        axis = rd.vector(*aa["axis"], 3)
        if np.linalg.norm(axis) < 1e-12:
            raise rd.error(aa["axis"][1], "the rotation axis has zero length")
        return rotations.from_axis_angle(axis, rd.number(*aa["angle"], "angle"))
    p = rd.vector(node, where, 4)
    norm = float(np.linalg.norm(p))
    if abs(norm - 1.0) > 0.01:
        raise rd.error(
            where,
            f"Euler parameters have length {norm:.4g}; expected unit length "
            "(e0² + e1² + e2² + e3² = 1)",
            node,
        )
    if abs(norm - 1.0) > 1e-3:
        rd.warn(where, f"Euler parameters have length {norm:.4g}; normalised")
    return p / norm


# -- joints, drivers, forces --------------------------------------------------------------------
def _joint(rd: Reader, name: str, node: Node, where: Where, bodies: dict) -> JointSpec:
    got = rd.fields(node, where, schema.JOINT_KEYS, ("type",), "a joint")
    jtype = rd.choice(*got["type"], schema.JOINT_TYPES, "joint type")
    spec = schema.JOINT_TYPES[jtype]
    allowed = ("type", "bodies", "points") + spec.data
    got = rd.fields(node, where, allowed, ("bodies", "points") + spec.data, f"a {jtype} joint")
    one = spec.needs_j is None
    names = rd.body_names(*got["bodies"], bodies, 1 if one else 2)
    needs = {names[0]: spec.needs_i} if one else dict(zip(names, (spec.needs_i, spec.needs_j)))
    points = rd.points(*got["points"], needs)
    data: dict = {}
    if "distance" in got:
        data["distance"] = rd.number(*got["distance"], "length")
        if data["distance"] <= 0:
            raise rd.error(got["distance"][1], f"distance must be > 0, got {data['distance']:g}")
    if "axis" in got:
        data["axis"] = rd.choice(*got["axis"], schema.AXES, "axis")
        data["value"] = rd.function(*got["value"], "length")
    return JointSpec(name, jtype, (names[0], None if one else names[1]), points, data, where)


def _driver(rd: Reader, name: str, node: Node, where: Where, bodies: dict,
            joints: dict) -> DriverSpec:  # fmt: skip
    got = rd.fields(node, where, schema.DRIVER_KEYS, ("type",), "a driver")
    dtype = rd.choice(*got["type"], schema.DRIVER_TYPES, "driver type")
    spec = schema.DRIVER_TYPES[dtype]
    required = ("function",) + tuple(k for k in spec.keys if k != "point")
    got = rd.fields(node, where, ("type", "function") + spec.keys, required, f"a {dtype} driver")
    function = rd.function(*got["function"], spec.dim)
    out = DriverSpec(name, dtype, function, where=where)
    if "joint" in got:
        out.joint = rd.name(*got["joint"], joints, "joint")
        joint = joints[out.joint]
        if joint.type not in spec.joints:
            raise rd.error(
                got["joint"][1],
                f"a {dtype} driver needs a "
                f"{' or '.join(spec.joints)} joint; {out.joint} is {joint.type}",
            )
        out.bodies = joint.bodies
        if dtype == "rotation" and joint.points[joint.bodies[1]].R is None:
            rd.warn(got["joint"][1], f"joint {out.joint} gives no R on body {joint.bodies[1]}; "
                    "the angle is measured from an arbitrary direction across the axis")
    elif dtype == "distance":
        out.bodies = rd.body_names(*got["bodies"], bodies, 2)
        out.points = rd.points(*got["points"], dict.fromkeys(out.bodies, "P"))
    else:  # absolute
        body = rd.name(*got["body"], bodies, "body")
        out.bodies = (body, None)
        P = rd.vector(*got["point"], 3, "length") if "point" in got else np.zeros(3)
        out.points = {body: PointSet(P, where=got.get("point", (None, where))[1])}
        out.data["axis"] = rd.choice(*got["axis"], schema.AXES, "axis")
    return out


def _force(rd: Reader, name: str, node: Node, where: Where, bodies: dict,
           joints: dict) -> ForceSpec:  # fmt: skip
    every = sorted({k for t in schema.FORCE_TYPES for k in schema.force_keys(t)})
    got = rd.fields(node, where, every, ("type",), "a force")
    ftype = rd.choice(*got["type"], schema.FORCE_TYPES, "force type")
    spec = schema.FORCE_TYPES[ftype]
    required = tuple(k for k, f in spec.fields.items() if f.required)
    required += {"pair": ("bodies", "points"), "one": ("body",)}.get(spec.bodies, ())
    got = rd.fields(node, where, schema.force_keys(ftype), required, f"a {ftype} force")
    groups = spec.one_of + ((("body", "bodies"),) if spec.bodies == "one-or-pair" else ())
    for group in groups:
        given = [k for k in group if k in got]
        if len(given) != 1:
            raise rd.error(got[given[1]][1] if given else where, f"give exactly one of "
                           f"{', '.join(group)}; got {', '.join(given) or 'none'}")  # fmt: skip
    data: dict = {}
    for key, fld in spec.fields.items():
        if key in got:
            data[key] = _field(rd, fld, *got[key], bodies, joints)
        elif fld.default is not None:
            data[key] = fld.default
    out = ForceSpec(name, ftype, (), data=data, where=where)
    if "bodies" in got:
        out.bodies = rd.body_names(*got["bodies"], bodies, 2)
    elif "body" in got:
        out.bodies = (rd.name(*got["body"], bodies, "body"),)
    if spec.bodies == "pair":
        out.points = rd.points(*got["points"], dict.fromkeys(out.bodies, "P"))
    elif spec.bodies == "pair-joint":  # the force works in the joint's frames
        joint = joints[data["joint"]]
        if out.bodies and set(out.bodies) != set(joint.bodies):
            raise rd.error(got["bodies"][1], f"the bodies must be those of joint "
                           f"{data['joint']} ({', '.join(joint.bodies)})")  # fmt: skip
        out.bodies, out.points = tuple(joint.bodies), dict(joint.points)
        out.data["joint_type"] = joint.type  # for forces whose law depends on it (stop)
    elif spec.bodies == "one":
        P = rd.vector(*got["point"], 3, "length") if "point" in got else np.zeros(3)
        out.points = {out.bodies[0]: PointSet(P, where=got.get("point", (None, where))[1])}
    return out


def _field(rd: Reader, fld: schema.Field, node: Node, where: Where, bodies: dict, joints: dict):
    """One FORCE_TYPES field (see :class:`mbsim.deck.schema.Field` for the kinds)."""
    if fld.kind == "number":
        return rd.number(node, where, fld.dim)
    if fld.kind == "vector":
        return rd.vector(node, where, 3, fld.dim)
    if fld.kind == "function":
        return rd.function(node, where, fld.dim)
    if fld.kind == "law" or fld.kind == "laws" and node.kind != "seq":
        return rd.law(node, where, fld.dim, fld.names)
    if fld.kind == "laws":
        if len(node.value) != 3:
            raise rd.error(where, f"expected 3 components, got {describe(node)}", node)
        return [rd.law(v, rd.item(where, i, v), fld.dim, fld.names)
                for i, v in enumerate(node.value)]  # fmt: skip
    if fld.kind == "choice":
        return rd.choice(node, where, fld.options)
    if fld.kind == "flag":
        if node.kind != "scalar" or not isinstance(node.value, bool):
            raise rd.error(where, f"expected true or false, got {describe(node)}", node)
        return bool(node.value)
    if fld.kind == "joint":
        jname = rd.name(node, where, joints, "joint")
        if joints[jname].type not in fld.options:
            raise rd.error(where, f"needs a {' or '.join(fld.options)} joint; {jname} is "
                           f"{joints[jname].type}")  # fmt: skip
        return jname
    if fld.kind == "measures":
        from mbsim.forces.measures import read_measures  # the force models own measures

        return read_measures(rd, node, where, bodies, joints)
    raise ValueError(f"FORCE_TYPES: unknown field kind {fld.kind!r}")


# -- outputs, analysis --------------------------------------------------------------------------
def _outputs(rd: Reader, node: Node, where: Where, bodies: dict) -> dict[str, OutputSpec]:
    got = rd.fields(node, where, schema.OUTPUT_KEYS, what="outputs")
    out = {}
    if "points" in got:
        for name, child, w in rd.items(*got["points"]):
            pt = rd.fields(child, w, schema.OUTPUT_POINT_KEYS, ("body",), "an output point")
            body = rd.name(*pt["body"], bodies, "body")
            P = rd.vector(*pt["point"], 3, "length") if "point" in pt else np.zeros(3)
            out[name] = OutputSpec(name, body, P, w)
    return out


def _output_extras(rd: Reader, node: Node, where: Where, bodies: dict, joints: dict):
    """(measures, only) of ``outputs:`` (mbsim.measures owns the measure types)."""
    got = rd.fields(node, where, schema.OUTPUT_KEYS, what="outputs")
    measures = {}
    if "measures" in got:
        from mbsim.measures import read_output_measures

        measures = read_output_measures(rd, *got["measures"], bodies, joints)
    only = None
    if "only" in got:
        onode, ow = got["only"]
        if onode.kind != "seq":
            raise rd.error(ow, f"expected a list of channel names or patterns, got "
                           f"{describe(onode)}", onode)
        only = []
        for k, item in enumerate(onode.value):
            text = item.name()
            group = (text or "").replace("/", ".").split(".")[0]
            if text is None or group not in schema.OUTPUT_GROUPS and group != "*":
                raise rd.error(ow.child(k, item.line or ow.line),
                               f"expected a channel name or pattern starting with one of "
                               f"{', '.join(schema.OUTPUT_GROUPS)}, got {describe(item)}", item)
            only.append(text)
        only = tuple(only)
    return measures, only


def _analysis(rd: Reader, node: Node, where: Where, bodies: dict) -> dict[str, dict]:
    got = rd.fields(node, where, schema.ANALYSIS_MODES, what="analysis")
    out = {}
    for mode in got:
        items = rd.items(*got[mode])
        for key, message in schema.setting_name_problems(mode, [k for k, _, _ in items]):
            raise rd.error(next(w for k, _, w in items if k == key), message)
        out[mode] = {key: rd.setting(child, w, schema.ANALYSIS_DIMENSIONS.get(key))
                     for key, child, w in items}  # fmt: skip
        wheres = {key: w for key, _, w in items}
        # Tolerances, steps and the number of output times, before any analysis allocates
        # (documented defaults t_start 0, step 0.01 s stand in for those not given).
        resolve_options(mode, out[mode], defaults={"t_start": 0.0, "step": 0.01},
                        where_of=lambda key, m=mode, w=wheres: w.get(key, got[m][1]))
        if mode == "assembly" and "hold" in out[mode]:
            _check_hold(rd, out[mode]["hold"], wheres["hold"], bodies)
    return out


def _check_hold(rd: Reader, hold, where: Where, bodies: dict) -> None:
    """``analysis.assembly.hold``: a list of 'BODY.COORD' (COORD one of HOLD_COORDS), checked
    here once (the assembly trusts it)."""
    if not isinstance(hold, list):
        raise rd.error(where, f"expected a list of BODY.COORD, e.g. [collar.y], got {hold!r}")
    for k, h in enumerate(hold):
        body, _, coord = str(h).rpartition(".")
        if body not in bodies or coord not in HOLD_COORDS:
            raise rd.error(where.child(k), f"{h!r} is not BODY.COORD with BODY one of "
                           f"{', '.join(bodies)} and COORD one of {', '.join(HOLD_COORDS)}")


# -- studies ------------------------------------------------------------------------------------
STUDY_NAME_RE = re.compile(r"[A-Za-z0-9_][A-Za-z0-9_.+-]*")  # also a file/folder name


def _studies(rd: Reader, node: Node, where: Where, base: Node) -> dict[str, dict]:
    """``studies:`` -> {name: {'description', 'cases', 'figures', 'numbers', 'where'}}.

    Plain data for :mod:`mbsim.study` (format: docs/studies.md).  Each case's scene and
    ``set`` paths are applied to a copy of the deck as written (``base``), so a path that
    does not exist is an error here, for every study, as for scenes (on copy-on-write
    views of ``base``, which stays as it is).
    """
    out = {}
    for name, child, w in rd.items(node, where):
        if not STUDY_NAME_RE.fullmatch(name) or name == "all":
            why = "is reserved (`mbsim study DECK all` runs every study)" if name == "all" \
                else "is not a name (letters, digits, _ . + -)"
            raise rd.error(w, f"study name {name!r} {why}")
        got = rd.fields(child, w, schema.STUDY_KEYS, ("cases",), "a study")
        seq = _sequence(rd, *got["cases"])
        if not seq:
            raise rd.error(got["cases"][1], "expected at least one case")
        cases = [_study_case(rd, c, cw, base) for c, cw in seq]
        _unique(rd, cases, [cw for _, cw in seq], "label")
        _unique(rd, cases, [cw for _, cw in seq], "name")
        known = {c["label"]: c["name"] for c in cases} | {c["name"]: c["name"] for c in cases}
        seq = _sequence(rd, *got["figures"]) if "figures" in got else []
        figures = [_study_figure(rd, f, fw, known) for f, fw in seq]
        _unique(rd, figures, [fw for _, fw in seq], "name")
        seq = _sequence(rd, *got["numbers"]) if "numbers" in got else []
        numbers = [_study_number(rd, n, nw, known) for n, nw in seq]
        out[name] = {
            "description": _text(rd, *got["description"]) if "description" in got else "",
            "cases": cases, "figures": figures, "numbers": numbers, "where": str(w),
        }  # fmt: skip
    return out


def _sequence(rd: Reader, node: Node, where: Where) -> list[tuple[Node, Where]]:
    if node.kind == "scalar" and node.value is None:
        return []
    if node.kind != "seq":
        raise rd.error(where, f"expected a list, got {describe(node)}", node)
    return [(child, rd.item(where, i, child)) for i, child in enumerate(node.value)]


def _text(rd: Reader, node: Node, where: Where) -> str:
    text = node.name()
    if text is None:
        raise rd.error(where, f"expected a text, got {describe(node)}", node)
    return str(text)


def _unique(rd: Reader, items: list[dict], wheres: list[Where], key: str) -> None:
    seen = set()
    for item, where in zip(items, wheres):
        if item[key] in seen:
            hint = " (give the cases different `name`s)" if key == "name" else ""
            raise rd.error(where, f"{key} {item[key]!r} is used twice{hint}")
        seen.add(item[key])


def _slug(text: str) -> str:
    """A file name from a case label: 'k = 1000' -> 'k_1000'."""
    return re.sub(r"[^A-Za-z0-9.+-]+", "_", text).strip("_.") or "case"


def _study_case(rd: Reader, node: Node, where: Where, base: Node) -> dict:
    got = rd.fields(node, where, schema.STUDY_CASE_KEYS, ("label", "mode"), "a study case")
    case = {"label": _text(rd, *got["label"]), "where": str(where)}
    case["name"] = _text(rd, *got["name"]) if "name" in got else _slug(case["label"])
    if not STUDY_NAME_RE.fullmatch(case["name"]):
        raise rd.error(got["name"][1], f"case name {case['name']!r} is not a name "
                       "(letters, digits, _ . + -)")  # fmt: skip
    case["mode"] = rd.choice(*got["mode"], schema.STUDY_MODES, "mode")
    trial = cow(base)  # set_path copies what it edits: base stays as written
    case["scene"] = None
    if "scene" in got:
        case["scene"] = rd.name(*got["scene"], scene_names(base), "scene")
        apply_scene(trial, case["scene"], rd.file)
    case["set"] = {}
    if "set" in got:
        for path, value, w in rd.items(*got["set"]):
            try:
                set_path(trial, path, value, schema.can_add)
            except PathError as exc:
                raise rd.error(w, f"cannot set {path}: {exc.message}") from None
            case["set"][path] = to_plain(value)
    case["options"] = {}
    if "options" in got:
        case["options"] = {
            key: rd.setting(child, w, schema.ANALYSIS_DIMENSIONS.get(key))
            for key, child, w in rd.items(*got["options"])
        }
        wheres = {key: w for key, _, w in rd.items(*got["options"])}
        for key, message in schema.setting_name_problems(case["mode"], case["options"]):
            raise rd.error(wheres[key], message)
        resolve_options(case["mode"], case["options"], defaults={},
                        where_of=lambda key: wheres.get(key, got["options"][1]))
    return case


def _case_list(rd: Reader, node: Node, where: Where, known: dict[str, str]) -> list[str]:
    names = []
    for child, w in _sequence(rd, node, where):
        names.append(known[rd.name(child, w, known, "case (label or name)")])
    return names


def _channels(rd: Reader, node: Node, where: Where) -> list[str]:
    if node.kind == "seq":
        return [_text(rd, c, w) for c, w in _sequence(rd, node, where)]
    return [_text(rd, node, where)]


def _study_figure(rd: Reader, node: Node, where: Where, known: dict[str, str]) -> dict:
    got = rd.fields(node, where, schema.STUDY_FIGURE_KEYS, ("name", "y"), "a study figure")
    fig = {"name": _text(rd, *got["name"]), "where": str(where)}
    if not STUDY_NAME_RE.fullmatch(fig["name"]):
        raise rd.error(got["name"][1], f"figure name {fig['name']!r} is not a file name "
                       "(letters, digits, _ . + -)")  # fmt: skip
    fig["y"] = _channels(rd, *got["y"])
    fig["x"] = _text(rd, *got["x"]) if "x" in got else "time"
    for key in ("title", "xlabel", "ylabel", "caption"):
        fig[key] = _text(rd, *got[key]) if key in got else ""
    for key in ("scale", "xscale"):
        fig[key] = rd.number(*got[key]) if key in got else 1.0
    fig["cases"] = _case_list(rd, *got["cases"], known) if "cases" in got else []
    fig["labels"] = _figure_labels(rd, *got["labels"], fig["y"]) if "labels" in got else []
    return fig


def _curve_count(selector: str) -> int | None:
    """Curves per case that a figure's channel selector gives: 1 for one component
    (``bodies.b.r.x``, ``joints.A.force_j[0]``, ``forces.f.force.x``), the channel's width
    for a channel of ``schema.STUDY_FIGURE_WIDTHS``; None when only the result can tell (the
    quantities of a force element, ``constraints.lam``)."""
    key = selector.replace(".", "/").strip("/")
    if re.search(r"\[-?\d+\]$", key):
        return 1
    parts = key.split("/")
    # monitors/energy, bodies/b/r
    depth = 2 if parts[0] in ("monitors", "constraints", "error") else 3
    if len(parts) == depth and parts[-1] in schema.STUDY_FIGURE_WIDTHS.get(parts[0], {}):
        return schema.STUDY_FIGURE_WIDTHS[parts[0]][parts[-1]]
    if len(parts) == depth + 1 and parts[0] in ("bodies", "points", "joints", "forces"):
        return 1  # a component label: bodies/b/r/x
    return None


def _figure_labels(rd: Reader, node: Node, where: Where, ys: list[str]) -> list[str]:
    """``labels``: one legend text per curve of a case, counted against ``y`` where the
    selectors tell (:func:`_curve_count`); the rest is checked when the figure is drawn."""
    labels = [_text(rd, c, w) for c, w in _sequence(rd, node, where)]
    counts = [_curve_count(y) for y in ys]
    if None not in counts and len(labels) != sum(counts):
        each = ", ".join(f"{y}: {n}" for y, n in zip(ys, counts))
        raise rd.error(where, f"{len(labels)} labels given for {sum(counts)} curves per case "
                       f"({each}); give one per channel or component")  # fmt: skip
    known = sum(n for n in counts if n is not None) + counts.count(None)
    if None in counts and len(labels) < known:
        raise rd.error(where, f"{len(labels)} labels given for at least {known} curves per "
                       "case; give one per channel or component")  # fmt: skip
    return labels


def _study_number(rd: Reader, node: Node, where: Where, known: dict[str, str]) -> dict:
    got = rd.fields(node, where, schema.STUDY_NUMBER_KEYS, ("name", "y"), "a study number")
    num = {"name": _text(rd, *got["name"]), "y": _text(rd, *got["y"]), "where": str(where)}
    num["stat"] = rd.choice(*got["stat"], schema.STUDY_STATS, "stat") if "stat" in got \
        else "final"
    num["scale"] = rd.number(*got["scale"]) if "scale" in got else 1.0
    num["unit"] = _text(rd, *got["unit"]) if "unit" in got else ""
    num["cases"] = _case_list(rd, *got["cases"], known) if "cases" in got else []
    num["from"] = rd.number(*got["from"], "time") if "from" in got else None
    num["band"] = rd.number(*got["band"]) if "band" in got else 0.02
    if not 0 < num["band"] < 1:
        raise rd.error(got["band"][1], f"band must be between 0 and 1, got {num['band']:g}")
    return num
