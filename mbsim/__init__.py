"""mbsim: spatial multibody dynamics in Cartesian coordinates with Euler parameters.

Formulation and notation follow E. J. Haug, *Computer-Aided Kinematics and Dynamics of
Mechanical Systems* (1989), Chapters 9-12.

Glossary (used throughout the code, written once here):

- ``nb``: number of bodies (ground included when the deck has one); ``nq = 7 nb``.
- ``q``: (nq,) generalized coordinates, per body ``[r (3), p (4)]``: centroid position in
  the global frame and Euler parameters ``p = (e0, e1, e2, e3)``.
- ``qd``, ``qdd``: first and second time derivatives of ``q``.
- ``A(p)``: (3, 3) rotation matrix, body frame -> global (Haug eq. 6.3.20).
- ``G(p)``, ``E(p)``: (3, 4) with ``omega_local = 2 G pd`` and ``omega = 2 E pd`` (Haug eq. 6.3.21).
- ``phi``: (m,) constraint residuals Phi(q, t); ``phi_q``: (m, nq) Jacobian.
- ``nu``: (m,) velocity right side, ``phi_q qd = nu = -phi_t``.
- ``gamma``: (m,) acceleration right side, ``phi_q qdd = gamma``.
- ``lam``: (m,) Lagrange multipliers; ``M``: (nq, nq) mass matrix; ``Q``: (nq,) applied forces.
- suffix ``_local``: body frame; ``_q``: partial derivative in q.
"""

import os as _os

# mbsim's linear algebra is many small dense solves (tens to hundreds of unknowns): BLAS
# threads only add overhead there, and on a shared 2-core machine they made a 15-body
# inverse run 9x slower (34 s vs 3.8 s). Default to one thread unless the user chose;
# this takes effect only when mbsim is imported before numpy (the `mbsim` command).
for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    _os.environ.setdefault(_var, "1")

__version__ = "0.1.0"


def read(path):
    """A result file for analysis in Python: ``mbsim.read('gov.h5').frame('bodies/collar')``
    is a pandas DataFrame indexed by time (mbsim.output.frame.ResultFile; docs/hdf5.md)."""
    from mbsim.output.frame import ResultFile

    return ResultFile(path)
