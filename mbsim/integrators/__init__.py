"""Integrators for the constrained equations of motion, one file per method family.

``INTEGRATORS`` maps the ``--integrator`` name to the class; the contract every class
follows is in :class:`mbsim.integrators.base.Integrator`.

- gcp.py: generalized coordinate partitioning (Wehage & Haug 1982) with explicit RK pairs
- index1.py: index-1 ODE with Baumgarte stabilisation or with projection
- genalpha.py: implicit index-3 generalized-alpha and HHT (Arnold & Bruls 2007)
- rk.py: the RK tableaus and the step loop they share (the index-1 family takes its trial
  steps, outputs and runs of steps in C: mbsim/fast/step.c through :mod:`mbsim.fast.stepper`)
- system.py: the equations of motion the integrators call: :class:`mbsim.fast.dynamics.System`,
  the one implementation (C kernels); tests/reference/ holds the numpy reference
"""

from __future__ import annotations

from mbsim.integrators.base import Integrator
from mbsim.integrators.gcp import GcpDop853, GcpRK4, GcpRK45
from mbsim.integrators.genalpha import HHT, GeneralizedAlpha
from mbsim.integrators.index1 import Baumgarte, Projection, ProjectionDop853, RK4Projection
from mbsim.integrators.system import System

INTEGRATORS: dict[str, type[Integrator]] = {
    c.name: c
    for c in (GcpRK45, GcpDop853, GcpRK4, GeneralizedAlpha, HHT, Baumgarte, Projection,
              ProjectionDop853, RK4Projection)
}

ALIASES = {"rk45": "gcp-rk45", "dop853": "gcp-dop853", "generalized-alpha": "genalpha",
           "hht-alpha": "hht"}
"""Other names a deck may use (e.g. ``integrator: dop853``)."""

DEFAULT = "projection-dop853"
"""The default integrator: the cheapest at equal achieved error on the seed decks
(``mbsim bench``: governor 0.031 wall s/s at 1e-6 against 0.077 for gcp-dop853; free
slider-crank 0.023 against 0.64), with an achieved error of 0.4-7 x rtol.  The book's method,
coordinate partitioning, stays available as gcp-dop853 / gcp-rk45 / gcp-rk4."""

__all__ = ["ALIASES", "DEFAULT", "INTEGRATORS", "Integrator", "System"]
