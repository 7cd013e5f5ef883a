"""Shared pieces of the dynamics benchmarks: models, timing, the optional Exudyn twins.

Single-threaded BLAS (set before numpy loads): the systems are small, threads only add
overhead and noise, and Exudyn runs on one thread too.  Timings are medians of repeats of
the process CPU time and of the wall time (on a shared machine the CPU time is the steadier
of the two; both are printed).
"""

from __future__ import annotations

import os

for _v in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_v, "1")

import re  # noqa: E402
import resource  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

ROOT = Path(os.environ.get("MBSIM_ROOT") or Path(__file__).resolve().parents[1]).resolve()
"""The mbsim checkout measured: $MBSIM_ROOT (set by before_after.py for each side), else the
checkout these scripts are in.  Its models/ are the decks run, and it goes first on
sys.path, so the mbsim imported is that tree's even where another one is installed."""
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))


def rot_A(p):
    """Rotation matrix of Euler parameters p = (e0, e), Haug eq. 6.2.25:
    A = (2 e0^2 - 1) I + 2 (e e^T + e0 e~); written here so that the chain decks need no
    mbsim internals (the same formula as mbsim.rotations.A)."""
    e0, e = float(p[0]), np.asarray(p[1:], float)
    skew = np.array([[0, -e[2], e[1]], [e[2], 0, -e[0]], [-e[1], e[0], 0]])
    return (2 * e0 * e0 - 1) * np.eye(3) + 2 * (np.outer(e, e) + e0 * skew)


def from_axis_angle(axis, angle):
    """Euler parameters of a turn `angle` (rad) about the unit vector along `axis`."""
    u = np.asarray(axis, float) / np.linalg.norm(axis)
    return np.concatenate([[np.cos(angle / 2)], np.sin(angle / 2) * u])


def timed(fn, *args, repeats=3):
    """(result of the last call fn(*args), median wall s, median CPU s) over `repeats`."""
    walls, cpus, out = [], [], None
    for _ in range(max(1, repeats)):
        w0, c0 = time.perf_counter(), time.process_time()
        out = fn(*args)
        walls.append(time.perf_counter() - w0)
        cpus.append(time.process_time() - c0)
    return out, float(np.median(walls)), float(np.median(cpus))


def load(deck, scene=None, overrides=None):
    from mbsim.api import load_model

    return load_model(ROOT / "models" / deck, overrides=overrides, scene=scene)[1]


def run_with_deck(model, mode, options, spec):
    """``mbsim.api.run_model`` as ``mbsim run`` runs it: with the deck's settings, ``outputs:
    only:``, hold, text and shapes.  A checkout whose run_model takes ``deck=`` gets the deck
    (``spec``) that way; an older one read it from the model (``Model.spec``)."""
    import inspect

    from mbsim.api import run_model

    if "deck" in inspect.signature(run_model).parameters:
        return run_model(model, mode, options, deck=spec)
    return run_model(model, mode, options)


def cost_at(points, target):
    """(CPU s at error `target`, extrapolated?) by log-log interpolation over [(cpu, error),
    ...]; past the ladder's end the last two points are extrapolated (flagged)."""
    pts = sorted(p for p in points if p[1] > 0)
    for (c0, e0), (c1, e1) in zip(pts, pts[1:]):
        if (e0 - target) * (e1 - target) <= 0 and e0 != e1:
            x = np.log(target / e0) / np.log(e1 / e0)
            return float(np.exp(np.log(c0) + x * np.log(c1 / c0))), False
    ok = [c for c, e in pts if e <= target]
    if ok:
        return min(ok), False
    if len(pts) >= 2 and pts[-1][1] < pts[-2][1]:
        (c0, e0), (c1, e1) = pts[-2], pts[-1]
        x = np.log(target / e0) / np.log(e1 / e0)
        return float(np.exp(np.log(c0) + x * np.log(c1 / c0))), True
    return float("nan"), False


# ------------------------------------------------------------------ the spherical chain
def chain_spec(n, angle=0.3, g=9.81):
    """Links of 1 kg, 0.5 m, body frame at the centre, rod axis y', J' = diag(1/48, 1e-4,
    1/48), joints at (0, +-0.25, 0); link i turned `angle` about (cos phi_i, 0, sin phi_i),
    phi_i = 2 pi i / n, hanging from a spherical joint at the origin; gravity (0, -g, 0)."""
    from mbsim.deck.spec import BodySpec, DeckSpec, JointSpec, PointSet

    def body(name, mass=1.0, J=(1.0, 1.0, 1.0), r=(0, 0, 0), p=(1, 0, 0, 0), ground=False):
        return BodySpec(name, mass, np.diag(J), np.asarray(r, float), np.asarray(p, float),
                        None, None, None, ground)

    bodies, joints, top = [body("ground", ground=True)], [], np.zeros(3)
    for i in range(n):
        ph = 2 * np.pi * i / n
        p = from_axis_angle((np.cos(ph), 0, np.sin(ph)), angle)
        A = rot_A(p)
        r = top - A @ np.array([0, 0.25, 0])
        bodies.append(body(f"link{i}", 1.0, (1 / 48, 1e-4, 1 / 48), r, p))
        prev = "ground" if i == 0 else f"link{i - 1}"
        pp = (0, 0, 0) if i == 0 else (0, -0.25, 0)
        joints.append(JointSpec(f"S{i}", "spherical", (prev, f"link{i}"),
                                {prev: PointSet(np.array(pp, float)),
                                 f"link{i}": PointSet(np.array([0, 0.25, 0]))}))
        top = r + A @ np.array([0, -0.25, 0])
    return DeckSpec(title=f"spherical chain of {n}", file=f"<chain {n}>", text="",
                    gravity=np.array([0, -g, 0.0]), parameters={},
                    bodies={b.name: b for b in bodies}, joints={j.name: j for j in joints},
                    drivers={}, forces={}, outputs={}, analysis={})


def chain_model(n):
    from mbsim.model import compile_model

    return compile_model(chain_spec(n))


def chain_tip(res, n):
    """Bottom point (0, -0.25, 0) of the last link at the last output, global."""
    r = res.channel(f"bodies/link{n - 1}/r").data[-1]
    p = res.channel(f"bodies/link{n - 1}/p").data[-1]
    return r + rot_A(p) @ np.array([0, -0.25, 0])


# ------------------------------------------------------------------ Exudyn (optional)
def exudyn_available():
    try:
        import exudyn  # noqa: F401
    except ImportError:
        return False
    return True


def _exudyn_settings(exu, steps, t_end, sparse=True):
    """Fixed-step settings for Exudyn's default implicit solver (generalized-alpha); the
    sparse linear solver (Eigen) is what makes its 64-link chain fast (dense: 25x slower)."""
    ss = exu.SimulationSettings()
    if sparse:
        ss.linearSolverType = exu.LinearSolverType.EigenSparse
    ss.timeIntegration.numberOfSteps = int(steps)
    ss.timeIntegration.endTime = float(t_end)
    ss.timeIntegration.verboseMode = 0
    for path, value in (("solution.file.write", False), ("show.computationTime", False),
                        ("show.statistics", False)):
        obj = ss
        try:
            *head, last = path.split(".")
            for h in head:
                obj = getattr(obj, h)
            setattr(obj, last, value)
        except AttributeError:  # older Exudyn: the pre-1.12 names
            pass
    return ss


def exudyn_rigid_system(model, q, qd):
    """An Exudyn twin of an mbsim model made of rigid bodies joined by spherical, revolute,
    translational and distance joints, with TSDA spring-dampers, started from the same
    consistent state (positions from q; velocities rd and global omega from qd).
    Returns (SystemContainer, mbs, {body name: ObjectIndex})."""
    import exudyn as exu
    from exudyn.utilities import RigidBodyInertia

    from mbsim.rotations import E as rot_E

    SC = exu.SystemContainer()
    mbs = SC.AddSystem()
    items = {}
    Q, V = q.reshape(-1, 7), qd.reshape(-1, 7)
    for b, name in enumerate(model.body_names):
        A = rot_A(Q[b, 3:])
        if model.is_ground[b]:
            items[name] = mbs.CreateGround(referencePosition=list(Q[b, :3]),
                                           referenceRotationMatrix=A)
            continue
        w = 2 * rot_E(Q[b, 3:]) @ V[b, 3:]
        inertia = RigidBodyInertia(mass=float(model.mass[b]),
                                   inertiaTensor=np.array(model.J_local[b]))
        items[name] = mbs.CreateRigidBody(inertia=inertia, referencePosition=list(Q[b, :3]),
                                          referenceRotationMatrix=A,
                                          initialVelocity=list(V[b, :3]),
                                          initialAngularVelocity=list(w),
                                          gravity=list(model.gravity))
    for it in model.items:
        if it.kind != "joint":
            continue
        bi, bj = model.body_names[it.bi], model.body_names[it.bj]
        Ai = rot_A(Q[it.bi, 3:])
        P = Q[it.bi, :3] + Ai @ it.P_i
        pair = [items[bi], items[bj]]
        if it.type == "spherical":
            mbs.CreateSphericalJoint(itemNumbers=pair, position=list(P))
        elif it.type == "revolute":
            mbs.CreateRevoluteJoint(itemNumbers=pair, position=list(P),
                                    axis=list(Ai @ it.C_i[:, 0]))
        elif it.type == "translational":
            mbs.CreatePrismaticJoint(itemNumbers=pair, position=list(P),
                                     axis=list(Ai @ it.C_i[:, 0]))
        elif it.type == "universal":
            # spherical + the book's dot-1 (Haug eq. 9.4.3): the cross axes stay
            # perpendicular; Exudyn's generic joint frees rotations about the two axes
            Aj = rot_A(Q[it.bj, 3:])
            hi, hj = Ai @ it.C_i[:, 0], Aj @ it.C_j[:, 0]
            third = np.cross(hi, hj)
            frame = np.column_stack([hi, hj - hi * (hi @ hj), third / np.linalg.norm(third)])
            frame[:, 1] /= np.linalg.norm(frame[:, 1])
            mbs.CreateGenericJoint(bodyNumbers=pair, position=list(P), rotationMatrixAxes=frame,
                                   constrainedAxes=[1, 1, 1, 0, 0, 1])
        elif it.type == "distance":
            Pj = Q[it.bj, :3] + rot_A(Q[it.bj, 3:]) @ it.P_j
            mbs.CreateDistanceConstraint(itemNumbers=pair, localPosition0=list(it.P_i),
                                         localPosition1=list(it.P_j),
                                         distance=float(np.linalg.norm(Pj - P)))
        else:
            raise NotImplementedError(f"no Exudyn twin for joint type {it.type}")
    for el in model.forces:
        if el.type != "tsda":
            raise NotImplementedError(f"no Exudyn twin for force type {el.type}")
        mbs.CreateSpringDamper(itemNumbers=[items[model.body_names[el.bi]],
                                            items[model.body_names[el.bj]]],
                               localPosition0=list(el.si), localPosition1=list(el.sj),
                               referenceLength=el.L0, stiffness=el.k, damping=el.c)
    mbs.Assemble()
    return SC, mbs, items


def exudyn_run(model, q, qd, steps, t_end, points, sparse=True, omegas=()):
    """Exudyn's default implicit solver (generalized-alpha) with `steps` fixed steps; returns
    ({name: (3,) global position at t_end} for points {name: (body, local point)}, plus
    ``{body: (3,) global angular velocity}`` for the bodies in `omegas` under the key
    ``"<body>.omega"``, wall s, CPU s).  The build is not timed."""
    import exudyn as exu

    SC, mbs, items = exudyn_rigid_system(model, q, qd)
    ss = _exudyn_settings(exu, steps, t_end, sparse)
    w0, c0 = time.perf_counter(), time.process_time()
    mbs.SolveDynamic(ss)
    wall, cpu = time.perf_counter() - w0, time.process_time() - c0
    out = {k: np.array(mbs.GetObjectOutputBody(items[b], exu.OutputVariableType.Position,
                                               localPosition=list(s)))
           for k, (b, s) in points.items()}
    for b in omegas:
        out[f"{b}.omega"] = np.array(mbs.GetObjectOutputBody(
            items[b], exu.OutputVariableType.AngularVelocity, localPosition=[0, 0, 0]))
    return out, wall, cpu


# ------------------------------------------------------------------ Exudyn: every solver
# Exudyn 1.13's dynamic solvers (exudyn.DynamicSolverType) by what they accept: the implicit
# ones take constrained (index-3 / index-2) systems, the explicit ones only systems without
# algebraic variables ("explicit integrator detected node ... which contains algebraic
# variables"), i.e. the minimal-coordinate ObjectKinematicTree of an open chain.
EXUDYN_IMPLICIT = ("GeneralizedAlpha", "TrapezoidalIndex2")
EXUDYN_FIXED = ("RK44", "RK67")  # explicit, fixed step
EXUDYN_ADAPTIVE = ("DOPRI5", "ODE23", "DVERK6")  # explicit, error-controlled step
EXUDYN_LINEAR = ("EXUdense", "EigenDense", "EigenSparse")  # EigenSparseSymmetric: "not available"


class ExudynSolver:
    """One Exudyn solver configuration: method (a DynamicSolverType name), linear solver (a
    LinearSolverType name), modified Newton (implicit methods: the Jacobian kept over steps).
    ``setting`` of a run is the number of fixed steps, or the tolerance of an adaptive one.
    ignore_singular: linearSolverSettings.ignoreSingularJacobian (Exudyn's switch for
    redundant constraints)."""

    def __init__(self, method, linear="EXUdense", modified_newton=False, ignore_singular=False):
        self.method, self.linear, self.modified_newton = method, linear, bool(modified_newton)
        self.ignore_singular = bool(ignore_singular)

    @property
    def adaptive(self):
        return self.method in EXUDYN_ADAPTIVE

    @property
    def label(self):
        newton = (", modified Newton" if self.modified_newton else ", full Newton") \
            if self.method in EXUDYN_IMPLICIT else ""
        return f"{self.method} ({self.linear}{newton})"

    def settings(self, exu, t_end, setting):
        ss = _exudyn_settings(exu, 100 if self.adaptive else int(setting), t_end, sparse=False)
        try:
            ss.linearSolver.solverType = getattr(exu.LinearSolverType, self.linear)
        except AttributeError:  # before 1.12
            ss.linearSolverType = getattr(exu.LinearSolverType, self.linear)
        ss.timeIntegration.newton.useModifiedNewton = self.modified_newton
        ss.linearSolverSettings.ignoreSingularJacobian = self.ignore_singular
        if self.adaptive:
            ti = ss.timeIntegration
            ti.automaticStepSize = True
            ti.absoluteTolerance = ti.relativeTolerance = float(setting)
            ti.minimumStepSize = 1e-12
        return ss

    def variants(self, implicit_newton=True):
        """This method with every linear solver (and both Newton variants if implicit)."""
        newton = (False, True) if self.method in EXUDYN_IMPLICIT and implicit_newton else (False,)
        return [ExudynSolver(self.method, lin, m, self.ignore_singular) for lin in EXUDYN_LINEAR
                for m in newton]


class quiet_stdout:
    """Silence file descriptor 1 (Exudyn's C++ core prints failure banners there)."""

    def __enter__(self):
        import sys

        sys.stdout.flush()
        self.saved = os.dup(1)
        null = os.open(os.devnull, os.O_WRONLY)
        os.dup2(null, 1)
        os.close(null)
        return self

    def __exit__(self, *exc):
        os.dup2(self.saved, 1)
        os.close(self.saved)
        return False


def exudyn_solve(mbs, solver, t_end, setting):
    """Solve `mbs` from its initial state with `solver` (ExudynSolver); returns (CPU s, None)
    or (CPU s, the error message) when Exudyn refuses or fails."""
    import exudyn as exu

    ss = solver.settings(exu, t_end, setting)
    c0 = time.process_time()
    try:
        with quiet_stdout():
            ok = mbs.SolveDynamic(ss, solverType=getattr(exu.DynamicSolverType, solver.method))
        message = None if ok else "solver failed"
    except Exception as exc:  # Exudyn raises RuntimeError/ValueError with its message
        message = " ".join(str(exc).split())[:200]
    return time.process_time() - c0, message


def exudyn_chain_tree(model, n, g=9.81):
    """The spherical chain of chain_spec as Exudyn's minimal-coordinate ObjectKinematicTree:
    each spherical joint is three revolutes (about z, x, y of a frame turned by the link's
    initial rotation relative to its parent, so q = 0 is the initial state and the
    gimbal-lock of the middle axis is 90 degrees of bending away), the first two on massless
    links.  Returns (SystemContainer, mbs, tip sensor): the sensor reads the last link's
    bottom point (0, -0.5, 0) from the joint, global (the same point as chain_tip)."""
    import exudyn as exu
    import exudyn.itemInterface as eii

    Q = model.q0.reshape(-1, 7)
    names = list(model.body_names)
    A = [rot_A(Q[names.index(f"link{i}"), 3:]) for i in range(n)]
    jtypes, parents, frames, offsets, inertias, coms, masses = [], [], [], [], [], [], []
    axes = (exu.JointType.RevoluteZ, exu.JointType.RevoluteX, exu.JointType.RevoluteY)
    for i in range(n):
        rel = A[i] if i == 0 else A[i - 1].T @ A[i]
        for k, axis in enumerate(axes):
            jtypes.append(axis)
            parents.append(len(jtypes) - 2)
            frames.append(rel if k == 0 else np.eye(3))
            offsets.append([0.0, -0.5 if (k == 0 and i > 0) else 0.0, 0.0])  # link frame at its top
            real = k == 2
            inertias.append(np.diag([1 / 48, 1e-4, 1 / 48]) if real else np.zeros((3, 3)))
            coms.append([0.0, -0.25 if real else 0.0, 0.0])
            masses.append(1.0 if real else 0.0)
    SC = exu.SystemContainer()
    mbs = SC.AddSystem()
    nq = 3 * n
    node = mbs.AddNode(eii.NodeGenericODE2(referenceCoordinates=[0.0] * nq,
                                           initialCoordinates=[0.0] * nq,
                                           initialCoordinates_t=[0.0] * nq,
                                           numberOfODE2Coordinates=nq))
    tree = mbs.AddObject(eii.ObjectKinematicTree(
        nodeNumber=node, gravity=[0.0, -g, 0.0], jointTypes=jtypes, linkParents=parents,
        jointTransformations=exu.Matrix3DList(frames), jointOffsets=exu.Vector3DList(offsets),
        linkInertiasCOM=exu.Matrix3DList(inertias), linkCOMs=exu.Vector3DList(coms),
        linkMasses=masses))
    tip = mbs.AddSensor(eii.SensorKinematicTree(
        objectNumber=tree, linkNumber=nq - 1, localPosition=[0.0, -0.5, 0.0],
        outputVariableType=exu.OutputVariableType.Position, writeToFile=False,
        storeInternal=True))
    mbs.Assemble()
    return SC, mbs, tip


# ------------------------------------------------------------------ figure lines
# Every figure a script measures is printed as one line that before_after.py reads:
#
#     figure: <name> = <value> <unit> (median of <N>, spread <lo>..<hi>)
#
# <name> is any text ("chain N = 64: CPU per step"; the last " = " ends it), <unit> holds no
# " = "; <value>, <lo>, <hi> are numbers (4 significant digits); a figure
# that could not be measured (the run failed, timed out, ran out of memory) is printed as
#
#     figure: <name> = failed (<the error line>)
#
# so that the table shows why.  Everything else a script prints is commentary.
FIGURE_RE = re.compile(r"^figure: (?P<name>.+) = (?:failed \((?P<error>.*)\)|"
                       r"(?P<value>\S+) (?P<unit>.*?) \(median of (?P<n>\d+), "
                       r"spread (?P<lo>\S+)\.\.(?P<hi>\S+)\))\s*$")


def figure_line(name, values, unit, spread=None):
    """The figure line of the median of `values` (a number or a list of repeats); or, with
    spread = (median, lo, hi), of a figure derived elsewhere from len(values) repeats."""
    vals = [float(v) for v in (values if np.ndim(values) else [values])]
    med, lo, hi = spread if spread is not None else (np.median(vals), min(vals), max(vals))
    return (f"figure: {name} = {med:.4g} {unit} (median of {len(vals)}, spread "
            f"{lo:.4g}..{hi:.4g})")


def figure(name, values, unit, spread=None):
    """Print the figure line of `values` (see figure_line)."""
    print(figure_line(name, values, unit, spread), flush=True)


def figure_failed(name, message):
    """Print a figure that could not be measured, with the one error line that says why."""
    text = " ".join(str(message).split())[:300] or "no message"
    print(f"figure: {name} = failed ({text})", flush=True)


def parse_figure(line):
    """{name, value, unit, n, lo, hi} or {name, error} of a figure line; None otherwise."""
    m = FIGURE_RE.match(line.strip())
    if not m:
        return None
    if m["error"] is not None:
        return {"name": m["name"], "error": m["error"]}
    try:
        return {"name": m["name"], "value": float(m["value"]), "unit": m["unit"],
                "n": int(m["n"]), "lo": float(m["lo"]), "hi": float(m["hi"])}
    except ValueError:
        return None


# ------------------------------------------------------------------ a process measured
class ChildRun:
    """One child process measured: exit code, wall s, CPU s (user + system, its own and its
    children's, from os.wait4), peak resident memory (MB, ru_maxrss), its output text, and
    whether it was killed at the time-out."""

    def __init__(self, code, wall, cpu, maxrss_mb, out, err, timed_out):
        self.code, self.wall, self.cpu, self.maxrss_mb = code, wall, cpu, maxrss_mb
        self.out, self.err, self.timed_out = out, err, timed_out

    def error_line(self):
        """The child's last `error: ...` line, else its last stderr line, else the exit."""
        if self.timed_out:
            return f"timed out after {self.wall:.0f} s"
        lines = [ln for ln in self.err.splitlines() if ln.strip()]
        errs = [ln for ln in lines if ln.startswith("error:")]
        last = (errs or lines or [f"exit {self.code}"])[-1]
        return f"exit {self.code}: {last.strip()}"


def run_child(cmd, cwd=None, env=None, timeout=None, memory_limit_mb=None, log=None):
    """Run `cmd` to its end (killed after `timeout` s) and measure it with os.wait4, which
    gives this child's own resource usage (RUSAGE_CHILDREN would mix all children).
    memory_limit_mb: an address-space limit (RLIMIT_AS) for the child, so that a model too
    large for the code fails with a memory error instead of swapping a shared machine.
    log: a file that receives the child's standard output as it runs (to follow a long
    run), else a temporary file."""
    import tempfile

    def limit():
        if memory_limit_mb:
            b = int(memory_limit_mb * 2**20)
            resource.setrlimit(resource.RLIMIT_AS, (b, b))

    out_file = open(log, "w+b") if log else tempfile.TemporaryFile()  # noqa: SIM115
    with out_file as fo, tempfile.TemporaryFile() as fe:
        w0 = time.perf_counter()
        p = subprocess.Popen(cmd, cwd=cwd, env=env, stdout=fo, stderr=fe, stdin=subprocess.DEVNULL,
                             preexec_fn=limit if memory_limit_mb else None,
                             start_new_session=True)
        timed_out = False
        deadline = None if timeout is None else w0 + timeout
        try:
            while True:
                pid, status, ru = os.wait4(p.pid, os.WNOHANG)
                if pid:
                    break
                if deadline is not None and time.perf_counter() > deadline:
                    timed_out = True
                    os.killpg(p.pid, 9)
                    pid, status, ru = os.wait4(p.pid, 0)
                    break
                time.sleep(0.005)
        except BaseException:  # Ctrl-C, or SIGTERM via exit_on_sigterm: no orphan left running
            os.killpg(p.pid, 9)
            os.wait4(p.pid, 0)
            raise
        wall = time.perf_counter() - w0
        p.returncode = os.waitstatus_to_exitcode(status)
        fo.seek(0)
        fe.seek(0)
        out = fo.read().decode(errors="replace")
        err = fe.read().decode(errors="replace")
    # ru_maxrss: kilobytes on Linux, bytes on macOS
    rss = ru.ru_maxrss / (2**20 if sys.platform == "darwin" else 2**10)
    return ChildRun(p.returncode, wall, ru.ru_utime + ru.ru_stime, rss, out, err, timed_out)


def exit_on_sigterm():
    """Make SIGTERM end this process through SystemExit, so that run_child kills the child
    it waits for (children run in their own session and would outlive a plain SIGTERM)."""
    import signal

    signal.signal(signal.SIGTERM, lambda *_: sys.exit(143))


def mbsim_command():
    """The mbsim command of the measured checkout: this interpreter with ``-m mbsim`` (the
    same imports as the ``mbsim`` script; ROOT is put on PYTHONPATH by mbsim_env)."""
    return [sys.executable, "-m", "mbsim"]


def mbsim_env():
    """The environment for an mbsim child: ROOT first on PYTHONPATH, BLAS single-threaded."""
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([str(ROOT)] + [p for p in env.get(
        "PYTHONPATH", "").split(os.pathsep) if p])
    return env


# ------------------------------------------------------------------ the chain as a deck
def chain_deck(n, t_end=2.0, step=None, angle=0.3, g=9.81):
    """chain_spec's spherical chain of `n` links as deck text (YAML), with a dynamic
    analysis to `t_end` at output step `step` (default t_end): the deck is the interface
    every version of mbsim reads, so the scripts that time set-up and output use it."""
    step = t_end if step is None else step
    lines = [f"title: spherical chain of {n} links", "units: SI", f"gravity: [0, {-g!r}, 0]",
             "bodies:", "  ground: {ground: true}"]
    top = np.zeros(3)
    for i in range(n):
        ph = 2 * np.pi * i / n
        p = from_axis_angle((np.cos(ph), 0, np.sin(ph)), angle)
        A = rot_A(p)
        r = top - A @ np.array([0, 0.25, 0])
        top = r + A @ np.array([0, -0.25, 0])
        lines.append(f"  link{i}: {{mass: 1.0, inertia: [{1 / 48!r}, 0.0001, {1 / 48!r}], "
                     f"r: [{', '.join(repr(float(x)) for x in r)}], "
                     f"p: [{', '.join(repr(float(x)) for x in p)}]}}")
    lines.append("joints:")
    for i in range(n):
        prev = "ground" if i == 0 else f"link{i - 1}"
        pp = "[0, 0, 0]" if i == 0 else "[0, -0.25, 0]"
        lines.append(f"  S{i}: {{type: spherical, bodies: [{prev}, link{i}], points: "
                     f"{{{prev}: {{P: {pp}}}, link{i}: {{P: [0, 0.25, 0]}}}}}}")
    lines += ["analysis:", f"  dynamic: {{t_end: {t_end!r}, step: {step!r}}}", ""]
    return "\n".join(lines)


def kernel_functions(lib):
    """The library's exported functions: every non-static ``mb_*`` function defined in the
    measured checkout's mbsim/fast/*.c (the C kernels of whatever version is measured),
    less the two that only describe the build."""
    import re

    found = []
    for src in sorted((ROOT / "mbsim" / "fast").glob("*.c")):
        for m in re.finditer(r"^(?!static)[A-Za-z_][\w \t*]*?\b(mb_\w+)\s*\(",
                             src.read_text(), re.M):
            if m[1] not in found and m[1] not in ("mb_source_hash", "mb_struct_size"):
                found.append(m[1])
    return [n for n in found if hasattr(lib, n)]
