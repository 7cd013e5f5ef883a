"""Helpers shared by the analyses: rank checks, body/point output channels."""

from __future__ import annotations

import numpy as np
import scipy.linalg as la

from mbsim import equations as eq
from mbsim.errors import DeckError, Where
from mbsim.result import Result
from mbsim.rotations import G as rot_G

XYZ = ("x", "y", "z")


def rank_and_redundant(model, J, tol=1e-9):
    """Rank of Phi_q by QR with column pivoting of Phi_q^T; the rows beyond the rank are the
    (locally) redundant ones, named by their items.  tol is relative to the largest pivot."""
    if J.shape[0] == 0:
        return 0, np.zeros(0, int)
    R, piv = la.qr(J.T, mode="r", pivoting=True)
    d = np.abs(np.diag(R))
    if d.size == 0 or d[0] == 0:
        return 0, np.arange(J.shape[0])
    rank = int(np.sum(d > tol * d[0]))
    return rank, np.sort(piv[rank:])


def require_dof_zero(model, dof: int, what: str) -> None:
    """A driven analysis (kinematic, inverse) needs DOF = 0: otherwise a deck error at the
    deck's ``drivers`` (file and line of its first driver) saying how many are missing."""
    if dof == 0:
        return
    drivers = [it for it in model.items if it.kind == "driver"]
    first = next((d for d in (model.spec.drivers.values() if model.spec else ())), None)
    where = Where(model.file, "drivers", first.where.line if first is not None else None)
    names = ", ".join(d.name for d in drivers) or "none"
    raise DeckError(f"{what} needs DOF = 0, but the drivers ({names}) leave DOF = {dof}: add "
                    f"{dof} driver(s), or run --mode dynamic", where)


def singular_rows(model, J, k=1):
    """Rows taking part in the k most singular directions of J (left singular vectors)."""
    U, s, _ = np.linalg.svd(J)
    w = np.abs(U[:, -k:]).max(axis=1) if J.shape[0] <= J.shape[1] else np.abs(U[:, :]).max(1)
    return np.argsort(-w)[: min(6, len(w))], s


def body_kinematics(model, q, qd, qdd):
    """Per body: r, p, rd, omega, omega_local, rdd, omegad, omegad_local, each (nb, 3/4)."""
    nb = model.nb
    Q = q.reshape(nb, 7)
    V = qd.reshape(nb, 7)
    Acc = qdd.reshape(nb, 7)
    st = eq.State(model, q, qd)
    Gm = rot_G(Q[:, 3:])
    wl = 2 * np.einsum("bij,bj->bi", Gm, V[:, 3:])
    w = np.einsum("bij,bj->bi", st.A, wl)
    wdl = 2 * np.einsum("bij,bj->bi", Gm, Acc[:, 3:])  # G(pd) pd = 0, so w'dot = 2 G pdd
    wd = np.einsum("bij,bj->bi", st.A, wdl)
    return dict(r=Q[:, :3], p=Q[:, 3:], rd=V[:, :3], omega=w, omega_local=wl, rdd=Acc[:, :3],
                omegad=wd, omegad_local=wdl, A=st.A)


class Recorder:
    """Collects per-time body states and writes the standard channels into a Result."""

    def __init__(self, model):
        self.model = model
        self.t: list[float] = []
        self.q: list[np.ndarray] = []
        self.qd: list[np.ndarray] = []
        self.qdd: list[np.ndarray] = []
        self.extra: dict[str, list] = {}

    def add(self, t, q, qd, qdd, **extra):
        self.t.append(float(t))
        self.q.append(np.array(q, float))
        self.qd.append(np.array(qd, float))
        self.qdd.append(np.array(qdd, float))
        for k, v in extra.items():
            self.extra.setdefault(k, []).append(v)

    def __len__(self):
        return len(self.t)

    def result(self, mode: str) -> Result:
        model = self.model
        res = Result(mode=mode, t=np.array(self.t))
        res.deck_file = model.file
        res.deck_text = model.spec.text if model.spec is not None else ""
        res.names = {
            "bodies": list(model.body_names),
            "joints": [it.name for it in model.items if it.kind == "joint"],
            "drivers": [it.name for it in model.items if it.kind == "driver"],
            "forces": [f.name for f in model.forces],
            "points": [o[0] for o in model.outputs],
        }
        nt = len(self.t)
        if nt == 0:
            return res
        kin = [body_kinematics(model, q, v, a) for q, v, a in zip(self.q, self.qd, self.qdd)]
        spec = [
            ("r", "m", "centroid position, global"),
            ("p", "", "Euler parameters e0 e1 e2 e3"),
            ("rd", "m/s", "centroid velocity, global"),
            ("omega", "rad/s", "angular velocity, global frame"),
            ("omega_local", "rad/s", "angular velocity, body frame"),
            ("rdd", "m/s^2", "centroid acceleration, global"),
            ("omegad", "rad/s^2", "angular acceleration, global frame"),
            ("omegad_local", "rad/s^2", "angular acceleration, body frame"),
        ]
        for b, name in enumerate(model.body_names):
            for key, unit, desc in spec:
                data = np.array([k[key][b] for k in kin])
                comps = ("e0", "e1", "e2", "e3") if key == "p" else XYZ
                res.add(f"bodies/{name}/{key}", data, unit, desc, comps)
        for name, b, s in model.outputs:
            pos, vel, acc = [], [], []
            for k in kin:
                sg = k["A"][b] @ s
                w, wd = k["omega"][b], k["omegad"][b]
                pos.append(k["r"][b] + sg)
                vel.append(k["rd"][b] + np.cross(w, sg))
                acc.append(k["rdd"][b] + np.cross(wd, sg) + np.cross(w, np.cross(w, sg)))
            res.add(f"points/{name}/position", pos, "m", f"point {name}, global", XYZ)
            res.add(f"points/{name}/velocity", vel, "m/s", f"velocity of point {name}", XYZ)
            res.add(f"points/{name}/acceleration", acc, "m/s^2", f"acceleration of {name}", XYZ)
        self._force_channels(res)
        return res

    def _force_channels(self, res) -> None:
        """forces/<name>/<quantity> from each element's ``channels(st, t)`` (length, force...)."""
        model = self.model
        if not model.forces:
            return
        from mbsim.equations import State

        data: dict[str, list] = {}
        units: dict[str, str] = {}
        for t, q, v in zip(self.t, self.q, self.qd):
            st = State(model, q, v)
            for el in model.forces:
                for key, (val, unit) in el.channels(st, t).items():
                    name = f"forces/{el.name}/{key}"
                    data.setdefault(name, []).append(np.asarray(val, dtype=float))
                    units[name] = unit
        for name, vals in data.items():
            arr = np.array(vals)
            res.add(name, arr, units[name], f"force element {name.split('/')[1]}: "
                    f"{name.split('/')[2]}", XYZ if arr.ndim == 2 and arr.shape[1] == 3 else ())
