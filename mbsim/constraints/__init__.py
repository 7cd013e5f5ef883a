"""Constraint library: batched basic kernels (:mod:`.basic`) and the joint/driver types
composed from them (:mod:`.joints`)."""

from mbsim.constraints.basic import KERNELS, Block
from mbsim.constraints.joints import DRIVERS, JOINTS

__all__ = ["DRIVERS", "JOINTS", "KERNELS", "Block"]
