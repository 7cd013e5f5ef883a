"""The constrained equations of motion as the integrators see them.

The one implementation is :class:`mbsim.fast.dynamics.System` (C kernels, its module doc
states the equations and the solve); this module re-exports it with :class:`SolveError`
where the integrators import them.  The plain numpy statement of the
same equations is tests/reference/equations.py (the reference the tests compare against).
"""

from __future__ import annotations

from mbsim.fast.constraints import SPARSE_NQ
from mbsim.fast.dynamics import SolveError, System

__all__ = ["SPARSE_NQ", "SolveError", "System"]
