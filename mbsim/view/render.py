"""Frames of a mechanism in 3D, drawn in software (Pillow): ``mbsim animate``'s renderer.

Each frame places every body's shape triangles (mbsim.view.geometry, read from the result
file) at its centroid and orientation, projects them orthographically onto the view plane
and fills those facing the viewer far to near (back-face culling and the painter's
algorithm; a mesh wound inwards is turned round first), each shaded by the angle between its
normal and the line of sight; a ground grid under the mechanism, joint points and the lines
of distance joints and springs go with it, and the force elements with a drawing of their own
(mbsim.view.glyphs: a contact's plane and spheres, a bushing's boxes, a stop's limits) as
outlines over the shapes.  One frame of the vehicle (about 8000 triangles)
takes some 10 ms of CPU; the 2D sketch it replaces, 200 ms (benchmarks/animation.py).

Views: ``iso`` looks at the mechanism from above and in front, up against gravity (as the
viewer's start view); ``xy``, ``xz``, ``yz`` look along the third axis.  A mechanism that
travels far (more than twice its size: a vehicle) is followed: the view moves with its
heaviest body.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np

from mbsim.rotations import A
from mbsim.view.geometry import Scene

SUPERSAMPLE = 2  # frames are drawn this many times larger, then scaled down (anti-aliasing)
BACKGROUND = (244, 245, 247)
GRID = (205, 208, 214)
INK = (40, 40, 40)
SPRING = (255, 127, 14)
MARGIN = 0.08  # of the frame on each side
VIEWS = ("iso", "xy", "xz", "yz")
LINKED = ("distance", "spherical-spherical", "revolute-spherical")  # joints drawn as a line


@dataclass
class Camera:
    """rows of ``axes``: screen right, screen up, towards the viewer (global frame);
    ``center`` (nt, 3): the point at the frame's middle at each output; ``scale``: px per m."""

    axes: np.ndarray
    center: np.ndarray
    scale: float
    up: np.ndarray


def _up(gravity) -> np.ndarray:
    g = -np.asarray(gravity if gravity is not None else (0, 0, 0), float)
    n = np.linalg.norm(g)
    return g / n if n > 0 else np.array([0.0, 1.0, 0.0])


def view_axes(view: str, up: np.ndarray) -> np.ndarray:
    """(3, 3) rows right, up, back of a view (see the module docstring)."""
    if view == "xy":
        return np.eye(3)
    if view == "xz":
        return np.array([[1.0, 0, 0], [0, 0, 1], [0, -1, 0]])
    if view == "yz":
        return np.array([[0.0, 1, 0], [0, 0, 1], [1, 0, 0]])
    ref = np.array([1.0, 0, 0]) if abs(up[0]) < 0.9 else np.array([0.0, 0, 1])
    e1 = ref - ref @ up * up
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(up, e1)
    back = 0.8 * e1 - 1.3 * e2 + 0.7 * up  # the viewer's start view (viewer.js resetCamera)
    back /= np.linalg.norm(back)
    right = np.cross(up, back)
    right /= np.linalg.norm(right)
    return np.array([right, np.cross(back, right), back])


def world_vertices(scene: Scene, i: int) -> list[np.ndarray]:
    """Every drawn body's vertices at output i, global: r + A(p) v (Haug eq. 6.3.20)."""
    return [scene.r[i, k] + scene.meshes[b][0] @ A(scene.p[i, k]).T
            for k, b in enumerate(scene.names) if b in scene.meshes]  # fmt: skip


def fit_camera(scene: Scene, frames: list[int], view: str, gravity, pixels: int) -> Camera:
    """A camera that keeps the whole motion in the frame, or follows the heaviest body of a
    mechanism that travels more than twice its size."""
    up = _up(gravity)
    axes = view_axes(view, up)
    every = max(1, len(frames) // 40)  # the bounds from up to 40 outputs
    pts = [np.concatenate(world_vertices(scene, i) or [scene.r[i]]) for i in frames[::every]]
    pts.append(np.concatenate(world_vertices(scene, frames[-1]) or [scene.r[frames[-1]]]))
    size = float(np.ptp(pts[0], axis=0).max()) or 1.0
    masses = [scene.layout.get("bodies", {}).get(b, {}).get("mass", 0.0)
              if not scene.layout.get("bodies", {}).get(b, {}).get("ground") else -1.0
              for b in scene.names]  # fmt: skip
    heavy = int(np.argmax(masses)) if masses else 0
    travel = float(np.linalg.norm(scene.r[frames[-1], heavy] - scene.r[frames[0], heavy]))
    if travel > 2 * size:  # follow: frame 0's extent about the followed body
        span = np.ptp(pts[0] @ axes.T, axis=0)[:2].max()
        center = scene.r[:, heavy] + (pts[0].mean(axis=0) - scene.r[frames[0], heavy])
    else:
        allp = np.concatenate(pts) @ axes.T
        lo, hi = allp.min(axis=0), allp.max(axis=0)
        span = float((hi - lo)[:2].max())
        center = np.tile((lo + hi) / 2 @ axes, (len(scene.t), 1))
    scale = pixels * (1 - 2 * MARGIN) / max(span, 1e-9)
    return Camera(axes, center, scale, up)


def render_frames(scene: Scene, frames: list[int], view: str = "iso", gravity=None,
                  pixels: int = 400, title: str = "", time_label: str = "t",
                  labels: bool = False,
                  progress: Callable[[float, float], None] | None = None):
    """Yield one RGB ``PIL.Image`` (pixels x pixels) for each output index in ``frames``;
    ``labels``: body names at their centroids; ``progress(done, total)`` after each frame."""
    from PIL import Image, ImageDraw

    cam = fit_camera(scene, frames, view, gravity, pixels)
    ss = SUPERSAMPLE
    big = pixels * ss
    drawn = [b for b in scene.names if b in scene.meshes]
    faces, colors, n = [], [], 0
    for b in drawn:
        v, f, c = scene.meshes[b]
        if _signed_volume(v, f) < 0:  # wound inwards (a mesh file's choice): turn it round
            f = f[:, ::-1]
        faces.append(f + n)
        colors.append(c[f[:, 0]])
        n += len(v)
    faces = np.concatenate(faces) if faces else np.zeros((0, 3), int)
    base = np.concatenate(colors) * 255 if colors else np.zeros((0, 3))
    level = min(float((np.concatenate(world_vertices(scene, frames[0]) or [scene.r[frames[0]]])
                       @ cam.up).min()), float((scene.r[frames[0]] @ cam.up).min()))  # fmt: skip
    marks, lines = _marks(scene)
    light = np.array([0.3, 0.5, 1.0]) / np.linalg.norm([0.3, 0.5, 1.0])  # camera frame
    for count, i in enumerate(frames):
        img = Image.new("RGB", (big, big), BACKGROUND)
        draw = ImageDraw.Draw(img)
        center = cam.center[i] @ cam.axes.T

        def screen(p, center=center):  # camera coordinates (..., 3) -> pixel x, y
            return ((p[..., 0] - center[0]) * cam.scale * ss + big / 2,
                    big / 2 - (p[..., 1] - center[1]) * cam.scale * ss)  # fmt: skip

        _grid(draw, cam, i, level, screen, big)
        verts = world_vertices(scene, i)
        if len(faces):
            cv = np.concatenate(verts) @ cam.axes.T
            tri = cv[faces]  # (nf, 3, 3)
            normal = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
            norm = np.linalg.norm(normal, axis=1)
            keep = normal[:, 2] > 0  # facing the viewer: the back faces are hidden anyway
            lit = np.abs(normal[keep] @ light) / norm[keep]
            shade = (base[keep] * (0.45 + 0.55 * lit[:, None])).astype(int)
            order = np.argsort(tri[keep, :, 2].mean(axis=1))  # far (most negative) first
            x, y = screen(tri[keep])
            xy = np.stack([x, y], axis=2).reshape(-1, 6)[order].tolist()
            shade = shade[order]
            inks = (shade[:, 0] | shade[:, 1] << 8 | shade[:, 2] << 16).tolist()  # RGB ink
            fill_polygon = draw.draw.draw_polygon  # ImageDraw.polygon without its per-call
            for pts, ink in zip(xy, inks):  # colour parsing: a third of the time
                fill_polygon(pts, ink, 1)
        _overlay(draw, scene, i, cam, marks, lines, screen, ss)
        frame = img.reduce(ss) if ss > 1 else img  # box filter: 1 ms, LANCZOS took 23
        text = ImageDraw.Draw(frame)
        if title:
            text.text((6, 4), title, fill=INK)
        text.text((6, pixels - 16), f"{time_label} = {scene.t[i]:.3f} s", fill=INK)
        for k, b in enumerate(scene.names if labels else []):
            x, y = screen(scene.r[i, k] @ cam.axes.T)
            text.text((x / ss + 3, y / ss - 12), b, fill=INK)
        if progress is not None:
            progress(float(count + 1), float(len(frames)))
        yield frame


def _signed_volume(v: np.ndarray, f: np.ndarray) -> float:
    """Volume enclosed by triangles (divergence theorem): > 0 when wound counter-clockwise
    seen from outside, which back-face culling assumes."""
    a, b, c = v[f[:, 0]], v[f[:, 1]], v[f[:, 2]]
    return float(np.einsum("ij,ij->i", a, np.cross(b, c)).sum() / 6)


def _grid(draw, cam: Camera, i: int, level: float, screen, big: int) -> None:
    """Ground lines on the plane normal to 'up' at the mechanism's lowest point, cells snapped
    to the world so that they stay put while the view follows."""
    span = big / (cam.scale * SUPERSAMPLE)
    cell = 10.0 ** np.floor(np.log10(span / 4))
    u = cam.up
    e1 = np.cross(u, [0, 0, 1.0]) if abs(u[2]) < 0.9 else np.cross(u, [1.0, 0, 0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(u, e1)
    c = cam.center[i]
    a0, b0 = np.round(c @ e1 / cell) * cell, np.round(c @ e2 / cell) * cell
    half = np.ceil(span / cell) * cell
    k = np.arange(-half, half + cell / 2, cell)[:, None, None]
    ends = np.array([-half, half])[None, :, None]
    lines = np.concatenate([  # (2 nk, 2 ends, 3): lines along e2, then along e1
        level * u + (a0 + k) * e1 + (b0 + ends) * e2,
        level * u + (b0 + k) * e2 + (a0 + ends) * e1])  # fmt: skip
    x, y = screen(lines @ cam.axes.T)
    for seg in np.stack([x, y], axis=2).reshape(-1, 4).tolist():
        draw.line(seg, fill=GRID, width=1)


def _marks(scene: Scene):
    """Joint points [(body, P)] and lines [(body i, P_i, body j, P_j, colour)] from the
    file's layout (distance-type joints and two-point force elements)."""
    lay = scene.layout
    marks, lines = [], []
    for j in lay.get("joints", []):
        for b, ps in zip(j["bodies"], j["points"]):
            marks.append((b, np.asarray(ps["P"], float)))
        if j["type"] in LINKED and len(j["bodies"]) == 2:
            lines.append((*[(b, np.asarray(ps["P"], float)) for b, ps in
                            zip(j["bodies"], j["points"])], INK))  # fmt: skip
    for f in lay.get("forces", []):
        if "glyphs" in f:  # drawn by _glyph
            continue
        if len(f["bodies"]) == 2 and len(f["points"]) == 2:
            lines.append((*[(b, np.asarray(ps["P"], float)) for b, ps in
                            zip(f["bodies"], f["points"])], SPRING))  # fmt: skip
    return marks, lines


def _overlay(draw, scene: Scene, i: int, cam: Camera, marks, lines, screen, ss: int) -> None:
    index = {b: k for k, b in enumerate(scene.names)}
    rot = {b: A(scene.p[i, k]) for b, k in index.items()}

    def glob(b, P):
        return scene.r[i, index[b]] + rot[b] @ P

    for f in scene.layout.get("forces", []):
        for g in f.get("glyphs", ()):
            if g["body"] in index:
                _glyph(draw, g, scene.r[i, index[g["body"]]], rot[g["body"]], cam, screen, ss)
    for (bi, Pi), (bj, Pj), color in lines:
        if bi in index and bj in index:
            x, y = screen(np.array([glob(bi, Pi), glob(bj, Pj)]) @ cam.axes.T)
            draw.line([(x[0], y[0]), (x[1], y[1])], fill=color, width=2 * ss)
    rad = 2.5 * ss
    pts = [glob(b, P) for b, P in marks if b in index]
    if pts:
        x, y = screen(np.array(pts) @ cam.axes.T)
        for xk, yk in zip(x.tolist(), y.tolist()):
            draw.ellipse([xk - rad, yk - rad, xk + rad, yk + rad], fill=(255, 255, 255),
                         outline=INK, width=ss)  # fmt: skip


def _glyph(draw, g: dict, r: np.ndarray, A_body: np.ndarray, cam: Camera, screen,
           ss: int) -> None:  # fmt: skip
    """One primitive of mbsim.view.glyphs on a body at centroid r (3,) and orientation A_body
    (3, 3): squares and boxes as the outlines of their faces, spheres as their outline circle
    (the orthographic projection of a sphere), markers as dots, segments as lines."""
    color = tuple(int(g["color"][i : i + 2], 16) for i in (1, 3, 5))

    def xy(P):  # body frame -> pixel (Haug eq. 6.3.20 for the global point)
        x, y = screen((r + A_body @ np.asarray(P, float)) @ cam.axes.T)
        return float(x), float(y)

    shape = g["shape"]
    if shape in ("square", "box"):
        pts = [xy(P) for P in g["corners"]]
        for face in g["faces"]:
            draw.line([pts[k] for k in (*face, face[0])], fill=color, width=ss)
    elif shape == "sphere":
        x, y = xy(g["center"])
        rad = g["radius"] * cam.scale * ss
        draw.ellipse([x - rad, y - rad, x + rad, y + rad], outline=color, width=ss)
    elif shape == "marker":
        x, y = xy(g["point"])
        rad = 3 * ss
        draw.ellipse([x - rad, y - rad, x + rad, y + rad], fill=color)
    elif shape == "segment":
        draw.line([xy(g["a"]), xy(g["b"])], fill=color, width=2 * ss)


# -------------------------------------------------------------------------- writing


def mp4_encoder() -> str | None:
    """The ffmpeg executable for MP4 (imageio-ffmpeg's, else one on PATH), or None."""
    import shutil

    try:
        import imageio_ffmpeg

        return imageio_ffmpeg.get_ffmpeg_exe()
    except (ImportError, RuntimeError):
        return shutil.which("ffmpeg")


def check_target(path: str | Path) -> Path:
    """Before any frame is drawn: the suffix names a format we can write (.gif; .mp4 with an
    encoder), the folder exists and takes a file.  Raises UsageError."""
    from mbsim.errors import UsageError
    from mbsim.output.hdf5 import prepare_output

    path = Path(path)
    suffix = path.suffix.lower()
    if suffix not in (".gif", ".mp4"):
        raise UsageError(f"animation {path}: name it *.gif or *.mp4, not {path.name}")
    if suffix == ".mp4" and mp4_encoder() is None:
        raise UsageError(f"animation {path}: no MP4 encoder (pip install imageio-ffmpeg, or "
                         "install ffmpeg); or write a .gif")  # fmt: skip
    return prepare_output(path)


def write_animation(images, path: str | Path, fps: float) -> int:
    """Write the images (an iterable of RGB PIL images) as GIF or MP4; returns the count.
    Written to a temporary name, renamed when complete."""
    import os

    path = Path(path)
    tmp = path.with_name(f".{path.name}.tmp-{os.getpid()}{path.suffix}")
    try:
        if path.suffix.lower() == ".mp4":
            n = _write_mp4(images, tmp, fps)
        else:
            frames = [im.quantize(colors=255, method=2, dither=0) for im in images]
            frames[0].save(tmp, save_all=True, append_images=frames[1:], loop=0,
                           duration=int(round(1000 / fps)), optimize=False)  # fmt: skip
            n = len(frames)
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)
    return n


def _write_mp4(images, path: Path, fps: float) -> int:
    """The frames piped to ffmpeg.  An ffmpeg that stops early is an OSError with the end of
    its message: SIGPIPE is ignored meanwhile (the command's default action for `| head`
    ended mbsim silently, exit -13, when ffmpeg refused its input)."""
    import signal
    import subprocess
    import threading

    exe = mp4_encoder()
    proc = None
    n = 0
    main = threading.current_thread() is threading.main_thread() and hasattr(signal, "SIGPIPE")
    old = signal.signal(signal.SIGPIPE, signal.SIG_IGN) if main else None
    try:
        for im in images:
            if proc is None:
                w, h = im.size
                proc = subprocess.Popen([exe, "-y", "-loglevel", "error", "-f", "rawvideo",
                                         "-pix_fmt", "rgb24", "-s", f"{w}x{h}", "-r", f"{fps:g}",
                                         "-i", "-", "-pix_fmt", "yuv420p", "-vf",
                                         "pad=ceil(iw/2)*2:ceil(ih/2)*2", "-f", "mp4", str(path)],
                                        stdin=subprocess.PIPE, stderr=subprocess.PIPE)  # fmt: skip
            try:
                proc.stdin.write(im.tobytes())
            except BrokenPipeError:
                break  # ffmpeg has gone: its message below
            n += 1
        if proc is not None:
            try:
                _, err = proc.communicate()
            except BrokenPipeError:  # closing its input after it went
                err = proc.stderr.read() if proc.stderr else b""
                proc.wait()
            if proc.returncode:
                raise OSError(f"ffmpeg failed: {err.decode(errors='replace').strip()[-200:]}")
    finally:
        if old is not None:
            signal.signal(signal.SIGPIPE, old)
    return n
