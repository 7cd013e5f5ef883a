"""``mbsim view``: one self-contained HTML page that shows result files in 3D (docs: cli.md).

The page holds three.js (vendored, mbsim/view/vendor: MIT), the viewer script
(viewer.js, viewer.css) and the data: per case the time axis, each body's centroid and Euler
parameters, its shape's triangles (mbsim.view.geometry, stored in the result file) and the
channels for the time-history panel, as base64 float32.  It needs no server and no network.

Cases: several result files (a sweep's folder) become cases to choose from; a linear
analysis's modes become one case each, its motion synthesised here from the mode shapes
(``linear/modes/body``: small displacements and rotations about the reference state).
"""

from __future__ import annotations

import base64
import json
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from mbsim.errors import UsageError
from mbsim.result import Result
from mbsim.view.geometry import Scene, read_scene

HERE = Path(__file__).parent
MAX_CHANNEL_VALUES = 4_000_000  # per case: channels beyond it are left out (16 MB of float32)
MODE_FRAMES = 60  # frames in one period of a mode shape
MAX_MODES = 12


@dataclass
class Case:
    label: str
    scene: Scene
    result: Result
    period: float | None = None  # a mode's period (s); None for a run


def _b64(a: np.ndarray, dtype) -> str:
    return base64.b64encode(np.ascontiguousarray(a, dtype=dtype).tobytes()).decode()


def natural_key(text: str):
    """Sort key that orders numbers by value: k1000 < k2000 < k10000."""
    return [float(s) if s[0].isdigit() else s for s in re.findall(r"\d+\.?\d*|\D+", text)]


def result_files(paths: list[str | Path], skipped: list[str] | None = None) -> list[Path]:
    """The result files among ``paths``: a folder or a sweep's ``index.h5`` stands for the
    ``*.h5`` files in it (sorted by the numbers in their names); those of them that are not
    results files are left out, each appended to ``skipped`` as 'FILE: why'.  A file named
    itself must be a results file (UsageError otherwise)."""
    from mbsim.output.hdf5 import result_file_problem

    files: list[Path] = []
    for p in map(Path, paths):
        folder = p if p.is_dir() else p.parent if p.name == "index.h5" else None
        if folder is not None:
            found = sorted((f for f in folder.glob("*.h5") if f.name != "index.h5"),
                           key=lambda f: natural_key(f.stem))  # fmt: skip
            problems = {f: result_file_problem(f) for f in found}
            bad = [f"{f}: {why}" for f, why in problems.items() if why]
            found = [f for f in found if not problems[f]]
            if not found:
                among = f" (only {'; '.join(bad[:3])})" if bad else ""
                raise UsageError(f"{p}: no result files (*.h5) in {folder}{among}")
            if skipped is not None:
                skipped += bad
            files += found
            continue
        problem = result_file_problem(p)
        if problem:
            raise UsageError(f"{p}: {problem}")
        files.append(p)
    return files


def cases_of(path: Path, result: Result) -> list[Case]:
    """One case for a run; one per mode (up to MAX_MODES) for a linear analysis."""
    scene = read_scene(result)
    if result.mode != "linear" or "linear/modes/body" not in result.arrays:
        return [Case(path.stem, scene, result)]
    return mode_cases(path.stem, scene, result)


def mode_cases(stem: str, scene: Scene, result: Result) -> list[Case]:
    """The oscillating modes of a linear analysis as cases, one period each
    (mbsim.animate.mode_shape_result: q0 + a Re(dq e^{i w t}), projected onto Phi = 0)."""
    from mbsim.animate import mode_shape_result

    lam = np.asarray(result.arrays["linear/eigenvalues"][0])
    neutral = np.asarray(result.arrays.get("linear/neutral", (np.zeros(len(lam)),))[0], bool)
    out = []
    for k in np.flatnonzero((lam.imag > 0) & ~neutral)[:MAX_MODES]:
        moving, title = mode_shape_result(result, int(k) + 1, frames_per_cycle=MODE_FRAMES)
        moving.names, moving.arrays = result.names, result.arrays
        mode_scene = read_scene(moving)
        out.append(Case(f"{stem}: {title}", mode_scene, moving, float(moving.t[-1])))
    if not out:
        raise UsageError(f"{stem}: the linear analysis has no oscillating mode to animate")
    return out


def case_data(case: Case) -> dict:
    """The JSON-ready data of one case (arrays as base64 float32/uint32)."""
    s = case.scene
    bodies = []
    for k, name in enumerate(s.names):
        body = {"name": name, "r": _b64(s.r[:, k], "<f4"), "p": _b64(s.p[:, k], "<f4")}
        if name in s.meshes:
            v, f, c = s.meshes[name]
            body.update(v=_b64(v, "<f4"), f=_b64(f, "<u4"), c=_b64(np.round(c * 255), "u1"))
        body.update(s.layout.get("bodies", {}).get(name, {}))
        bodies.append(body)
    channels, total = [], 0
    if case.period is None:
        for name, ch in case.result.channels.items():
            data = np.asarray(ch.data, float).reshape(len(case.result.t), -1)
            total += data.size
            if total > MAX_CHANNEL_VALUES:
                break
            comps = list(ch.components) or [str(i) for i in range(data.shape[1])]
            if data.shape[1] == 1:
                comps = [""]
            offset = np.nan_to_num(data.mean(axis=0))  # float32 keeps 7 digits of the variation
            channels.append({"name": name, "unit": ch.unit, "components": comps,
                             "offset": offset.tolist(), "data": _b64(data - offset, "<f4")})
    return {
        "label": case.label,
        "mode": case.result.mode,
        "status": case.result.status,
        "message": case.result.message,
        "period": case.period,
        "t": _b64(s.t, "<f8"),
        "nt": len(s.t),
        "bodies": bodies,
        "layout": {k: v for k, v in s.layout.items() if k != "bodies"},
        "gravity": s.layout.get("gravity", [0.0, 0.0, 0.0]),
        "channels": channels,
    }


def build_page(paths: list[str | Path], title: str | None = None,
               skipped: list[str] | None = None) -> str:
    """The viewer page (HTML text) for the result files ``paths``."""
    from mbsim.output import read_result

    cases: list[Case] = []
    for path in result_files(paths, skipped):
        cases += cases_of(path, read_result(path))
    data = {"title": title or ", ".join(Path(p).name for p in paths), "cases":
            [case_data(c) for c in cases]}  # fmt: skip
    payload = json.dumps(data, separators=(",", ":")).replace("</", "<\\/")
    template = (HERE / "viewer.html").read_text()
    parts = {
        "TITLE": _escape(data["title"]),
        "CSS": (HERE / "viewer.css").read_text(),
        "THREE": (HERE / "vendor" / "three.min.js").read_text(),
        "VIEWER": (HERE / "viewer.js").read_text(),
        "DATA": payload,
    }
    return re.sub(r"/\*@(\w+)@\*/", lambda m: parts[m.group(1)], template)


def _escape(text: str) -> str:
    return text.replace("&", "&amp;").replace("<", "&lt;").replace(">", "&gt;")


def write_page(paths: list[str | Path], out: str | Path, title: str | None = None,
               skipped: list[str] | None = None) -> Path:
    """Build the page and write it to ``out`` atomically (a temporary file, then a rename);
    ``skipped``: as for :func:`result_files`."""
    import os

    out = Path(out)
    html = build_page(paths, title, skipped)
    tmp = out.with_name(f".{out.name}.tmp-{os.getpid()}")
    try:
        tmp.write_text(html, encoding="utf-8")
        os.replace(tmp, out)
    except OSError as exc:
        tmp.unlink(missing_ok=True)
        from mbsim.output.hdf5 import OutputError

        raise OutputError(f"cannot write {out}: {exc.strerror or exc}") from None
    return out
