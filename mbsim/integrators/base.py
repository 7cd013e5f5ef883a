"""The integrator contract (after scipy's OdeSolver), filled in by the dynamics work.

See mbsim/integrators/__init__.py for the registry ``INTEGRATORS``.
"""
