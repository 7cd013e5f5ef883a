"""Test-session set-up.

One BLAS thread, as the ``mbsim`` command runs (see ``mbsim/__init__.py``): mbsim's linear
algebra is many small dense solves, where BLAS threads only add overhead (a 15-body inverse
run measured 9x slower with them on a 2-core machine).  The variables must be set before
numpy is first imported, which is why this is the first thing the test session does.
"""

import os
import sys
import warnings

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

if "numpy" in sys.modules:  # a plugin loaded it first: the limit may not take effect
    warnings.warn("numpy was imported before tests/conftest.py could limit BLAS threads; "
                  "set OPENBLAS_NUM_THREADS=1 for representative test times", stacklevel=1)
