"""The compiled form of the constraint rows: one :class:`Block` per basic kernel.

Every joint and driver is compiled into rows of a few basic constraints of Haug Ch. 9
(*kernels*: dot-1, dot-2, spherical, distance, angle, absolute coordinate, ground,
normalisation).  All rows of one kernel, whatever joint they come from, are stacked in one
Block; the C kernels (mbsim/fast/kernels.c, through :mod:`mbsim.core`) evaluate them.  This
module holds only the data layout: no equations.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

KERNELS = {
    "dot1": 1,  # a_i . a_j  (Haug eq. 9.2.3)
    "dot2": 1,  # a . d_ij  (Haug eq. 9.2.6)
    "spherical": 3,  # d_ij  (Haug eq. 9.4.1)
    "distance": 1,  # d_ij . d_ij - C^2  (Haug eq. 9.2.9)
    "angle": 1,  # relative rotation about f_i  (Haug Sec. 9.5)
    "absolute": 1,  # a global coordinate of a body point  (Haug Sec. 9.5)
    "ground": 6,  # r = r0, (e1, e2, e3) = e0'
    "normalization": 1,  # p^T p - 1  (Haug eq. 6.3.2)
}
"""kernel name -> equations per constraint (ne)."""


@dataclass(frozen=True)
class Block:
    """k constraints of one kernel. Arrays are read-only after compile."""

    kernel: str
    rows: np.ndarray  # (k, ne) global row numbers
    bi: np.ndarray  # (k,) body i index
    bj: np.ndarray  # (k,) body j index, -1 for one-body kernels
    vecs: dict[str, np.ndarray]  # kernel arguments, (k, 3) local vectors or (k,) flags
    c_const: np.ndarray  # (k, ne) constant targets
    funcs: tuple = ()  # ((flat row in block, TimeFunction, squared), ...) time targets
    ne: int = 1
    scatter: dict = field(default_factory=dict)  # precomputed index arrays for assembly
