"""Build step of mbsim: the C kernels (mbsim/fast/kernels.c, step.c, outputs.c, implicit.c,
partition.c) as one plain shared library.

Everything else is declared in pyproject.toml.  The library is not a Python extension
module (no Python.h, no PyInit_): mbsim.fast._lib loads it with ctypes.  A failed compile
does not fail the install: it warns, and mbsim compiles the kernels at first use instead
(into ~/.cache/mbsim), or says which compiler to install.
"""

import hashlib
import os
import shlex
from pathlib import Path

from setuptools import Extension, setup
from setuptools.command.build_ext import build_ext

SOURCES = [Path("mbsim") / "fast" / "kernels.c", Path("mbsim") / "fast" / "step.c",
           Path("mbsim") / "fast" / "outputs.c", Path("mbsim") / "fast" / "implicit.c",
           Path("mbsim") / "fast" / "partition.c"]


class BuildKernels(build_ext):
    """build_ext that tolerates a missing or failing C compiler."""

    def get_export_symbols(self, ext):
        return []  # no PyInit_ function to export: a plain library

    def run(self):
        try:
            super().run()
        except Exception as exc:  # noqa: BLE001 - any build failure: warn, compile later
            self.warn(f"mbsim: the C kernels were not built ({exc}); they will be compiled "
                      "at first use (needs a C compiler: e.g. apt install gcc)")

    def build_extension(self, ext):
        try:
            super().build_extension(ext)
        except Exception as exc:  # noqa: BLE001
            self.warn(f"mbsim: the C kernels were not built ({exc}); they will be compiled "
                      "at first use (needs a C compiler: e.g. apt install gcc)")


HEADERS = [Path("mbsim") / "fast" / "mb_model.h"]  # included by both sources
# = mbsim.fast._lib.source_hash: the sources' and the header's bytes one after the other
digest = hashlib.sha256(b"".join(p.read_bytes() for p in SOURCES + HEADERS)).hexdigest()[:16]
kernels = Extension(
    "mbsim.fast._kernels",
    sources=[str(p) for p in SOURCES],
    depends=[str(p) for p in HEADERS],
    define_macros=[("MB_SOURCE_HASH", f'"{digest}"')],
    # MBSIM_CFLAGS (e.g. "-O0" or "-O3 -march=native") after -O2 wins: the same variable as
    # a first-use compile reads (mbsim/fast/_lib.py)
    extra_compile_args=["-O2", "-std=c99", *shlex.split(os.environ.get("MBSIM_CFLAGS", ""))],
    libraries=["m"],
    optional=True,
)

setup(ext_modules=[kernels], cmdclass={"build_ext": BuildKernels})
