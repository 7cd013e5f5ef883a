"""Constraint library: the compiled row layout (:mod:`.blocks`: one Block per basic kernel)
and the joint/driver types composed from the basic kernels (:mod:`.joints`).  The equations
themselves are evaluated in C (:mod:`mbsim.core`)."""

from mbsim.constraints.blocks import KERNELS, Block
from mbsim.constraints.joints import DRIVERS, JOINTS

__all__ = ["DRIVERS", "JOINTS", "KERNELS", "Block"]
