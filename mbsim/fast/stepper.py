"""CompiledStep: the trial step and the dense output of an explicit RK integrator in C.

mbsim/fast/step.c takes one whole trial step of a tableau (rk.py's class data, passed in
as arrays) on the index-1 system y = (q, qd, w) of a :class:`~mbsim.fast.dynamics.System`:
the stages through ``mb_accelerations``, the embedded error norm, and after acceptance the
projection of q and qd and the derivative there; and evaluates the dense output of the
last accepted step at all output times inside it at once, each output projected.  Python
keeps the step-size controller, the change-point policy and every fallback: a call
returns a status (``ST_*``) as soon as one of them must decide.

What still runs in Python per stage: the time targets of driven rows (f, f', f'') and the
force elements that are not compiled (laws, rsda, tire: :mod:`mbsim.fast.dynamics`), through
one ctypes callback (``load``) per stage; models without either never leave C in a step.

Buffers (all owned here, handed to C once):

- ``K`` (16, ny): the stages, K[ns] = f(t + h, y_new), DOP853's extra stages after it;
- ``y``, ``f`` (ny,): the step's start and its derivative (written before each trial);
- ``y_new`` (the unprojected end), ``y_acc``, ``f_acc`` (the accepted, projected end and
  its derivative) (ny,);
- ``out`` (5,): error norm, smallest change-point measure of the trial's stages, measure of
  the last derivative, last projection residual, failure code of a factorisation;
- ``count`` (6,): the work done (``COUNTERS``), added to ``system.counters`` after a call,
  then the output samples whose velocities were projected on their positions' factor and
  those projected on a fresh one (``OUTPUT_COUNTERS``, ``REUSE_FACTOR``), added to
  ``output_projections``.

A third call takes many accepted steps in a row (``steps``: up to the last of a window of
output times), with the step-size controller of :mod:`mbsim.integrators.base` and the
change-point approach's bookkeeping in C too (``Loop``), and writes the outputs of each
step as it goes (``Outputs``: projected as ``dense`` does, or the plain interpolant for the
error estimate's companion, which also gives the loop its mesh of step ends); it returns
before any step that needs Python, and after one where the change-point policy's approach,
the stall watchdog or the Python dense output (a flagged output) must look.
"""

from __future__ import annotations

import ctypes

import numpy as np

from mbsim import core
from mbsim.fast import _lib

ST_ACCEPTED, ST_REJECTED, ST_SOLVE, ST_ALARM, ST_PROJECTION, ST_NONFINITE, ST_CALLBACK = range(7)
O_ERR, O_SMIN, O_SLAST, O_RES, O_CODE = range(5)
COUNTERS = ("function_evaluations", "constraint_evaluations", "factorizations",
            "newton_iterations")
OUTPUT_COUNTERS = ("kept", "fresh")
"""step.c's C_KEPT, C_FRESH after COUNTERS: output samples whose velocities were projected
on the Schur factor their positions' projection made, and those projected on a fresh one
(``CompiledStep.output_projections``)."""
REUSE_FACTOR = True
"""Project an output sample's velocities on the factor its positions' Newton step made
(step.c: project_sample); False: on a fresh factorisation, as before
(tests/integrators/test_output_projection.py)."""
ERROR_FORMS = {None: 0, "embedded": 1, "dop853": 2}
DENSE_FORMS = {"poly": 0, "dop853": 1, "hermite": 2}
N_K = 16  # rows of K: DOP853's 12 stages, f(t + h, y_new) and 3 extra stages

LOAD = ctypes.CFUNCTYPE(ctypes.c_int, ctypes.c_double, ctypes.c_int)


class RK(ctypes.Structure):
    """mb_rk of step.c, field for field."""

    _fields_ = (
        [(n, ctypes.c_int64) for n in
         ("ns", "nq", "err_kind", "dense_kind", "np", "project", "kkt", "stab", "reuse")]
        + [(n, ctypes.c_double) for n in
           ("rtol", "atol", "tangent", "proj_tol", "proj_fail", "alpha", "beta")]
        + [("load", ctypes.c_void_p)]
        + [(n, ctypes.c_void_p) for n in
           ("A", "B", "C", "E", "E3", "P", "AX", "CX", "D", "y", "f", "K", "y_new", "y_acc",
            "f_acc", "ys", "vm", "qw", "Fd", "out", "count")]
    )


LOOP_STOP, LOOP_NEAR, LOOP_TINY, LOOP_PYTHON, LOOP_OUTPUT = range(5)


class Loop(ctypes.Structure):
    """mb_loop of step.c: the step-size controller's settings and state."""

    _fields_ = (
        [(n, ctypes.c_double) for n in
         ("t", "t_bound", "t_stop", "h_abs", "h_max", "h_min", "h_fixed", "err_old",
          "exponent", "beta", "safety", "min_factor", "max_factor", "stall_floor")]
        + [(n, ctypes.c_int64) for n in ("max_steps", "max_rejects", "steps", "rejected",
                                         "why")]
        + [(n, ctypes.c_double) for n in ("t_old", "h_last", "s")]
        + [("ends", ctypes.POINTER(ctypes.c_double))]
        + [("times", ctypes.c_void_p)]
        + [(n, ctypes.c_int64) for n in ("n_out", "k_out", "project_out")]
        + [(n, ctypes.c_void_p) for n in ("Q", "QD", "W", "H", "flags", "mesh")]
        + [(n, ctypes.c_int64) for n in ("n_mesh", "k_mesh")]
        + [("ap", ctypes.c_void_p), ("ap_h_far", ctypes.c_double)]
    )


class ApproachState(ctypes.Structure):
    """mb_approach of step.c: changepoints.Approach's measure (its near() and accepted() in
    C, shared with the loop of many steps): the policy's switch, the rate -ds/dt, the last
    accepted state (t, s) and the entry s (NaN: none)."""

    _fields_ = [(n, ctypes.c_double) for n in ("tangent", "rate", "last_t", "last_s", "entry")]


class Outputs:
    """The output request of a :class:`Loop` (step.c: mb_loop's outputs): the output times
    ``times`` (n,) and fresh buffers Q, QD (n, nq), W, H (n,) that the loop fills from row
    ``loop.k_out`` on (H: the size of each output's step), from one allocation."""

    def __init__(self, times, nq, project):
        self.times = np.ascontiguousarray(times, dtype=np.float64)
        n = self.times.size
        self.block = np.empty(n * (2 * nq + 2))
        b, size = self.block, n * nq
        self.Q, self.QD = b[:size].reshape(n, nq), b[size:2 * size].reshape(n, nq)
        self.W, self.H = b[2 * size:2 * size + n], b[2 * size + n:]
        self.flags = np.empty(n, dtype=np.int64)
        self.project = int(project)
        self.k = 0  # the outputs written (Index1._loop)

    def done(self):
        """(Q (k, nq), QD (k, nq), W (k,), H (k,)): the k outputs written (fresh rows)."""
        k = self.k
        out = self.Q[:k], self.QD[:k], self.W[:k], self.H[:k]
        if 2 * k < self.times.size:  # (the rows are kept: not the whole block for a few)
            out = tuple(a.copy() for a in out)
        return out

    def attach(self, loop: Loop):
        """Point ``loop`` at the request (from the first output on)."""
        loop.times, loop.n_out, loop.k_out = self.times.ctypes.data, self.times.size, 0
        loop.project_out = self.project
        base, size = self.block.ctypes.data, self.times.size * self.Q.shape[1]
        loop.Q, loop.QD = base, base + 8 * size
        loop.W, loop.H = base + 16 * size, base + 16 * size + 8 * self.times.size
        loop.flags = self.flags.ctypes.data


def supports(tableau) -> bool:
    """True when step.c knows the tableau's error norm and dense output (class data
    ``error_form``, ``dense_form``)."""
    return (getattr(tableau, "dense_form", None) in DENSE_FORMS
            and getattr(tableau, "error_form", "?") in ERROR_FORMS)


class CompiledStep:
    """One integrator's step in C on ``system`` with ``tableau``.

    control: the error norm is computed (an embedded pair without a fixed step); project:
    q, qd projected after each accepted step and at each output (the projection families);
    stab: Baumgarte's (alpha, beta) or None; rtol, atol, proj_tol as the integrator's."""

    def __init__(self, system, tableau, *, rtol, atol, control, project, proj_tol, stab=None):
        self.system = system
        self.lib = system.fc.lib
        if (self.lib.mb_rk_size(), self.lib.mb_loop_size()) != (ctypes.sizeof(RK),
                                                               ctypes.sizeof(Loop)):
            raise _lib.KernelBuildError("mb_rk / mb_loop in step.c and mbsim.fast.stepper's "
                                        "RK / Loop differ (an edit on one side only)")
        nq = system.nq
        ny = 2 * nq + 1
        self.tableau = tab = tableau
        ns = tab.n_stages
        err_form = tab.error_form if control else None
        r = self.r = RK()
        r.ns, r.nq = ns, nq
        r.err_kind = ERROR_FORMS[err_form]
        r.dense_kind = DENSE_FORMS[tab.dense_form]
        P = getattr(tab, "P", None)
        r.np = 0 if P is None else P.shape[1]
        r.project, r.kkt = int(project), int(system.kkt)
        r.stab = int(stab is not None)
        r.alpha, r.beta = stab if stab is not None else (0.0, 0.0)
        r.rtol, r.atol = rtol, atol
        r.proj_tol = proj_tol
        from mbsim.integrators.changepoints import Policy  # scipy: imported where a run is

        r.proj_fail = Policy.projection_kept(proj_tol)  # Index1._project's failure rule
        self._keep = tableau_arrays(tab, err_form)  # the arrays C points into
        for name, a in self._keep.items():
            setattr(r, name, a.ctypes.data)
        r.reuse = int(REUSE_FACTOR)
        # the buffers, from one allocation (one pointer each by offset)
        self._buffers = _lib.carve(y=ny, f=ny, y_new=ny, y_acc=ny, f_acc=ny, ys=ny, qw=ny,
                                   K=(N_K, ny), vm=system.model.m, Fd=7 * ny, out=5)
        for name, (_, address) in self._buffers.items():
            setattr(r, name, address)
        self.y, self.f, self.y_new, self.y_acc, self.f_acc, self.K, self.out = (
            self._buffers[k][0] for k in ("y", "f", "y_new", "y_acc", "f_acc", "K", "out"))
        self.count = np.zeros(len(COUNTERS) + len(OUTPUT_COUNTERS), dtype=np.int64)
        self.output_projections = dict.fromkeys(OUTPUT_COUNTERS, 0)
        r.count = self.count.ctypes.data
        self._pending = []  # a KeyboardInterrupt (or SystemExit) met in the callback
        self._load = load_callback(system, self._pending)
        r.load = ctypes.cast(self._load, ctypes.c_void_p).value if self._load else None
        self.ptr = ctypes.addressof(r)
        self.ns = ns
        self._dense_io = None  # dense: (times, flags buffers, their addresses)

    def _counted(self, status):
        c = self.system.counters
        counts = self.count.tolist()
        for name, n in zip(COUNTERS, counts):
            c[name] += n
        for name, n in zip(OUTPUT_COUNTERS, counts[len(COUNTERS):]):
            self.output_projections[name] += n
        self.count[:] = 0
        if self._pending:  # raised where the C call was made (load_callback)
            raise self._pending.pop()
        return status

    def trial(self, t, h, y, f, tangent) -> int:
        """One trial step of size h from (t, y), y' = f, with the change-point switch
        ``tangent`` (0: off); returns ST_* (buffers: module doc)."""
        self.y[:] = y
        self.f[:] = f
        self.r.tangent = tangent
        return self._counted(self.lib.mb_rk_trial(self.system.c.ptr, self.ptr, t, h))

    def steps(self, y, f, loop: Loop) -> int:
        """Accepted steps from (loop.t, y), y' = f, as ``loop`` says (step.c: mb_rk_steps);
        returns LOOP_* (``loop`` updated)."""
        self.y[:] = y
        self.f[:] = f
        return self._counted(self.lib.mb_rk_steps(self.system.c.ptr, self.ptr,
                                                  ctypes.byref(loop)))

    def stages(self) -> np.ndarray:
        """(ns + 1, ny) copy of the last trial's stages and f(t + h, y_new)."""
        return self.K[: self.ns + 1].copy()

    def dense(self, t0, h, times, k=None):
        """(status, Q (n, nq), QD (n, nq), W (n,), flags (k,)) of the last trial (accepted;
        the buffers untouched since) at the first k (default all n) of ``times`` in
        [t0, t0 + h] (the rows after k are left for the caller); flags[i] = 1 where Python
        must give the output (step.c: mb_rk_dense; flags: a view valid until the next call)."""
        times = np.asarray(times, dtype=np.float64).reshape(-1)
        n, nq = times.size, self.system.nq
        k = n if k is None else k
        if self._dense_io is None or self._dense_io[0].size < n:  # (addresses made once)
            tb, fb = np.empty(max(n, 16)), np.empty(max(n, 16), dtype=np.int64)
            self._dense_io = (tb, fb, tb.ctypes.data, fb.ctypes.data)
        tb, fb, t_address, f_address = self._dense_io
        tb[:n] = times
        fb[:k] = 0
        # Q, QD, W: fresh (the caller keeps their rows), one allocation, addresses by offset
        block = np.empty(n * (2 * nq + 1))
        base, size = block.ctypes.data, n * nq
        Q, QD, W = (block[:size].reshape(n, nq), block[size:2 * size].reshape(n, nq),
                    block[2 * size:])
        st = self.lib.mb_rk_dense(self.system.c.ptr, self.ptr, t0, h, k, t_address, base,
                                  base + 8 * size, base + 16 * size, f_address)
        return self._counted(st), Q, QD, W, fb[:k]


_TABLEAU_ARRAYS: dict = {}


def tableau_arrays(tab, err_form) -> dict:
    """{RK field: contiguous float64 array} of a tableau as step.c reads it (A padded to
    (ns, ns), the error weights of ``err_form``, zeros where a form has none), built once
    per tableau class and error form (class data never changes; a tableau object that is
    not a class is not kept)."""
    key = (tab, err_form)
    if key not in _TABLEAU_ARRAYS:
        ns = tab.n_stages
        A = np.zeros((ns, ns))
        A[:, : tab.A.shape[1]] = tab.A[:ns, : min(ns, tab.A.shape[1])]
        if err_form == "dop853":
            E, E3 = tab.E5, tab.E3
        elif err_form == "embedded":
            E, E3 = tab.E, None
        else:
            E = E3 = None
        out = {}
        for name, x, shape in (("A", A, None), ("B", tab.B, None), ("C", tab.C, None),
                               ("E", E, ns + 1), ("E3", E3, ns + 1),
                               ("P", getattr(tab, "P", None), 1),
                               ("AX", getattr(tab, "A_EXTRA", None), (3, 16)),
                               ("CX", getattr(tab, "C_EXTRA", None), 3),
                               ("D", getattr(tab, "D", None), (4, 16))):
            a = np.ascontiguousarray(np.zeros(shape) if x is None else x, dtype=np.float64)
            a.setflags(write=False)
            out[name] = a
        if not isinstance(tab, type):
            return out
        _TABLEAU_ARRAYS[key] = out
    return _TABLEAU_ARRAYS[key]


def solve_error(code):
    """The SolveError that System.accelerations / System._correction raise for a failed
    factorisation with this status code (mbsim.fast.dynamics.STATUS_*)."""
    from mbsim.fast import dynamics as dyn

    return dyn.SolveError("singular KKT matrix" if int(code) == dyn.STATUS_SINGULAR
                          else dyn._NOT_PD)


def load_callback(system, pending):
    """The per-stage Python part (time targets, Python force elements) as a C callback, or
    None when the model has neither.  It reads q, qd where C loaded them (the system's own
    input buffers), and, for loads of the multipliers (System.reaction_loop: joint
    friction), the multipliers there too (the implicit integrators' Newton iterate, which
    implicit.c leaves in the model's lam).  An exception returns 1 and the caller raises it
    in Python again (a compiled step is taken again in Python; the implicit integrators'
    Newton iteration, :mod:`mbsim.fast.implicit`, calls the loads again at the state C
    left), where it is handled.  A KeyboardInterrupt or SystemExit (Ctrl-C arrives in the
    callback: the only Python code running during the C call) returns 1 too and is kept in
    ``pending``, to be raised once the C call is back (:meth:`CompiledStep._counted`);
    ctypes would print and drop it."""
    fc, py = system.fc, system.py_forces
    if not fc.funcs and not py:
        return None
    loads, model, reactions = system._loads, system.model, system.reaction_loop

    def load(t, forces):
        try:
            if fc.funcs:
                fc.targets(t)
            if forces and reactions:  # loads of the multipliers C left in the model
                system._lam_known = system.full_lam(system._lam.copy())
            if forces and py:
                system.apply_python(core.State(model, fc._q, fc._qd), t, loads)
        except Exception:  # noqa: BLE001 - re-raised by the Python path (docstring)
            return 1
        except BaseException as exc:  # noqa: BLE001 - raised after the C call (docstring)
            pending.append(exc)
            return 1
        return 0

    return LOAD(load)
