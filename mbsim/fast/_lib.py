"""Find, build and load the C kernels (mbsim/fast/*.c, SOURCES) through ctypes.

Where the shared library comes from, in this order:

1. next to this file, built at install time by setup.py (``mbsim.fast._kernels``, a plain
   shared library, not a Python extension), when it was built from the sources beside it
   (every build embeds the SHA-256 of its sources, ``mb_source_hash``);
2. the compile cache: ``$MBSIM_CACHE_DIR`` or ``~/.cache/mbsim``, one file per (source,
   compiler, flags, platform) hash;
3. otherwise compiled now with the system C compiler (``sysconfig``'s CC, else cc, gcc,
   clang) into that cache, through a temporary file and ``os.replace`` so concurrent
   processes (pytest workers, parallel sweeps) never see half a library.  Before compiling,
   ``mbsim.fast.on_compile(message)`` is called when set (the CLI prints the line on stderr)
   and the message is logged; library code never prints.

No C compiler and no built library: :class:`KernelBuildError` says what is missing and how
to fix it.
"""

from __future__ import annotations

import ctypes
import hashlib
import logging
import math
import os
import platform
import shlex
import shutil
import subprocess
import sys
import sysconfig
import tempfile
from pathlib import Path

import numpy as np

from mbsim.errors import MbsimError

log = logging.getLogger(__name__)

HERE = Path(__file__).resolve().parent
SOURCE = HERE / "kernels.c"
SOURCES = (SOURCE, HERE / "step.c", HERE / "outputs.c", HERE / "implicit.c",
           HERE / "partition.c")
"""The files of the one library: the physics (kernels.c), the integrators' step
(step.c, :mod:`mbsim.fast.stepper`), the equations at a run's outputs (outputs.c,
:func:`mbsim.analyses.trajectory.output_rows`), the implicit integrators' Newton
iteration (implicit.c, :mod:`mbsim.fast.implicit`) and the coordinate-partitioning stage
(partition.c, :mod:`mbsim.fast.partition`)."""
HEADERS = (HERE / "mb_model.h",)
"""What both sources include (the one definition of mb_model): part of the source hash."""
CFLAGS = ["-O2", "-std=c99", "-fPIC", "-shared"]  # -O3: no faster (benchmarks/kernels.py)
FLAGS_ENV = "MBSIM_CFLAGS"
"""Extra compiler flags, appended after CFLAGS (so ``-O0`` or ``-O3 -march=native`` wins
over -O2), read by setup.py at install and here at a first-use compile; part of the cache
key, so builds with other flags never mix."""


def cflags() -> list[str]:
    return CFLAGS + shlex.split(os.environ.get(FLAGS_ENV, ""))
MESSAGE = "compiling kernels (first run only) ..."


class KernelBuildError(MbsimError):
    """The C kernels are neither installed nor compilable here."""

    exit_code = 1


def source_hash(text: bytes | None = None) -> str:
    """First 16 hex digits of the SHA-256 of the sources (SOURCES in order, then
    the header mb_model.h: their bytes one after the other; setup.py computes the same)."""
    text = b"".join(p.read_bytes() for p in (*SOURCES, *HEADERS)) if text is None else text
    return hashlib.sha256(text).hexdigest()[:16]


def compiler() -> list[str]:
    """The C compiler command: sysconfig's CC when it runs, else cc, gcc or clang."""
    cc = shlex.split(os.environ.get("CC") or sysconfig.get_config_var("CC") or "")
    if cc and shutil.which(cc[0]):
        return cc
    for name in ("cc", "gcc", "clang"):
        if shutil.which(name):
            return [name]
    raise KernelBuildError(
        "no C compiler found to build mbsim's C kernels (mbsim/fast/kernels.c, compiled "
        "once per install); install one (Debian/Ubuntu: apt install gcc; macOS: "
        "xcode-select --install) or install mbsim from a wheel built with its kernels"
    )


def compile_command(cc, src, out, digest):
    """The compiler's command line; src: one path or a sequence of them (SOURCES)."""
    src = [src] if isinstance(src, (str, Path)) else list(src)
    return [*cc, *cflags(), f"-DMB_SOURCE_HASH=\"{digest}\"", "-o", str(out),
            *map(str, src), "-lm"]


def cache_dir() -> Path:
    return Path(os.environ.get("MBSIM_CACHE_DIR") or Path.home() / ".cache" / "mbsim")


def _suffix() -> str:
    return ".dll" if sys.platform == "win32" else (".dylib" if sys.platform == "darwin" else ".so")


def _installed(digest):
    """The library setup.py built next to this file, if it matches kernels.c."""
    for path in sorted(HERE.glob("_kernels*")):
        if path.suffix not in (".so", ".pyd", ".dylib", ".dll"):
            continue
        try:
            lib = ctypes.CDLL(str(path))
            built = _hash_of(lib)
        except (OSError, AttributeError):
            continue
        if digest is None or built == digest:
            return lib
        log.debug("ignoring %s: built from another kernels.c (%s != %s)", path, built, digest)
    return None


def _hash_of(lib) -> str:
    f = lib.mb_source_hash
    f.restype = ctypes.c_char_p
    f.argtypes = []
    return f().decode()


def build(dest: Path | None = None) -> Path:
    """Compile the sources (SOURCES) into the cache (or ``dest``); returns the library's path."""
    digest = source_hash()
    cc = compiler()
    key = hashlib.sha256(
        "\0".join([digest, " ".join(cc), " ".join(cflags()), platform.platform(),
                   platform.machine(), sys.implementation.cache_tag or ""]).encode()
    ).hexdigest()[:16]
    if dest is None:
        dest = cache_dir() / f"kernels-{key}{_suffix()}"
    if dest.exists():
        return dest
    from mbsim import fast

    log.info(MESSAGE)
    if fast.on_compile is not None:
        fast.on_compile(MESSAGE)
    try:
        dest.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=dest.stem + ".", suffix=".tmp" + _suffix(),
                                   dir=dest.parent)
    except OSError as exc:
        raise KernelBuildError(
            f"cannot write mbsim's compile cache {dest.parent} ({exc.strerror}); set "
            "MBSIM_CACHE_DIR to a writable folder"
        ) from exc
    os.close(fd)
    try:
        cmd = compile_command(cc, SOURCES, tmp, digest)
        out = subprocess.run(cmd, capture_output=True, text=True)
        if out.returncode != 0:
            raise KernelBuildError(
                f"compiling mbsim's C kernels failed ({' '.join(cmd)}): "
                f"{out.stderr.strip()[-500:]}"
            )
        os.replace(tmp, dest)  # atomic: another process sees the old name or the whole file
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)
    return dest


_LIB = None


def library():
    """The loaded C library (argtypes and restypes set), built on first use if needed."""
    global _LIB
    if _LIB is None:
        digest = (source_hash() if all(p.exists() for p in (*SOURCES, *HEADERS))
                  else None)
        lib = _installed(digest)
        if lib is None:
            if digest is None:
                raise KernelBuildError("mbsim/fast/kernels.c, step.c, outputs.c or mb_model.h is "
                                       "missing and no built kernels are installed; reinstall "
                                       "mbsim")
            lib = ctypes.CDLL(str(build()))
        _declare(lib)
        sizes = (lib.mb_struct_size(), ctypes.sizeof(Struct))
        if len(set(sizes)) != 1:  # an edit on one side only
            raise KernelBuildError(
                f"mb_model in mb_model.h ({sizes[0]} bytes) and mbsim.fast._lib.Struct "
                f"({sizes[1]} bytes) differ"
            )
        _LIB = lib
    return _LIB


def _declare(lib):
    P, I = ctypes.c_void_p, ctypes.c_int
    sig = {
        "mb_constraints": ([P, I, I], None),
        "mb_terms": ([P, I, I, I], None),
        "mb_gather_dense": ([P, P, P], None),
        "mb_jac_times": ([P, P, P], None),
        "mb_applied_forces": ([P], None),
        "mb_tire_states": ([ctypes.c_int64, ctypes.c_int64, ctypes.c_int64, P, P, P, P, P],
                           None),
        "mb_mass_blocks": ([P], None),
        "mb_accelerations": ([P, I, I], I),
        "mb_project": ([P, I], I),
        "mb_project_factored": ([P], None),
        "mb_struct_size": ([], ctypes.c_int64),
        "mb_rk_size": ([], ctypes.c_int64),
        "mb_rk_trial": ([P, P, ctypes.c_double, ctypes.c_double], I),
        "mb_rk_dense": ([P, P, ctypes.c_double, ctypes.c_double, ctypes.c_int64, P, P, P, P,
                         P], I),
        "mb_rk_steps": ([P, P, P], I),
        "mb_loop_size": ([], ctypes.c_int64),
        "mb_approach_near": ([P, ctypes.c_double], ctypes.c_double),
        "mb_approach_accepted": ([P, ctypes.c_double, ctypes.c_double, ctypes.c_double], I),
        "mb_approach_size": ([], ctypes.c_int64),
        "mb_kinematic": ([P, ctypes.c_double, ctypes.c_int64, I, P, P, P], I),
        "mb_apply_minv": ([P, I, ctypes.c_int64, P, P], None),
        "mb_ga_size": ([], ctypes.c_int64),
        "mb_ga_newton": ([P, P, ctypes.c_double, ctypes.c_double, P, P, P, P, P, P, P, P, P],
                         I),
        "mb_ga_tangent": ([P, P, ctypes.c_double, P, P, P, P, P, P], I),
        "mb_ga_solve": ([P, P, ctypes.c_int64], I),
        "mb_gcp_size": ([], ctypes.c_int64),
        "mb_gcp_stage": ([P, P, ctypes.c_double, P, P, P, P, P, I], I),
        "mb_gcp_trial": ([P, P, ctypes.c_double, ctypes.c_double, I], I),
        "mb_gcp_dense": ([P, P, ctypes.c_double, ctypes.c_double, ctypes.c_int64, P, P, P, P,
                          P], I),
        "mb_outputs": ([P, I, ctypes.c_int64, ctypes.c_int64, P, P, P, P, P, P, P, P, P],
                       ctypes.c_int64),
    }
    for name, (args, res) in sig.items():
        f = getattr(lib, name)
        f.argtypes, f.restype = args, res


SIZES = ("nb", "nq", "m", "ma", "nc", "ninc", "npairs", "nenv", "ne")
POINTERS = (
    "ci cf rb rows dpos sidx inc pairs bt nrm ei ef "
    "q qd tv loads par Jg rhs phi Jc gamma nu phi_a gamma_a nu_a J data "
    "Q qdd lam dq out Qt g Mi XG JG env srhs z K kr Mb A F n w kp"
).split()
INT_ARRAYS = {"ci", "rb", "rows", "dpos", "sidx", "inc", "pairs", "nrm", "ei", "kp"}


class Struct(ctypes.Structure):
    """mb_model of kernels.c: the sizes, then one pointer per table and buffer."""

    _fields_ = [(n, ctypes.c_int64) for n in SIZES] + [(n, ctypes.c_void_p) for n in POINTERS]


class Model:
    """One mb_model and the numpy arrays it points into (kept alive here).

    ``set(name=array, ...)`` stores C-contiguous int64/float64 copies where needed and
    points the struct at them; ``self.a[name]`` is the array; ``self.ptr`` the address to
    pass to the C functions."""

    def __init__(self, **sizes):
        self.s = Struct()
        self.a = {}
        for n in SIZES:
            setattr(self.s, n, int(sizes.get(n, 0)))
        self.ptr = ctypes.addressof(self.s)

    def size(self, **sizes):
        for n, v in sizes.items():
            setattr(self.s, n, int(v))

    def set(self, **arrays):
        for name, arr in arrays.items():
            dtype = np.int64 if name in INT_ARRAYS else np.float64
            arr = np.ascontiguousarray(arr, dtype=dtype)  # the same object when it already is
            self.a[name] = arr
            setattr(self.s, name, arr.ctypes.data)
        return [self.a[n] for n in arrays]

    def zeros(self, **shapes):
        """``set`` of zero float64 arrays of the given shapes (int or tuple of ints), carved
        from one allocation (:func:`carve`); returns the arrays in order."""
        out = []
        for name, (arr, address) in carve(**shapes).items():
            self.a[name] = arr
            setattr(self.s, name, address)
            out.append(arr)
        return out


def carve(**shapes):
    """{name: (zero float64 array of that shape (int or tuple of ints), its address)}, all
    views of one allocation, each address by offset (``ctypes.data`` costs microseconds per
    array, and a System has some thirty buffers); the views keep the block alive."""
    shapes = {k: v if isinstance(v, tuple) else (v,) for k, v in shapes.items()}
    sizes = [math.prod(shape) for shape in shapes.values()]
    block = np.zeros(max(1, sum(sizes)))
    base, off, out = block.ctypes.data, 0, {}
    for (name, shape), size in zip(shapes.items(), sizes):
        out[name] = (block[off : off + size].reshape(shape), base + 8 * off)
        off += size
    return out
