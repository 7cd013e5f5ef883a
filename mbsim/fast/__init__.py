"""Compiled (numba) fast path for the constraint terms and the equations of motion.

The numpy path (:mod:`mbsim.equations`, :mod:`mbsim.integrators.system`) evaluates each
kernel on stacked arrays; on models of a few bodies its cost is numpy's per-call overhead
(0.3-1 ms per evaluation).  This package evaluates the same equations (Haug 1989, Ch. 9
and eq. 11.1.x) in one compiled call per evaluation (``python benchmarks/kernels.py``):

- :class:`FastConstraints` ``(model, rows=None, sparse=None)``: Phi, Phi_q (dense, or CSR in
  a fixed pattern when nq >= ``SPARSE_NQ``), gamma, nu; ``evaluate`` writes into
  preallocated buffers, ``constraints`` returns fresh arrays like
  :func:`mbsim.equations.constraints`.
- :class:`FastDynamics` ``(model, rows=None, sparse=None)``: a stand-in for
  :class:`mbsim.integrators.system.System` with the same attributes (model, nb, nq, rows,
  all_rows, m, sparse, rheonomic, norm_pos, counters) and methods (``terms``, ``nu``,
  ``accelerations(q, qd, t, baumgarte=None, jac=None) -> (qdd, lam, power)``,
  ``full_lam``, ``project_positions``, ``project_velocities``, ``violations``,
  ``energy``, ``applied_forces(st, t) -> Q``), plus ``generalized_forces(q, qd, t) -> Q``
  and ``mass_matrix(q) -> M``.  It raises ``mbsim.integrators.system.SolveError`` where
  System does.  ``qdd, lam = fd.accelerations(q, qd, t)[:2]`` equals
  :func:`mbsim.equations.accelerations` (with ``rows``; ``fd.full_lam(lam)`` for all m
  rows).  System's internals (``minv_blocks``, ``schur``, ``G``, ``J_inv``, ``c_norm``,
  ``fused``, ``bs``) are not provided.

What is compiled and what stays Python:

- every constraint kernel (dot1, dot2, spherical, distance, angle, absolute, ground,
  normalisation); driver functions f(t), f', f'' are called in Python (few rows);
- gravity, the gyroscopic term, ``tsda`` with k, c, L0 (no law, no actuator) and constant
  ``force``/``torque`` vectors; every other element (laws, measures, rsda, tire, user
  classes) is applied by its own Python ``apply`` on a :class:`mbsim.equations.State`;
- the Schur complement of the modified mass matrix (System's module doc), assembled in an
  envelope after a reverse Cuthill-McKee ordering and factored by envelope Cholesky (O(m)
  for chains).  Models where some J' is singular (four-bar, Table 12.3.1: Izz = 0) have no
  exact Mt^-1: their accelerations solve the full (nq + m) KKT matrix by dense LU, and the
  projections use the identity metric (min-norm corrections).

Plugging in (the analyses build the System in one place, mbsim/analyses/dynamic.py)::

    from mbsim import fast
    system = fast.make_system(model, rows, opt.get("sparse"))   # FastDynamics or System

and, where an integrator calls ``eq.applied_forces(system.model, q, qd, t)[0]`` (gen-alpha,
its mass matrix too), ``system.generalized_forces(q, qd, t)`` and ``system.mass_matrix(q)``
when the system has them.  Nothing else changes: the counters, SolveError and the returned
shapes are System's (tests/test_kernels.py compares them; the integrator and analysis tests
pass with FastDynamics in place of System).  Arrays returned by ``FastDynamics`` methods
are fresh; only ``FastConstraints.evaluate`` returns buffers.

Fallback: without numba (or with the environment variable ``MBSIM_NO_NUMBA=1``),
``AVAILABLE`` is False, constructing :class:`FastConstraints` or :class:`FastDynamics` raises
ImportError with the reason, and :func:`make_system` returns the numpy System.

Compile cost: all numba code is in :mod:`mbsim.fast._compiled`, cached on disk (numba
``cache=True``: ``mbsim/fast/__pycache__``, or ``NUMBA_CACHE_DIR``).  The first use after
an install or an edit of that file compiles for 30-80 s (2-CPU machine); later processes
load the cache in under a second (``python benchmarks/kernels.py`` measures both).
"""

from __future__ import annotations

import os

_REASON = ""
try:
    if os.environ.get("MBSIM_NO_NUMBA", "") not in ("", "0"):
        raise ImportError("MBSIM_NO_NUMBA is set")
    import numba  # noqa: F401
except ImportError as exc:  # the numpy path stays usable
    AVAILABLE = False
    _REASON = str(exc)
else:
    AVAILABLE = True

if AVAILABLE:
    from mbsim.fast.constraints import SPARSE_NQ, FastConstraints
    from mbsim.fast.dynamics import FastDynamics
else:
    SPARSE_NQ = 700

    class _Unavailable:
        def __init__(self, *args, **kwargs):
            raise ImportError(
                f"mbsim.fast.{type(self).__name__} needs numba>=0.60 ({_REASON}); "
                "install it (pip install numba) or use the numpy path (mbsim.equations, "
                "mbsim.integrators.system.System)"
            )

    class FastConstraints(_Unavailable):  # type: ignore[no-redef]
        """Unavailable: numba cannot be imported (see the module doc)."""

    class FastDynamics(_Unavailable):  # type: ignore[no-redef]
        """Unavailable: numba cannot be imported (see the module doc)."""


def make_system(model, rows=None, sparse=None, compiled: bool = True):
    """FastDynamics(model, rows, sparse) when numba is available and ``compiled``, else
    :class:`mbsim.integrators.system.System` (the same interface)."""
    if compiled and AVAILABLE:
        return FastDynamics(model, rows, sparse)
    from mbsim.integrators.system import System

    return System(model, rows, sparse)


__all__ = ["AVAILABLE", "SPARSE_NQ", "FastConstraints", "FastDynamics", "make_system"]
