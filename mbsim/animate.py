"""Animations of a result: the mechanism drawn moving, written as a GIF or MP4.

Two styles.  ``3d`` (the default): the bodies' shapes (the deck's ``shape:``, or shapes
derived from inertia and joints), shaded, with joints, springs and a ground grid, drawn by
mbsim.view.render from the file's ``shapes/`` group; GIF, or MP4 where ffmpeg is found.
``sketch``: the 2D line drawing below (GIF only).

The sketch comes from the deck stored in the result file (``/deck``), recompiled with the
scene and ``--set`` overrides stored in its ``settings``: every joint, driver and force
point, in body coordinates, is attached to its body.  Each frame draws

- each moving body through all its points (joint, driver and force attachment points, the
  deck's output points and measure points): the outline (convex hull) of its points and
  centroid, with lines from the centroid to each point (a rod is the line through its two
  ends, a crank the line from its pivot to its pin), its centroid a dot.  A body with a
  single point besides its centroid (a pendulum link hanging from one joint) is drawn to
  the point mirrored through the centroid as well: its free end;
- each massless link (``distance``, ``spherical-spherical``, ``revolute-spherical`` joints,
  ``distance`` drivers) as a dashed line between its two points;
- each TSDA as a dotted line between its points;
- the force elements with a drawing of their own (mbsim.view.glyphs) as lines in their
  colours: a contact's plane (the square's outline) and spheres (their outline circles), a
  bushing's boxes (their edges), a stop's limits (dots, or rays for an angle);
- the points on ground bodies as fixed triangles, and the guide of each translational or
  cylindrical joint with ground as a thin line over the travel of the moving body;
- a body whose points all lie at its centroid (a slider) as a square;
- the time, ``t = 0.350 s``; axes with a scale in metres (``x [m]``, or ``screen right
  [m]`` in the isometric view), optional body labels; the view fits the whole motion.

A linear analysis result (``linear/...``) can be drawn as one of its modes oscillating
(:func:`mode_shape_result`, ``mbsim animate FILE --mode-shape K``).

Positions are projected orthographically: ``xy``, ``xz``, ``yz`` onto a coordinate plane,
or ``iso``: an isometric view with "up" opposite to gravity (z when there is none).
Matplotlib ``Figure`` + ``FuncAnimation`` + the Pillow writer; no pyplot state.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from mbsim.errors import DeckError
from mbsim.result import Result
from mbsim.rotations import A as rotation_matrix

LINK_TYPES = ("distance", "spherical-spherical", "revolute-spherical")


@dataclass
class Sketch:
    """What to draw, in body coordinates (built once from the deck)."""

    bodies: list[str]  # moving bodies, drawn as stars
    points: dict[str, np.ndarray] = field(default_factory=dict)  # body -> (n, 3) local points
    links: list[tuple[str, np.ndarray, str, np.ndarray]] = field(default_factory=list)
    springs: list[tuple[str, np.ndarray, str, np.ndarray]] = field(default_factory=list)
    ground: list[tuple[str, np.ndarray]] = field(default_factory=list)  # (ground body, P)
    # guides: (ground body, P, axis f (3,), moving body, its joint point), body coordinates
    rails: list[tuple[str, np.ndarray, np.ndarray, str, np.ndarray]] = field(default_factory=list)
    up: np.ndarray = field(default_factory=lambda: np.array([0.0, 0.0, 1.0]))
    glyphs: list[dict] = field(default_factory=list)  # mbsim.view.glyphs primitives


def _add_point(points: dict[str, list], body: str, P) -> None:
    P = np.asarray(P, float)
    if not any(np.allclose(P, Q, atol=1e-12) for Q in points.setdefault(body, [])):
        points[body].append(P)


def sketch_of(spec) -> Sketch:
    """The drawing of a validated deck (:class:`~mbsim.deck.spec.DeckSpec`)."""
    ground = {n for n, b in spec.bodies.items() if b.ground}
    pts: dict[str, list] = {}
    links, springs, fixed = [], [], []

    def attach(body, P):
        if body in ground:
            fixed.append((body, np.asarray(P, float)))
        else:
            _add_point(pts, body, P)

    rails = []
    for joint in spec.joints.values():
        bi, bj = joint.bodies
        if joint.type in ("translational", "cylindrical") and (bi in ground) != (bj in ground):
            g, b = (bi, bj) if bi in ground else (bj, bi)
            ps = joint.points[g]
            if ps.Q is not None:
                rails.append((g, ps.P, ps.Q - ps.P, b, joint.points[b].P))
        if joint.type in LINK_TYPES and bj is not None:
            links.append((bi, joint.points[bi].P, bj, joint.points[bj].P))
        for body, ps in joint.points.items():
            attach(body, ps.P)
    for drv in spec.drivers.values():
        if drv.type == "distance":
            bi, bj = drv.bodies
            links.append((bi, drv.points[bi].P, bj, drv.points[bj].P))
        for body, ps in drv.points.items():
            attach(body, ps.P)
    from mbsim.view.geometry import mechanism_size
    from mbsim.view.glyphs import force_glyphs

    glyphs = []
    size = mechanism_size(spec) if spec.forces else 1.0
    for force in spec.forces.values():
        glyphs += force_glyphs(force, spec, size) or []
        if force.type == "tsda":
            bi, bj = force.bodies
            springs.append((bi, force.points[bi].P, bj, force.points[bj].P))
        for body, ps in (force.points or {}).items():
            if body is not None and ps is not None and ps.P is not None:
                attach(body, ps.P)
    for out in spec.outputs.values():  # output points
        attach(out.body, out.point)
    for om in (getattr(spec, "output_measures", None) or {}).values():  # measure points
        d = om.data
        if d.get("body") is not None:
            attach(d["body"], d["point"])
        for body, P in zip(d.get("bodies", ()), d.get("points", ())):
            attach(body, P)
    for body, plist in list(pts.items()):  # one point off the centroid and no other: a
        if len(plist) == 1 and np.linalg.norm(plist[0]) > 1e-12:  # link hanging from it
            _add_point(pts, body, -plist[0])  # its free end, mirrored through the centroid
    g = np.asarray(spec.gravity, float)
    up = -g / np.linalg.norm(g) if np.linalg.norm(g) > 0 else np.array([0.0, 0.0, 1.0])
    moving = [n for n in spec.bodies if n not in ground]
    return Sketch(
        moving,
        {b: np.array(v) for b, v in pts.items()},
        links=links,
        springs=springs,
        ground=fixed,
        rails=rails,
        up=up,
        glyphs=glyphs,
    )


def projection(view: str, up: np.ndarray) -> np.ndarray:
    """(2, 3) matrix from global coordinates to the screen (right, up) of `view`."""
    planes = {"xy": (0, 1), "xz": (0, 2), "yz": (1, 2)}
    if view in planes:
        P = np.zeros((2, 3))
        P[0, planes[view][0]] = P[1, planes[view][1]] = 1.0
        return P
    if view != "iso":
        raise ValueError(f"unknown view {view!r}; use iso, xy, xz or yz")
    k = int(np.argmax(np.abs(up)))
    e_up = np.zeros(3)
    e_up[k] = np.sign(up[k]) or 1.0
    a, b = np.eye(3)[(k + 1) % 3], np.eye(3)[(k + 2) % 3]
    eye = (a + b + e_up) / np.sqrt(3.0)  # the viewer's direction
    right = np.cross(e_up, eye)
    right /= np.linalg.norm(right)
    screen_up = np.cross(eye, right)
    return np.vstack([right, screen_up])


def _poses(result: Result, names: list[str]) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """body -> (r (nt, 3), A (nt, 3, 3)) from the result's channels."""
    out = {}
    for name in names:
        r = result.channel(f"bodies/{name}/r").data
        p = result.channel(f"bodies/{name}/p").data
        out[name] = (r, np.array([rotation_matrix(pk / np.linalg.norm(pk)) for pk in p]))
    return out


def _glob(poses, body, P, k):
    r, A = poses[body]
    return r[k] + A[k] @ P


def frames(result: Result, sketch: Sketch, view: str, every: int = 1):
    """Projected geometry per frame: list of dicts with 'bodies' {name: (centroid (2,),
    points (n, 2))}, 'links', 'springs', 'rails' [((2,), (2,))], 'ground' (n, 2), 't'."""
    P2 = projection(view, sketch.up)
    names = set(sketch.bodies) | {b for b, _ in sketch.ground}
    names |= {b for item in sketch.links + sketch.springs for b in (item[0], item[2])}
    names |= {b for item in sketch.rails for b in (item[0], item[3])}
    names |= {g["body"] for g in sketch.glyphs}
    poses = _poses(result, sorted(names))
    rails = []  # static: the guide over the whole travel of the moving point
    for g, P, f, b, Pb in sketch.rails:
        base = _glob(poses, g, P, 0)
        axis = poses[g][1][0] @ (f / np.linalg.norm(f))
        s = [(_glob(poses, b, Pb, k) - base) @ axis for k in range(len(result.t))]
        lo, hi = min(s), max(s)
        pad = 0.1 * max(hi - lo, 1e-3)
        rails.append((P2 @ (base + (lo - pad) * axis), P2 @ (base + (hi + pad) * axis)))
    out = []
    for k in range(0, len(result.t), every):
        bodies = {}
        for b in sketch.bodies:
            r, A = poses[b]
            local = sketch.points.get(b, np.zeros((0, 3)))
            bodies[b] = (P2 @ r[k], (r[k] + local @ A[k].T) @ P2.T if len(local) else
                         np.zeros((0, 2)))  # fmt: skip
        pair = [(P2 @ _glob(poses, bi, Pi, k), P2 @ _glob(poses, bj, Pj, k))
                for bi, Pi, bj, Pj in sketch.links]  # fmt: skip
        springs = [(P2 @ _glob(poses, bi, Pi, k), P2 @ _glob(poses, bj, Pj, k))
                   for bi, Pi, bj, Pj in sketch.springs]  # fmt: skip
        ground = np.array([P2 @ _glob(poses, g, P, k) for g, P in sketch.ground]).reshape(-1, 2)
        glyphs = [_glyph_line(g, lambda P, b=g["body"], k=k: P2 @ _glob(poses, b, np.asarray(P), k))
                  for g in sketch.glyphs]  # fmt: skip
        out.append({"t": float(result.t[k]), "bodies": bodies, "links": pair,
                    "springs": springs, "ground": ground, "rails": rails,
                    "glyphs": glyphs})  # fmt: skip
    return out


CIRCLE = 48  # points round a sphere's outline


def _glyph_line(g: dict, to2) -> np.ndarray:
    """(n, 2) the projected polyline of one primitive (mbsim.view.glyphs), NaN rows between
    its pieces: the outline of each face of a square or box, a sphere's outline circle (its
    orthographic projection: the rows of P2 are orthonormal), a segment; a marker's point."""
    shape = g["shape"]
    if shape in ("square", "box"):
        c = [to2(P) for P in g["corners"]]
        rows = []
        for face in g["faces"]:
            rows += [c[i] for i in (*face, face[0])] + [np.full(2, np.nan)]
        return np.array(rows)
    if shape == "sphere":
        a = 2 * np.pi * np.arange(CIRCLE + 1) / CIRCLE
        return to2(g["center"]) + g["radius"] * np.c_[np.cos(a), np.sin(a)]
    if shape == "segment":
        return np.array([to2(g["a"]), to2(g["b"])])
    return np.array([to2(g["point"])])  # marker


def _turn(o, a, b) -> float:
    """z of (a - o) x (b - o): > 0 for a left turn."""
    return float((a[0] - o[0]) * (b[1] - o[1]) - (a[1] - o[1]) * (b[0] - o[0]))


def hull(points: np.ndarray) -> np.ndarray:
    """Closed outline (m, 2) of 2-D points: the convex hull by Andrew's monotone chain
    (collinear points give the segment between the extremes, there and back)."""
    pts = np.unique(np.round(np.asarray(points, float), 12), axis=0)
    if len(pts) < 3:
        return np.vstack([pts, pts[:1]]) if len(pts) else pts

    def half(seq):
        out = []
        for p in seq:
            while len(out) >= 2 and _turn(out[-2], out[-1], p) <= 0:
                out.pop()
            out.append(p)
        return out

    lower, upper = half(pts), half(pts[::-1])
    ring = np.array(lower[:-1] + upper[:-1])
    return np.vstack([ring, ring[:1]])


def _limits(frame_list) -> tuple[np.ndarray, np.ndarray]:
    pts = []
    for f in frame_list:
        for c, p in f["bodies"].values():
            pts += [c[None, :], p]
        for a, b in f["links"] + f["springs"] + f["rails"]:
            pts += [a[None, :], b[None, :]]
        pts.append(f["ground"])
        pts += [xy[np.isfinite(xy).all(axis=1)] for xy in f.get("glyphs", ())]
    allp = np.vstack([p for p in pts if len(p)])
    lo, hi = allp.min(axis=0), allp.max(axis=0)
    span = max(float(np.max(hi - lo)), 1e-9)
    mid = 0.5 * (lo + hi)
    half = 0.55 * span
    return mid - half, mid + half


def sketch_from_result(result: Result):
    """Recompile the deck stored in `result` (with its scene and overrides) -> Sketch."""
    from mbsim.deck import load_deck_text

    if not result.deck_text:
        raise DeckError("the results file holds no deck text (/deck); cannot draw the "
                        "mechanism")  # fmt: skip
    overrides = result.settings.get("overrides") or {}
    spec = load_deck_text(result.deck_text, result.deck_file or "<deck>",
                          overrides=overrides, scene=result.settings.get("scene"))  # fmt: skip
    return sketch_of(spec)


STYLES = ("3d", "sketch")


def animate_result(
    result: Result,
    path: str | Path,
    fps: float = 20,
    view: str = "iso",
    every: int = 1,
    dpi: float = 80,
    size: float = 5.0,
    sketch: Sketch | None = None,
    title: str | None = None,
    labels: bool = False,
    style: str = "3d",
    progress=None,
) -> tuple[Path, int]:
    """Write a GIF (or MP4, style 3d, where an encoder is found) of `result` to `path`;
    returns (path, number of frames).

    Parameters
    ----------
    result : a result with ``bodies/<name>/r`` and ``p`` channels.
    path : the GIF or MP4 file; checked before any frame is drawn.
    fps : frames per second (real time when ``fps * every * step = 1``).
    view : ``iso`` | ``xy`` | ``xz`` | ``yz``.
    every : draw every n-th output time.
    dpi, size : resolution and size (inches, square) of a frame: ``dpi * size`` pixels.
    sketch : style sketch: what to draw (default: from the deck stored in the result).
    title : default: the deck's title and the mode.
    labels : write each body's name at its centroid.
    style : ``3d``: the bodies' shapes shaded in 3D (mbsim.view.render, from the file's
        ``shapes/``); ``sketch``: the 2D line drawing of the module docstring (matplotlib).
    progress : ``progress(done, total)`` after each frame (mbsim.progress contract).
    """
    if style == "3d":
        return _animate_3d(result, path, fps, view, every, round(dpi * size), title, labels,
                           progress)  # fmt: skip
    from matplotlib.animation import FuncAnimation, PillowWriter
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    path = Path(path)
    if path.suffix.lower() != ".gif":
        raise ValueError(f"the animation is written as GIF; name it *.gif, not {path.name}")
    sketch = sketch or sketch_from_result(result)
    frame_list = frames(result, sketch, view, every)
    if not frame_list:
        raise ValueError("the result has no output times to draw")
    lo, hi = _limits(frame_list)
    fig = Figure(figsize=(size, size), dpi=dpi, layout="constrained")
    FigureCanvasAgg(fig)
    ax = fig.add_subplot()
    ax.set_xlim(lo[0], hi[0])
    ax.set_ylim(lo[1], hi[1])
    ax.set_aspect("equal")
    ax.tick_params(labelsize="x-small")
    ax.grid(True, alpha=0.25)
    xl, yl = {"iso": ("screen right", "screen up"), "xy": ("x", "y"), "xz": ("x", "z"),
              "yz": ("y", "z")}[view]  # fmt: skip
    ax.set_xlabel(f"{xl} [m]", fontsize="small")
    ax.set_ylabel(f"{yl} [m]", fontsize="small")
    label = {"iso": "isometric view", "xy": "x right, y up", "xz": "x right, z up",
             "yz": "y right, z up"}[view]  # fmt: skip
    first = frame_list[0]
    if title is None:
        deck_title = (
            result.deck_text.split("title:", 1)[1].splitlines()[0].strip()
            if "title:" in result.deck_text
            else Path(result.deck_file).stem
        )
        title = f"{deck_title}\n{result.mode}, {label}"
    ax.set_title(title, fontsize="small")
    colors = {b: f"C{i % 10}" for i, b in enumerate(sketch.bodies)}
    star = {b: ax.plot([], [], "-", color=colors[b], lw=1.2, solid_capstyle="round")[0]
            for b in sketch.bodies}  # fmt: skip
    outline = {b: ax.plot([], [], "-", color=colors[b], lw=2.5, solid_capstyle="round",
                          solid_joinstyle="round")[0] for b in sketch.bodies}  # fmt: skip
    names = {b: ax.text(0, 0, f" {b}", fontsize="x-small", color=colors[b], va="bottom")
             for b in (sketch.bodies if labels else [])}  # fmt: skip

    def blob(b):  # a body with all its points at the centroid is a block, the others a dot
        pts = sketch.points.get(b, np.zeros((0, 3)))
        block = not len(pts) or np.allclose(pts, 0.0, atol=1e-12)
        return ax.plot([], [], "s" if block else "o", color=colors[b], ms=11 if block else 5,
                       zorder=3)[0]  # fmt: skip

    for a, b in first["rails"]:
        ax.plot([a[0], b[0]], [a[1], b[1]], "-", color="0.6", lw=1)
    dots = {b: blob(b) for b in sketch.bodies}
    joints = ax.plot([], [], "o", mfc="white", mec="k", ms=4, ls="none")[0]
    links = [ax.plot([], [], "--", color="0.3", lw=1.5)[0] for _ in first["links"]]
    springs = [ax.plot([], [], ":", color="0.45", lw=2)[0] for _ in first["springs"]]
    ground = ax.plot([], [], "^", color="k", ms=7, ls="none")[0]
    glyphs = [ax.plot([], [], "o" if g["shape"] == "marker" else "-", color=g["color"], ms=5,
                      lw=1 if g.get("opacity", 1) < 1 else 1.5, zorder=4)[0]
              for g in sketch.glyphs]  # fmt: skip
    stamp = ax.text(0.02, 0.97, "", transform=ax.transAxes, va="top", family="monospace",
                    fontsize="small")
    time_label = "t" if result.mode != "linear-mode" else "phase t"

    def draw(i):
        f = frame_list[i]
        jx, jy = [], []
        for b, (c, pts) in f["bodies"].items():
            xs, ys = [], []
            for p in pts:
                xs += [c[0], p[0], np.nan]
                ys += [c[1], p[1], np.nan]
                jx.append(p[0])
                jy.append(p[1])
            star[b].set_data(xs, ys)
            ring = hull(np.vstack([c[None, :], pts])) if len(pts) else np.zeros((0, 2))
            outline[b].set_data(ring[:, 0], ring[:, 1])
            dots[b].set_data([c[0]], [c[1]])
            if b in names:
                names[b].set_position((c[0], c[1]))
        joints.set_data(jx, jy)
        for line, (a, b) in zip(links, f["links"]):
            line.set_data([a[0], b[0]], [a[1], b[1]])
        for line, (a, b) in zip(springs, f["springs"]):
            line.set_data([a[0], b[0]], [a[1], b[1]])
        ground.set_data(f["ground"][:, 0], f["ground"][:, 1])
        for line, xy in zip(glyphs, f["glyphs"]):
            line.set_data(xy[:, 0], xy[:, 1])
        stamp.set_text(f"{time_label} = {f['t']:.3f} s")
        return []

    anim = FuncAnimation(fig, draw, frames=len(frame_list), blit=False, repeat=False)
    anim.save(path, writer=PillowWriter(fps=fps), dpi=dpi)
    return path, len(frame_list)


def mode_shape_result(result: Result, k: int, cycles: float = 1.0, frames_per_cycle: int = 40,
                      amplitude: float = 0.1) -> tuple[Result, str]:
    """A Result holding mode ``k`` (1-based, as printed by ``--mode linear``) of a linear
    analysis oscillating about its reference: q(t) = q0 + a Re(dq exp(i w t)), w = Im lambda
    (a real or neutral mode: q0 + a dq sin(2 pi t / T), T = 1 s or 1/|lambda|), p normalised.
    ``amplitude``: the largest displacement as a fraction of the mechanism's size (its bodies'
    spread, at least 0.1 m x amplitude).  Returns (result, a title naming the mode)."""
    if "linear/eigenvalues" not in result.arrays:
        raise ValueError("--mode-shape needs a file of `mbsim run --mode linear`")
    lam = np.asarray(result.arrays["linear/eigenvalues"][0])
    if not 1 <= k <= lam.size:
        raise ValueError(f"mode {k} does not exist: the file has modes 1 to {lam.size}")
    q0 = np.asarray(result.arrays["linear/q0"][0], float)
    dq = np.asarray(result.arrays["linear/modes/q"][0])[k - 1]
    nb = q0.size // 7
    r0 = q0.reshape(nb, 7)[:, :3]
    size = max(float(np.ptp(r0, axis=0).max()), 0.1)
    D = dq.reshape(nb, 7)
    big = max(float(np.abs(D[:, :3]).max()), 0.5 * float(np.abs(D[:, 3:]).max()) * size, 1e-300)
    a = amplitude * size / big
    lk = lam[k - 1]
    oscillating = abs(lk.imag) > 1e-9 * max(1.0, abs(lk))
    period = 2 * np.pi / abs(lk.imag) if oscillating else (1.0 / abs(lk) if abs(lk) > 1e-6
                                                             else 1.0)
    t = np.linspace(0.0, cycles * period, int(cycles * frames_per_cycle) + 1)
    phase = np.exp(1j * 2 * np.pi * t / period)
    q = q0[None, :] + a * (np.real(dq[None, :] * phase[:, None]) if oscillating else
                           np.real(dq)[None, :] * np.imag(phase)[:, None])
    Q = q.reshape(len(t), nb, 7)
    Q[:, :, 3:] /= np.linalg.norm(Q[:, :, 3:], axis=2, keepdims=True)
    Q = _onto_constraints(result, Q)
    out = Result(mode="linear-mode", t=t)
    out.deck_text, out.deck_file, out.settings = result.deck_text, result.deck_file, \
        result.settings
    for b, name in enumerate(result.names.get("bodies", [])):
        out.add(f"bodies/{name}/r", Q[:, b, :3], "m")
        out.add(f"bodies/{name}/p", Q[:, b, 3:])
    fhz = abs(lk) / (2 * np.pi)
    zeta = -lk.real / abs(lk) if abs(lk) > 0 else 0.0
    zeta = 0.0 if abs(zeta) < 1e-9 else zeta
    lk = complex(0.0 if abs(lk.real) < 1e-9 * max(1.0, abs(lk)) else lk.real, lk.imag)
    what = (f"f = {fhz:.4g} Hz, zeta = {zeta:.3g}" if abs(lk) > 1e-6 else "neutral")
    return out, f"mode {k}: lambda = {lk.real:.4g} {'+-'[int(lk.imag < 0)]} {abs(lk.imag):.4g}i " \
                f"1/s ({what})"


def _onto_constraints(result: Result, Q: np.ndarray) -> np.ndarray:
    """Each frame's q (nt, nb, 7) projected back onto Phi = 0 (Newton, minimum-norm steps),
    so that a finite amplitude keeps the joints together; as given where that fails."""
    from mbsim.analyses.assembly import newton
    from mbsim.deck import load_deck_text
    from mbsim.errors import MbsimError
    from mbsim.model import compile_model

    try:
        spec = load_deck_text(result.deck_text, result.deck_file or "<deck>",
                              overrides=result.settings.get("overrides") or {},
                              scene=result.settings.get("scene"))
        model = compile_model(spec)
        out = np.array([newton(model, qk.reshape(-1), float(result.settings.get("t") or 0.0),
                               1e-10, 30)[0] for qk in Q])
        return out.reshape(Q.shape)
    except (MbsimError, ValueError, np.linalg.LinAlgError):
        return Q


def animate_file(file: str | Path, path: str | Path, mode_shape: int | None = None,
                 **kwargs) -> tuple[Path, int]:
    """Read a results file and write its animation (see :func:`animate_result`); with
    ``mode_shape`` (a linear analysis' file) that mode oscillating."""
    from mbsim.output import read_result
    from mbsim.view.render import check_target

    if kwargs.get("style", "3d") == "3d":
        check_target(path)  # before reading or drawing anything
    result = read_result(file)
    if mode_shape is not None:
        moving, title = mode_shape_result(result, mode_shape)
        moving.names, moving.arrays = result.names, result.arrays  # shapes/ for the 3D style
        result = moving
        if kwargs.get("style", "3d") == "sketch":
            kwargs["sketch"] = kwargs.get("sketch") or sketch_from_result(result)
        kwargs.setdefault("title", f"{Path(result.deck_file).stem}: {title}")
    return animate_result(result, path, **kwargs)


def _animate_3d(result: Result, path, fps, view, every, pixels, title, labels, progress):
    """Style 3d of :func:`animate_result` (mbsim.view.render)."""
    from mbsim.errors import UsageError
    from mbsim.view.geometry import read_scene
    from mbsim.view.render import check_target, render_frames, write_animation

    path = check_target(path)
    scene = read_scene(result)
    if not scene.meshes and not scene.layout:
        raise UsageError("the results file holds no shapes (shapes/) and no deck text to "
                         "derive them from; run the analysis again with this mbsim")
    if not len(scene.t):
        raise ValueError("the result has no output times to draw")
    if title is None:
        deck_title = (result.deck_text.split("title:", 1)[1].splitlines()[0].strip()
                      if "title:" in result.deck_text else Path(result.deck_file).stem)
        title = f"{deck_title} ({result.mode})"
    frames = list(range(0, len(scene.t), every))
    images = render_frames(scene, frames, view, scene.layout.get("gravity"), pixels, title,
                           "phase t" if result.mode == "linear-mode" else "t", labels,
                           progress)  # fmt: skip
    return path, write_animation(images, path, fps)
