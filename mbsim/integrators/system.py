"""The constrained equations of motion as the integrators see them.

The one implementation is :class:`mbsim.fast.dynamics.System` (C kernels, its module doc
states the equations and the solve); this module re-exports it with :class:`SolveError`
and :func:`mass_blocks` where the integrators import them.  The plain numpy statement of the
same equations is :mod:`mbsim.equations` (the reference the tests compare against).
"""

from __future__ import annotations

import numpy as np

from mbsim.equations import State
from mbsim.fast.constraints import SPARSE_NQ
from mbsim.fast.dynamics import SolveError, System

__all__ = ["SPARSE_NQ", "SolveError", "System", "mass_blocks"]


def mass_blocks(model, q):
    """(nb, 7, 7) diagonal blocks of M = diag(m I, 4 G^T J' G) (Haug eq. 11.1.x), in numpy
    from the model alone (the reference's form; :meth:`System.mass_blocks` is the C one)."""
    st = State(model, q)
    B = np.zeros((model.nb, 7, 7))
    B[:, 0, 0] = B[:, 1, 1] = B[:, 2, 2] = model.mass
    B[:, 3:, 3:] = 4 * np.matmul(np.matmul(st.G.transpose(0, 2, 1), model.J_local), st.G)
    return B
