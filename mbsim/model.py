"""compile_model(spec) -> Model: the one place where names become indices.

After compilation the Model is frozen: arrays are read-only and every per-step quantity
travels in function arguments (:mod:`mbsim.core`).  Every constraint row keeps the
name of the item it came from (``row_item``), so that errors and outputs name joints,
not matrix rows (MuJoCo's ``efc_id``).  The Model holds physics and names only, not its
deck: what a run takes from the deck besides (its ``analysis:`` settings, the assembly's
``hold``, ``outputs: only:``, the text stored in results) is read where the run is
requested (:func:`mbsim.options.run_options`) and passed in with the options.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from types import MappingProxyType
from typing import Any

import numpy as np

from mbsim import functions
from mbsim.constraints.blocks import KERNELS, Block
from mbsim.constraints.joints import DRIVERS, JOINTS
from mbsim.deck.spec import DeckSpec, PointSet
from mbsim.errors import DeckError, Where
from mbsim.rotations import B_tensor


@dataclass(frozen=True)
class Item:
    """A constraint item: a joint, a driver, a ground constraint or a normalisation row."""

    name: str
    kind: str  # 'joint' | 'driver' | 'ground' | 'normalization'
    type: str
    rows: np.ndarray  # global row numbers, in the item's equation order
    bi: int
    bj: int  # -1 for one-body items
    P_i: np.ndarray  # (3,) joint point on body i, body coordinates
    P_j: np.ndarray | None
    C_i: np.ndarray  # (3, 3) joint frame on body i, columns f, g, h (body coordinates)
    C_j: np.ndarray | None
    driver: Any = None  # driver class (for effort) and its TimeFunction
    func: Any = None
    where: Where = field(default_factory=Where)


@dataclass(frozen=True)
class Model:
    title: str
    file: str
    body_names: tuple[str, ...]
    nb: int
    nq: int  # 7 nb
    m: int  # constraint rows
    mass: np.ndarray  # (nb,) kg
    J_local: np.ndarray  # (nb, 3, 3) inertia about the centroid, body frame
    is_ground: np.ndarray  # (nb,) bool
    q0: np.ndarray  # (nq,) initial estimate [r, p] per body
    rdot0: np.ndarray  # (nb, 3) given centroid velocities (nan where not given)
    omega0: np.ndarray  # (nb, 3) given global angular velocities (nan where not given)
    omega0_local: np.ndarray  # (nb, 3) given body-frame angular velocities (nan: not given)
    gravity: np.ndarray  # (3,)
    blocks: tuple[Block, ...]
    items: tuple[Item, ...]
    row_item: np.ndarray  # (m,) index into items
    row_label: tuple[str, ...]  # (m,) e.g. 'REV2[4] dot1(h_i,f_j)'
    forces: tuple = ()
    outputs: tuple = ()  # ((name, body index, (3,) local point), ...)
    # outputs: measures: name -> mbsim.measures.OutputMeasure, evaluated at the outputs
    measures: Mapping[str, Any] = field(default_factory=lambda: MappingProxyType({}))
    events: tuple = ()  # the deck's events (mbsim.events.UserEvent)

    def item(self, name: str) -> Item:
        for it in self.items:
            if it.name == name:
                return it
        raise KeyError(name)

    def body_index(self, name: str) -> int:
        return self.body_names.index(name)

    def rows_of(self, kind: str) -> np.ndarray:
        rows = [it.rows for it in self.items if it.kind == kind]
        return np.concatenate(rows or [np.zeros(0, int)])

    def items_of_rows(self, rows) -> list[str]:
        """Names of the items that own the given rows, in order of first appearance."""
        seen: list[str] = []
        for r in np.atleast_1d(rows):
            n = self.items[self.row_item[r]].name
            if n not in seen:
                seen.append(n)
        return seen


def joint_frame(ps: PointSet | None) -> dict[str, np.ndarray]:
    """P and unit vectors f (P->Q), g (P->R orthogonalised against f), h = f x g."""
    out = {"P": np.zeros(3) if ps is None else np.asarray(ps.P, float)}
    if ps is None or ps.Q is None:
        f = np.array([1.0, 0.0, 0.0])
    else:
        f = np.asarray(ps.Q, float) - out["P"]
        f = f / _norm(f)
    if ps is not None and ps.R is not None:
        g = np.asarray(ps.R, float) - out["P"]
    else:  # any perpendicular: the axis least aligned with f
        g = np.eye(3)[int(np.argmin(np.abs(f)))]
    g = g - f * (f @ g)
    g = g / _norm(g)
    out.update(f=f, g=g, h=_cross(f, g))
    return out


def _norm(v: np.ndarray) -> float:
    """|v| of a 3-vector as np.linalg.norm computes it (sqrt(v . v)), without its dispatch."""
    return math.sqrt(v.dot(v))


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """a x b of two 3-vectors, each component as np.cross forms it (a1 b2 - a2 b1, ...),
    without its dispatch (about 15 us a call, 13 calls for the governor's joints)."""
    a0, a1, a2 = a.tolist()
    b0, b1, b2 = b.tolist()
    return np.array([a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0])


def _frames_of(bi_name, bj_name, points) -> dict[str, np.ndarray]:
    fi = joint_frame(points.get(bi_name))
    fj = joint_frame(points.get(bj_name)) if bj_name is not None else joint_frame(None)
    fr = {f"{k}_i": v for k, v in fi.items()}
    fr.update({f"{k}_j": v for k, v in fj.items()})
    return fr


class _Rows:
    """Collects basic rows during compilation, then stacks them into kernel Blocks."""

    def __init__(self):
        self.m = 0
        self.by_kernel: dict[str, list] = {}
        self.labels: list[str] = []
        self.owner: list[int] = []

    def add(self, kernel, args, frames, bi, bj, target, func, squared, item_no, label):
        ne = KERNELS[kernel]
        rows = np.arange(self.m, self.m + ne)
        self.m += ne
        vecs = {}
        for key, ref in args.items():
            vecs[key] = frames[ref]
        if kernel == "dot2":
            vecs["on_j"] = args["a"].endswith("_j")
        self.by_kernel.setdefault(kernel, []).append(
            dict(rows=rows, bi=bi, bj=bj, vecs=vecs, target=target, func=func, squared=squared))
        self.owner += [item_no] * ne
        self.labels += [f"{label} {kernel}" + (f"[{k}]" if ne > 1 else "") for k in range(ne)]
        return rows

    def blocks(self, nq: int) -> tuple[Block, ...]:
        out = []
        for kernel, entries in self.by_kernel.items():
            ne = KERNELS[kernel]
            rows = np.array([e["rows"] for e in entries])
            bi = np.array([e["bi"] for e in entries], dtype=int)
            bj = np.array([e["bj"] for e in entries], dtype=int)
            keys = entries[0]["vecs"].keys()
            vecs = {k: np.array([e["vecs"][k] for e in entries]) for k in keys}
            for key in list(vecs):  # B(p, a') = T(a') p, precomputed (mbsim.rotations.B_tensor)
                if vecs[key].ndim == 2 and vecs[key].shape[1] == 3:
                    vecs[key + "~T"] = B_tensor(vecs[key])
            c_const = np.array([[e["target"]] * ne for e in entries], dtype=float)
            funcs = tuple((n, e["func"], e["squared"]) for n, e in enumerate(entries)
                          if e["func"] is not None)
            k = len(entries)
            col = np.arange(7)
            sc = {
                "ri": np.repeat(rows.reshape(-1), 7),
                "ci": (7 * bi[:, None, None] + col[None, None, :]).repeat(ne, 1).reshape(-1),
            }
            if bj[0] >= 0:
                sc["rj"] = sc["ri"]
                sc["cj"] = (7 * bj[:, None, None] + col[None, None, :]).repeat(ne, 1).reshape(-1)
            for a in list(vecs.values()) + [rows, bi, bj, c_const] + list(sc.values()):
                a.setflags(write=False)
            assert rows.shape == (k, ne)
            out.append(Block(kernel, rows, bi, bj, vecs, c_const, funcs, ne, sc))
        return tuple(out)


def compile_model(spec: DeckSpec) -> Model:
    """Resolve names to indices, build frames and kernel blocks, freeze (see module doc)."""
    names = tuple(spec.bodies)
    nb = len(names)
    idx = {n: k for k, n in enumerate(names)}
    mass = np.array([spec.bodies[n].mass for n in names], dtype=float)
    J = np.array([spec.bodies[n].inertia for n in names], dtype=float).reshape(nb, 3, 3)
    ground = np.array([spec.bodies[n].ground for n in names], dtype=bool)
    q0 = np.zeros(7 * nb)
    nan3 = np.full(3, np.nan)
    rdot0, om0, oml0 = np.zeros((nb, 3)), np.zeros((nb, 3)), np.zeros((nb, 3))
    for k, n in enumerate(names):
        b = spec.bodies[n]
        q0[7 * k: 7 * k + 3] = b.r
        q0[7 * k + 3: 7 * k + 7] = b.p / np.linalg.norm(b.p)
        rdot0[k] = nan3 if b.rdot is None else b.rdot
        om0[k] = nan3 if b.omega is None else b.omega
        oml0[k] = nan3 if b.omega_local is None else b.omega_local

    rows = _Rows()
    items: list[Item] = []

    def body(name, where):
        if name not in idx:
            raise DeckError(f"unknown body {name!r}", where)
        return idx[name]

    for jn, js in spec.joints.items():
        cls = JOINTS.get(js.type)
        if cls is None:
            raise DeckError(f"unknown joint type {js.type!r}", js.where.child("type"))
        bi_name, bj_name = js.bodies
        bi = body(bi_name, js.where.child("bodies"))
        bj = body(bj_name, js.where.child("bodies")) if bj_name is not None else -1
        fr = _frames_of(bi_name, bj_name, js.points)
        target = 0.0
        if cls.target == "distance":
            target = float(js.data["distance"]) ** 2
        item_rows = []
        func = None
        for kernel, args in cls.rows:
            if kernel == "absolute":
                args = dict(args)
                value = js.data.get("value", 0.0)
                func = functions.from_spec(value)
                tgt = 0.0
                fr["axis"] = "xyz".index(js.data.get("axis", "x"))
                args["axis"] = "axis"
                r = rows.add(kernel, args, fr, bi, -1, tgt,
                             None if func.kind == "constant" else func, False, len(items), jn)
                if func.kind == "constant":
                    rows.by_kernel[kernel][-1]["target"] = func.value
            else:
                r = rows.add(kernel, args, fr, bi, bj if kernel != "absolute" else -1,
                             target if kernel == "distance" else 0.0, None, False, len(items), jn)
            item_rows.append(r)
        items.append(_item(jn, "joint", js.type, item_rows, bi, bj, fr, js.where, func=func))

    for dn, ds in spec.drivers.items():
        cls = DRIVERS[ds.type]
        func = functions.from_spec(ds.function)
        if cls.joint_types:
            js = spec.joints.get(ds.joint)
            if js is None:
                raise DeckError(f"unknown joint {ds.joint!r}", ds.where.child("joint"))
            if js.type not in cls.joint_types:
                raise DeckError(f"a {ds.type} driver needs a joint of type "
                                f"{' or '.join(cls.joint_types)}; {ds.joint} is {js.type}",
                                ds.where.child("joint"))
            bi_name, bj_name = js.bodies
            fr = _frames_of(bi_name, bj_name, js.points)
        else:
            bi_name, bj_name = ds.bodies
            fr = _frames_of(bi_name, bj_name, ds.points)
        bi = body(bi_name, ds.where.child("bodies"))
        bj = body(bj_name, ds.where.child("bodies")) if bj_name is not None else -1
        item_rows = []
        for kernel, args in cls.rows:
            if kernel == "absolute":
                args = dict(args, axis="axis")
                fr["axis"] = "xyz".index(ds.data.get("axis", "x"))
            r = rows.add(kernel, args, fr, bi, bj, 0.0, func, cls.squared, len(items), dn)
            item_rows.append(r)
        items.append(_item(dn, "driver", ds.type, item_rows, bi, bj, fr, ds.where, cls, func))

    fr0 = joint_frame(None)
    for k, n in enumerate(names):
        if ground[k]:
            frg = {"P_i": fr0["P"]}
            r = rows.add("ground", {}, frg, k, -1, 0.0, None, False, len(items), f"ground:{n}")
            items.append(_item(f"ground:{n}", "ground", "ground", [r], k, -1,
                               {"P_i": np.zeros(3), "f_i": fr0["f"], "g_i": fr0["g"],
                                "h_i": fr0["h"]}, spec.bodies[n].where))
    for k, n in enumerate(names):
        r = rows.add("normalization", {}, {}, k, -1, 1.0, None, False, len(items), f"norm:{n}")
        items.append(_item(f"norm:{n}", "normalization", "normalization", [r], k, -1,
                           {"P_i": np.zeros(3), "f_i": fr0["f"], "g_i": fr0["g"],
                            "h_i": fr0["h"]}, spec.bodies[n].where))
    # ground constraint targets: r0 and e of the deck's ground position
    for e in rows.by_kernel.get("ground", []):
        k = e["bi"]
        e["target"] = 0.0
        e["c_vec"] = np.concatenate([q0[7 * k: 7 * k + 3], q0[7 * k + 4: 7 * k + 7]])
    blocks = list(rows.blocks(7 * nb))
    for n, b in enumerate(blocks):
        if b.kernel == "ground":
            c = np.array([e["c_vec"] for e in rows.by_kernel["ground"]])
            c.setflags(write=False)
            blocks[n] = Block(b.kernel, b.rows, b.bi, b.bj, b.vecs, c, b.funcs, b.ne, b.scatter)

    from mbsim.forces import compile_forces  # forces know the body index

    forces = compile_forces(spec, idx)
    outputs = tuple((on, body(o.body, o.where.child("body")), np.asarray(o.point, float))
                    for on, o in spec.outputs.items())
    from mbsim.events import compile_events

    events = compile_events(getattr(spec, "events", {}) or {}, idx)
    for a in (mass, J, ground, q0, rdot0, om0, oml0):
        a.setflags(write=False)
    row_item = np.array(rows.owner, dtype=int)
    row_item.setflags(write=False)
    model = Model(
        title=spec.title, file=spec.file, body_names=names, nb=nb, nq=7 * nb, m=rows.m,
        mass=mass, J_local=J, is_ground=ground, q0=q0, rdot0=rdot0, omega0=om0,
        omega0_local=oml0, gravity=np.asarray(spec.gravity, float), blocks=tuple(blocks),
        items=tuple(items), row_item=row_item, row_label=tuple(rows.labels), forces=forces,
        outputs=outputs, measures=MappingProxyType(dict(spec.output_measures)), events=events,
    )
    for el in forces:  # elements that read the compiled rows (a friction's joint reaction)
        if hasattr(el, "bind"):
            el.bind(model)
    return model


def _item(name, kind, typ, row_list, bi, bj, fr, where, driver=None, func=None) -> Item:
    rows = np.concatenate(row_list) if row_list else np.zeros(0, int)
    rows.setflags(write=False)
    Ci = np.column_stack([fr["f_i"], fr["g_i"], fr["h_i"]])
    Cj = np.column_stack([fr["f_j"], fr["g_j"], fr["h_j"]]) if "f_j" in fr and bj >= 0 else None
    return Item(name, kind, typ, rows, bi, bj, fr["P_i"], fr.get("P_j") if bj >= 0 else None,
                Ci, Cj, driver, func, where)
