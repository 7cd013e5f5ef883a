"""The physics in C: constraint terms and equations of motion, for every analysis.

This package is the one implementation of the equations in production (Haug 1989, Chs. 9
and 11): every analysis (assembly, kinematic, inverse, equilibrium, linear,
dynamic, initial conditions, reactions, diagnosis) reaches it through the free functions of
:mod:`mbsim.core`, the integrators through :class:`System`.  mbsim/fast/kernels.c holds
every basic kernel (dot1, dot2, spherical, distance, angle, absolute, ground,
normalization: each one function with its Phi, Phi_q, nu and gamma), the applied forces,
the mass matrix and the Schur-complement and KKT solves.  The numpy statement of the same
equations lives under tests/reference/ only, as the reference the tests compare this
package against to round-off.

- :class:`FastConstraints` ``(model, rows=None, sparse=None)``: Phi, Phi_q (dense, or CSR in
  a fixed pattern when nq >= ``SPARSE_NQ``), gamma, nu; ``evaluate`` writes into
  preallocated buffers, ``constraints`` returns fresh arrays (:class:`mbsim.core.Terms`).
- :class:`System` ``(model, rows=None, sparse=None)``: the one equations-of-motion object
  every integrator calls (also exported as :class:`mbsim.integrators.System`): ``terms``,
  ``nu``, ``accelerations(q, qd, t, baumgarte=None, jac=None) -> (qdd, lam, power)``,
  ``full_lam``, ``project_positions``, ``project_velocities``, ``violations``, ``energy``,
  ``applied_forces(st, t)``, ``generalized_forces(q, qd, t)``, ``mass_blocks(q)``,
  ``mass_matrix(q)``; counters; :class:`SolveError` when a factorisation fails.
- :mod:`mbsim.fast.stepper` (mbsim/fast/step.c, built into the same library):
  ``CompiledStep`` takes a whole trial step of an explicit RK tableau of the index-1
  integrators (stages, error norm, projection) and the dense outputs of a step in one C
  call each; the integrators keep the step-size controller and the change-point policy.

What is in C and what stays Python: every constraint kernel (driver functions f(t), f', f''
are called in Python: few rows); gravity, the gyroscopic term, ``tsda`` with k, c, L0 (no
law, no actuator) and constant ``force``/``torque`` vectors; every other force element
(laws, measures, rsda, tire, user classes) is applied by its own Python ``apply``.

Building: setup.py compiles kernels.c into a plain shared library at install time; a source
checkout (or an install without a compiler) compiles it at first use into
``$MBSIM_CACHE_DIR`` (default ``~/.cache/mbsim``), about 1 s once (:mod:`mbsim.fast._lib`).
``on_compile``: a callable taking one line of text, called before such a compile (the CLI
sets it to print on stderr); the same line is logged (``logging``, INFO).
"""

from __future__ import annotations

on_compile = None
"""Called with "compiling kernels (first run only) ..." before a first-use compile."""

_LAZY = {
    "FastConstraints": "mbsim.fast.constraints",
    "SPARSE_NQ": "mbsim.fast.constraints",
    "System": "mbsim.fast.dynamics",
    "SolveError": "mbsim.fast.dynamics",
    "KernelBuildError": "mbsim.fast._lib",
}


def __getattr__(name):  # imports numpy/scipy only when used (the CLI imports this package)
    if name in _LAZY:
        import importlib

        return getattr(importlib.import_module(_LAZY[name]), name)
    raise AttributeError(f"module 'mbsim.fast' has no attribute {name!r}")


__all__ = ["SPARSE_NQ", "FastConstraints", "KernelBuildError", "SolveError", "System",
           "on_compile"]
