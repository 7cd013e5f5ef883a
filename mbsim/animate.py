"""Animations of a result: the mechanism drawn moving, written as a GIF.

The drawing comes from the deck stored in the result file (``/deck``), recompiled with the
scene and ``--set`` overrides stored in its ``settings``: every joint, driver and force
point, in body coordinates, is attached to its body.  Each frame draws

- each moving body as lines from its centroid to its points (a "star": a rod is the line
  through its two ends, a crank the line from its pivot to its pin), its centroid a dot;
- each massless link (``distance``, ``spherical-spherical``, ``revolute-spherical`` joints,
  ``distance`` drivers) as a dashed line between its two points;
- each TSDA as a dotted line between its points;
- the points on ground bodies as fixed triangles, and the guide of each translational or
  cylindrical joint with ground as a thin line over the travel of the moving body;
- a body whose points all lie at its centroid (a slider) as a square;
- the time, ``t = 0.350 s``.

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
    for force in spec.forces.values():
        if force.type == "tsda":
            bi, bj = force.bodies
            springs.append((bi, force.points[bi].P, bj, force.points[bj].P))
            for body in (bi, bj):
                attach(body, force.points[body].P)
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
        out.append({"t": float(result.t[k]), "bodies": bodies, "links": pair,
                    "springs": springs, "ground": ground, "rails": rails})  # fmt: skip
    return out


def _limits(frame_list) -> tuple[np.ndarray, np.ndarray]:
    pts = []
    for f in frame_list:
        for c, p in f["bodies"].values():
            pts += [c[None, :], p]
        for a, b in f["links"] + f["springs"] + f["rails"]:
            pts += [a[None, :], b[None, :]]
        pts.append(f["ground"])
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
) -> tuple[Path, int]:
    """Write a GIF of `result` to `path`; returns (path, number of frames).

    Parameters
    ----------
    result : a result with ``bodies/<name>/r`` and ``p`` channels.
    path : the GIF file.
    fps : frames per second of the GIF (real time when ``fps * every * step = 1``).
    view : ``iso`` | ``xy`` | ``xz`` | ``yz``.
    every : draw every n-th output time.
    dpi, size : resolution and size (inches, square) of a frame.
    sketch : what to draw (default: from the deck stored in the result).
    title : default: the deck's title and the mode.
    """
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
    ax.set_xticks([])
    ax.set_yticks([])
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
    star = {b: ax.plot([], [], "-", color=colors[b], lw=2.5, solid_capstyle="round")[0]
            for b in sketch.bodies}  # fmt: skip

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
    stamp = ax.text(0.02, 0.97, "", transform=ax.transAxes, va="top", family="monospace")

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
            dots[b].set_data([c[0]], [c[1]])
        joints.set_data(jx, jy)
        for line, (a, b) in zip(links, f["links"]):
            line.set_data([a[0], b[0]], [a[1], b[1]])
        for line, (a, b) in zip(springs, f["springs"]):
            line.set_data([a[0], b[0]], [a[1], b[1]])
        ground.set_data(f["ground"][:, 0], f["ground"][:, 1])
        stamp.set_text(f"t = {f['t']:.3f} s")
        return []

    anim = FuncAnimation(fig, draw, frames=len(frame_list), blit=False, repeat=False)
    anim.save(path, writer=PillowWriter(fps=fps), dpi=dpi)
    return path, len(frame_list)


def animate_file(file: str | Path, path: str | Path, **kwargs) -> tuple[Path, int]:
    """Read a results file and write its animation (see :func:`animate_result`)."""
    from mbsim.output import read_result

    return animate_result(read_result(file), path, **kwargs)
