"""Start-up (issue 24, item 5): what `mbsim --help` and `mbsim check` import.

scipy.linalg alone costs about 0.4 s to import; a command that does not use it must not
import it.  Each command runs in a fresh interpreter (``python -c``) that prints the
modules it ended with; the wall times are measured by benchmarks/cold_start.py --startup.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PROBE = """
import json, runpy, sys
sys.argv = ["mbsim", *json.loads(sys.argv[1])]
try:
    runpy.run_module("mbsim", run_name="__main__")
except SystemExit as exc:
    code = exc.code
print(json.dumps({"code": code, "modules": sorted(sys.modules)}))
"""


def modules_after(*args: str) -> tuple[int, set[str]]:
    """(exit code, top-level packages imported) of ``mbsim ARGS`` in a fresh interpreter."""
    out = subprocess.run([sys.executable, "-c", PROBE, json.dumps(args)], cwd=ROOT,
                         capture_output=True, text=True, timeout=120)
    report = json.loads(out.stdout.strip().splitlines()[-1])
    return report["code"], {m.split(".")[0] for m in report["modules"]}


def test_help_imports_neither_scipy_nor_numpy():
    code, packages = modules_after("--help")
    assert code == 0
    assert "scipy" not in packages and "numpy" not in packages and "h5py" not in packages


def test_check_imports_no_scipy():
    code, packages = modules_after("check", "models/governor.yaml")
    assert code == 0
    assert "scipy" not in packages


def test_the_modules_of_check_import_no_scipy():
    """Everything `mbsim check` imports up to the assembly's rank test is scipy-free: the
    CLI, the deck loader, the model, the core, the assembly, the compiled kernels'
    loader, the results layer."""
    probe = ("import sys; import mbsim.cli, mbsim.api, mbsim.deck.loader, mbsim.model, "
             "mbsim.core, mbsim.analyses.assembly, mbsim.fast._lib, mbsim.output; "
             "print(sorted(m for m in sys.modules if m.split('.')[0] == 'scipy'))")
    out = subprocess.run([sys.executable, "-c", probe], cwd=ROOT, capture_output=True,
                         text=True, timeout=120)
    assert out.stdout.strip() == "[]", out.stderr
