"""Helpers shared by the analyses: rank checks, body/point output channels."""

from __future__ import annotations

import numpy as np

from mbsim import core
from mbsim.analyses.pivoted_qr import qr_pivoted_r
from mbsim.errors import DeckError, Where
from mbsim.result import Result
from mbsim.rotations import A as rot_A
from mbsim.rotations import G as rot_G

XYZ = ("x", "y", "z")


DENSE_NQ = 400
"""Set-up (rank, redundancy, assembly steps, initial velocities) uses dense rank-revealing
factorizations (QR with column pivoting, SVD: O(nq^3), 0.1 s at nq = 400) below this many
coordinates, and sparse factorizations with a fill-reducing ordering (linear in the size of
chains, trees and loops) from it on, falling back to dense only where a sparse factor finds
the rows dependent."""

SPARSE_PIVOT = 1e-12
"""Smallest pivot of the sparse LDL^T of Phi_q Phi_q^T, relative to its diagonal entry, that
certifies full row rank (a singular value ratio of about 1e-6; dependent rows leave pivots
of round-off size, 1e-16 relative): below it the dense QR decides which rows are redundant."""


def sparse_gram_factor(J):
    """SuperLU factor of S = J J^T ((m, m), symmetric positive definite when J (m, nq) has
    full row rank) in a fill-reducing symmetric ordering (minimum degree on S), pivots on the
    diagonal; None when some pivot is below SPARSE_PIVOT of its diagonal entry (dependent
    rows) or the factorization fails."""
    import scipy.sparse as sp
    from scipy.sparse.linalg import splu

    J = sp.csr_matrix(J)
    S = (J @ J.T).tocsc()
    diag = S.diagonal()
    if J.shape[0] == 0 or not np.all(diag > 0):
        return None
    try:
        lu = splu(S, permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.0,
                  options={"SymmetricMode": True})
    except RuntimeError:  # exactly singular
        return None
    piv = np.abs(lu.U.diagonal())
    if not np.array_equal(lu.perm_r, lu.perm_c) or \
            not np.all(piv > SPARSE_PIVOT * diag[lu.perm_c]):
        return None
    return lu


def min_norm_step(J, rhs):
    """dq (nq,) of least norm with J dq = rhs (least squares when inconsistent): dense lstsq,
    or J^T (J J^T)^-1 rhs on the sparse factor when J is sparse with full row rank."""
    if not isinstance(J, np.ndarray):  # sparse (scipy imported only then)
        lu = sparse_gram_factor(J)
        if lu is not None:
            return J.T @ lu.solve(rhs)
        J = J.toarray()
    return np.linalg.lstsq(J, rhs, rcond=None)[0]


def rank_and_redundant(model, J, tol=1e-9, lapack=True):
    """Rank of Phi_q by QR with column pivoting of Phi_q^T; the rows beyond the rank are the
    (locally) redundant ones, named by their items.  tol is relative to the largest pivot.
    J dense or sparse; a sparse J (large models, DENSE_NQ) with full row rank is certified
    by the sparse factor of J J^T without the dense QR.

    lapack: the QR of scipy.linalg (LAPACK dgeqp3), or False for the same algorithm in numpy
    alone (:func:`mbsim.analyses.pivoted_qr.qr_pivoted_r`; `mbsim check`, which then
    imports no scipy: 0.4 s).  The two agree on the rank and on the redundant rows except
    where rows of equal norm tie and round-off decides (the parallel four-bar deck): runs
    keep LAPACK's choice, to which the runs past singular positions and their tests are
    sensitive (tests/integrators/test_index1_tangent.py, tests/analyses/test_estimate.py)."""
    if J.shape[0] == 0:
        return 0, np.zeros(0, int)
    if not isinstance(J, np.ndarray):
        if sparse_gram_factor(J) is not None:
            return J.shape[0], np.zeros(0, int)
        J = J.toarray()
    if lapack:
        d, piv = _geqp3_pivots(J.T)
    else:
        R, piv = qr_pivoted_r(J.T)  # numpy alone: scipy.linalg costs ~0.4 s to import
        d = np.abs(np.diag(R))
    if d.size == 0 or d[0] == 0:
        return 0, np.arange(J.shape[0])
    rank = int(np.sum(d > tol * d[0]))
    return rank, np.sort(piv[rank:])


_GEQP3 = {}  # dtype char -> scipy's LAPACK dgeqp3 wrapper, looked up once


def _geqp3_pivots(a):
    """(|diag R| (min(n, m),), piv (m,) 0-based) of LAPACK's QR with column pivoting of ``a``
    (n, m): the call ``scipy.linalg.qr(a, mode="r", pivoting=True)`` makes (the same
    routine, the same workspace size from its query, so the same numbers to the bit),
    without that function's wrappers (a quarter of a 4-link chain run's set-up)."""
    a = np.asarray_chkfinite(a)  # as scipy.linalg.qr: NaN or inf is a ValueError
    geqp3 = _GEQP3.get(a.dtype.char)
    if geqp3 is None:
        from scipy.linalg.lapack import get_lapack_funcs

        geqp3 = _GEQP3[a.dtype.char] = get_lapack_funcs(("geqp3",), (a,))[0]
    lwork = geqp3(a, lwork=-1)[-2][0].real.astype(np.int_)
    qr, piv, _, _, info = geqp3(a, lwork=lwork)
    if info < 0:
        raise ValueError(f"illegal value in {-info}th argument of internal geqp3")
    return np.abs(np.diag(qr)), piv - 1


def require_dof_zero(model, dof: int, what: str) -> None:
    """A driven analysis (kinematic, inverse) needs DOF = 0: otherwise a deck error at the
    deck's ``drivers`` (file and line of its first driver) saying how many are missing."""
    if dof == 0:
        return
    drivers = [it for it in model.items if it.kind == "driver"]
    where = Where(model.file, "drivers", drivers[0].where.line if drivers else None)
    names = ", ".join(d.name for d in drivers) or "none"
    raise DeckError(f"{what} needs DOF = 0, but the drivers ({names}) leave DOF = {dof}: add "
                    f"{dof} driver(s), or run --mode dynamic", where)


def weakest_directions(J, k=1):
    """(U (m, k), s): the left singular vectors of the k smallest singular values of J
    (m <= nq rows), and singular values with s[0] the largest and s[-1] the smallest.

    Dense SVD below DENSE_NQ columns (or for a tall J); from there on the extreme eigenpairs
    of the sparse S = J J^T by Lanczos (scipy eigsh; the smallest in shift-invert mode about
    a shift of -1e-12 |S| below zero, so that a singular S factors): s then holds only the
    extreme values [s_max, s_(k), ..., s_min]."""
    import scipy.sparse as sp

    m, nq = J.shape
    if nq < DENSE_NQ or m > nq or m <= k + 1:
        U, s, _ = np.linalg.svd(J.toarray() if sp.issparse(J) else J)
        return U[:, m - k:] if m <= nq else U, s
    from scipy.sparse.linalg import eigsh

    J = sp.csr_matrix(J)
    S = (J @ J.T).tocsc()
    top = float(eigsh(S, k=1, which="LA", return_eigenvectors=False)[0])
    lam, U = eigsh(S, k=k, sigma=-1e-12 * top, which="LM")
    order = np.argsort(-lam)
    lam, U = lam[order], U[:, order]
    s = np.sqrt(np.maximum(np.concatenate([[top], lam]), 0.0))
    return U, s


def singular_rows(model, J, k=1):
    """Rows taking part in the k most singular directions of J (left singular vectors), and
    the singular values (s[0] the largest, s[-1] the smallest: :func:`weakest_directions`)."""
    U, s = weakest_directions(J, k)
    w = np.abs(U).max(axis=1)
    return np.argsort(-w)[: min(6, len(w))], s


def body_kinematics(model, q, qd, qdd):
    """Per body: r, p, rd, omega, omega_local, rdd, omegad, omegad_local, A.

    q, qd, qdd: (nq,) for one instant, giving (nb, 3/4) arrays, or (nt, nq) for a time
    series, giving (nt, nb, 3/4) arrays (time first): one vectorised evaluation."""
    nb = model.nb
    lead = np.shape(q)[:-1]
    Q = np.asarray(q, float).reshape(lead + (nb, 7))
    V = np.asarray(qd, float).reshape(lead + (nb, 7))
    Acc = np.asarray(qdd, float).reshape(lead + (nb, 7))
    A = rot_A(Q[..., 3:])
    Gm = rot_G(Q[..., 3:])
    wl = 2 * np.einsum("...ij,...j->...i", Gm, V[..., 3:])
    w = np.einsum("...ij,...j->...i", A, wl)
    wdl = 2 * np.einsum("...ij,...j->...i", Gm, Acc[..., 3:])  # G(pd) pd = 0: w'dot = 2 G pdd
    wd = np.einsum("...ij,...j->...i", A, wdl)
    return dict(r=Q[..., :3], p=Q[..., 3:], rd=V[..., :3], omega=w, omega_local=wl,
                rdd=Acc[..., :3], omegad=wd, omegad_local=wdl, A=A)


BODY_CHANNELS = (
    ("r", "m", "centroid position, global"),
    ("p", "", "Euler parameters e0 e1 e2 e3"),
    ("rd", "m/s", "centroid velocity, global"),
    ("omega", "rad/s", "angular velocity, global frame"),
    ("omega_local", "rad/s", "angular velocity, body frame"),
    ("rdd", "m/s^2", "centroid acceleration, global"),
    ("omegad", "rad/s^2", "angular acceleration, global frame"),
    ("omegad_local", "rad/s^2", "angular acceleration, body frame"),
)


class Recorder:
    """Collects the raw per-output state (t, q, qd, qdd) in growing arrays and, at the end,
    computes every channel vectorised over time (bodies, points, force elements, the deck's
    output measures), restricted to the deck's ``outputs: only:`` patterns."""

    def __init__(self, model, capacity: int = 256):
        self.model = model
        self._n = 0
        self._t = np.empty(capacity)
        self._s = np.empty((3, capacity, model.nq))  # q, qd, qdd rows
        self.extra: dict[str, list] = {}
        self._kin = (None, -1)  # kinematics() and the number of outputs it was computed for
        self._states = (None, -1)  # states() and the number of outputs it was built for

    def add(self, t, q, qd, qdd, **extra):
        n = self._n
        if n == self._t.size:  # grow by doubling: amortised O(1) per output
            self._t = np.concatenate([self._t, np.empty(n)])
            self._s = np.concatenate([self._s, np.empty_like(self._s)], axis=1)
        self._t[n] = t
        self._s[0, n], self._s[1, n], self._s[2, n] = q, qd, qdd
        for k, v in extra.items():
            lst = self.extra.setdefault(k, [])
            del lst[n:]  # (what an interrupted add left behind)
            lst.append(v)
        self._n = n + 1  # last: an add interrupted before here records nothing

    def add_many(self, t, q, qd, qdd):
        """:meth:`add` of k outputs at once (no extras): t (k,), q, qd, qdd (k, nq)."""
        n, k = self._n, len(t)
        if n + k > self._t.size:
            grow = max(n + k, 2 * self._t.size) - self._t.size
            self._t = np.concatenate([self._t, np.empty(grow)])
            self._s = np.concatenate([self._s, np.empty((3, grow, self.model.nq))], axis=1)
        self._t[n:n + k] = t
        self._s[0, n:n + k], self._s[1, n:n + k], self._s[2, n:n + k] = q, qd, qdd
        self._n = n + k  # last: an add interrupted before here records nothing

    def trim(self):
        """Drop what an interrupted :meth:`add` left in ``extra`` beyond the outputs."""
        for v in self.extra.values():
            del v[self._n:]

    def __len__(self):
        return self._n

    @property
    def t(self) -> np.ndarray:
        return self._t[: self._n]

    @property
    def q(self) -> np.ndarray:
        return self._s[0, : self._n]

    @property
    def qd(self) -> np.ndarray:
        return self._s[1, : self._n]

    @property
    def qdd(self) -> np.ndarray:
        return self._s[2, : self._n]

    def kinematics(self) -> dict:
        """:func:`body_kinematics` of the recorded outputs, computed once (the result's
        channels and the dynamic analysis' energy monitors both use it)."""
        if self._kin[1] != self._n:
            self._kin = (body_kinematics(self.model, self.q, self.qd, self.qdd), self._n)
        return self._kin[0]

    def result(self, mode: str, only: tuple[str, ...] | None = None) -> Result:
        """The Result with the standard channels (``only``: slash patterns, the run's
        ``outputs: only:`` (:attr:`mbsim.options.DeckContext.only`), None: every channel; see
        :func:`mbsim.measures.selected`).  The deck text is the caller's to add
        (:func:`mbsim.api.run_model`)."""
        from mbsim import measures as ms

        model = self.model
        patterns = only
        res = Result(mode=mode, t=self.t.copy())
        res.deck_file = model.file
        res.names = {
            "bodies": list(model.body_names),
            "joints": [it.name for it in model.items if it.kind == "joint"],
            "drivers": [it.name for it in model.items if it.kind == "driver"],
            "forces": [f.name for f in model.forces],
            "points": [o[0] for o in model.outputs],
        }
        measures = model.measures
        if measures:
            res.names["measures"] = list(measures)
        if self._n == 0:
            return res
        refs = [sel.replace(".", "/").strip("/") for m in measures.values()
                if m.type == "expression" for sel in m.data["channels"].values()]

        if patterns is None:  # every channel (no ``only:``): no test per channel
            def needed(path):
                return True
        else:
            def needed(path):
                return ms.selected(path, patterns) or any(
                    r == path or r.startswith(path + "/") or r.startswith(path + "[")
                    for r in refs)

        kin = self.kinematics()
        for b, name in enumerate(model.body_names):
            for key, unit, desc in BODY_CHANNELS:
                path = f"bodies/{name}/{key}"
                if needed(path):
                    res.add(path, kin[key][:, b], unit, desc,
                            ("e0", "e1", "e2", "e3") if key == "p" else XYZ)
        for name, b, s in model.outputs:
            paths = [f"points/{name}/{k}" for k in ("position", "velocity", "acceleration")]
            if not any(needed(p) for p in paths):
                continue
            pos, vel, acc = ms._point_state(kin, b, s)
            for path, data, unit, desc in zip(paths, (pos, vel, acc), ("m", "m/s", "m/s^2"), (
                    f"point {name}, global", f"velocity of point {name}",
                    f"acceleration of {name}")):
                if needed(path):
                    res.add(path, data, unit, desc, XYZ)
        self._force_channels(res, needed)
        if measures:
            self._measure_channels(res, kin, measures)
        if patterns is not None:
            for path in [p for p in res.channels if not ms.selected(p, patterns)]:
                del res.channels[path]
        return res

    def states(self) -> core.States:
        """The force elements' view of the recorded outputs (A, G, omega once for all)."""
        if self._states[1] != self._n:
            self._states = (core.States(self.model, self.q, self.qd), self._n)
        return self._states[0]

    def _force_channels(self, res, needed) -> None:
        """forces/<name>/<quantity> from each element's ``channels_many(states, t)`` (length,
        force...; array code where the element has it, else its scalar ``channels`` output by
        output), only for the elements with a channel that is needed.  A joint friction
        outside a run with modes (kinematic, equilibrium, linear) has none: its force is a
        mode of the dynamic run with the joint's reaction as normal load, which these
        analyses do not have (it once showed 0 N and a NaN mode that failed the run as an
        "overflow"); inverse dynamics derives its modes and adds its channels itself."""
        model = self.model
        if not model.forces:
            return
        from mbsim.forces.friction import JointFriction

        states, ts = self.states(), self.t
        for el in model.forces:
            if getattr(el, "hybrid", False):  # in each output's mode (mbsim.events)
                modes, lam = self.extra.get("modes"), self.extra.get("lam_all")
                if modes is None and isinstance(el, JointFriction):
                    continue  # its loads need the modes and reactions (inverse: its own)
                rows = [el.channels_in(None if modes is None else modes[k].get(el.name),
                                       states[k], ts[k], None if lam is None else lam[k],
                                       None if modes is None else modes[k])
                        for k in range(len(ts))]
                chans = {key: (np.array([np.asarray(r[key][0], float) for r in rows]), unit)
                         for key, (_, unit) in rows[0].items()}
                keys = [k for k in chans if needed(f"forces/{el.name}/{k}")]
            else:
                keys = [k for k in el.channels(states[0], ts[0])
                        if needed(f"forces/{el.name}/{k}")]
                if not keys:
                    continue
                chans = el.channels_many(states, ts)
            for key in keys:
                val, unit = chans[key]
                arr = np.asarray(val, dtype=float)
                res.add(f"forces/{el.name}/{key}", arr, unit, f"force element {el.name}: {key}",
                        XYZ if arr.ndim == 2 and arr.shape[1] == 3 else ())

    def _measure_channels(self, res, kin, measures) -> None:
        """measures/<name>, vectorised over time (mbsim.measures); expressions see t, the
        measures before them, kinetic_energy, potential_energy and the channels they name."""
        from mbsim import measures as ms
        from mbsim.output.export import select_columns

        model, t = self.model, self.t
        env: dict[str, np.ndarray] = {"t": t}
        for name, om in measures.items():
            if om.type == "expression":
                names = om.data["value"].names
                if "kinetic_energy" in names and "kinetic_energy" not in env:
                    env["kinetic_energy"] = kinetic_energies(model, kin)
                if "potential_energy" in names and "potential_energy" not in env:
                    env["potential_energy"] = potential_energies(model, self.q, kin,
                                                                  self.states())
                for local, sel in om.data["channels"].items():
                    cols = select_columns(res, sel)
                    if len(cols) != 1:
                        raise DeckError(f"measure {name}: channel {sel!r} has {len(cols)} "
                                        "components; name one (e.g. .z or [2])", om.where)
                    env[local] = cols[0].data
            data = ms.evaluate(model, om, kin, t, env)
            comps = ms.components_of(om)
            res.add(f"measures/{name}", data, ms.unit_of(om), ms.describe(om), comps)
            if comps:
                env.update({f"{name}_{c}": data[:, k] for k, c in enumerate(comps)})
            else:
                env[name] = data


def kinetic_energies(model, kin) -> np.ndarray:
    """(nt,) T = sum 1/2 m |rd|^2 + 1/2 w'^T J' w' (Haug Ch. 11), from batched kinematics."""
    wl = kin["omega_local"]
    rot = np.einsum("tbi,bij,tbj->t", wl, model.J_local, wl)
    return 0.5 * np.einsum("b,tbi,tbi->t", model.mass, kin["rd"], kin["rd"]) + 0.5 * rot


def potential_energies(model, q, kin, states=None) -> np.ndarray:
    """(nt,) V: gravity plus the force elements' potentials (``potential_many``), vectorised
    over the outputs; ``states``: :class:`mbsim.core.States` of q if already built."""
    V = -np.einsum("b,tbi,i->t", model.mass, kin["r"], model.gravity)
    if any(True for _ in model.forces):
        states = core.States(model, q) if states is None else states
        for el in model.forces:
            V = V + el.potential_many(states)
    return V
