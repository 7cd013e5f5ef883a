"""Where a run as a user runs it spends its CPU, phase by phase (issue 24: user run <= 2x
the bare integration, the estimate <= 0.5x the run).

    python benchmarks/user_run.py [--repeats 5] [--decks governor,slider_crank:free,vehicle]

Per deck (``name`` or ``name:scene``): the work of ``mbsim run DECK --mode dynamic -o FILE``
in process, with the deck as that command passes it (``common.run_with_deck``: its settings,
text and shapes; the deck loaded once, untimed; one untimed warm-up run so that first-use
imports and the kernels' loading count nowhere), split by the functions it calls, process
CPU per run in ms, median of --repeats [min-max]:

- ``set-up``: :class:`mbsim.analyses.trajectory.Prepared` (initial state, row selection);
- ``trajectory``: the run's integration with the state at every output
  (``main_trajectory``);
- ``estimate``: the error estimate's companion and its differences (``estimate``);
- ``outputs``: the channels and monitors at the outputs (``build_result``);
- ``shapes``: the scene arrays of the file (:func:`mbsim.view.geometry.scene_arrays`);
- ``write``: :func:`mbsim.output.hdf5.write_result` (in memory, then written and synced);
- ``rest``: the user run less the phases above (option merging, the result's bookkeeping);
- ``bare``: the same integration with one output and no estimate (its own run), and the
  ratio user / bare, which ``benchmarks/peers.py --cases user`` also prints;
- ``load``: :func:`mbsim.api.load_model` of the deck as ``mbsim run`` loads it (its
  ``studies:`` left to ``mbsim check`` where the checkout's load_model can), outside the
  user run (a figure of its own: ms per load, median of the repeats);
- the number of HDF5 objects (groups and datasets) in the run's file (a figure).

Phases are timed by wrapping the named functions where the run looks them up (the wrappers'
own cost, ~1 us a call, is in the phases).  Figures (``phases: ...``, so that
before_after.py's table keeps them apart from peers.py's): user run / bare, and estimate /
(user run - estimate - shapes - write) per deck.

``--split`` (default on; ``--no-split``): the whole ``mbsim run`` again as a process runs it
once, ``load_model`` of the deck, the run and ``write_result`` of a fresh model each time
(``peers.py --cases share``'s work, after the same warm-up), with every C kernel of the
measured checkout (every ``mb_*`` function of its mbsim/fast/*.c) wrapped as well: per phase
the process CPU inside the kernels (``C``) and outside them (``Python``, the wrappers' ~1 us
a call included), ms per run, medians; and the share of the C kernels in the process CPU of
the whole (figure ``phases: compiled share (process CPU)``), the arithmetic of issue 24's
60 %.

``--floors`` (default on; ``--no-floors``): what the ratio user run / bare could be with no
Python around the work a user run must add, per deck (the model loaded once, as ``measure``):
the C kernels' process CPU in the user run (without its file) and in the bare run, each
kernel wrapped as in ``--split``; the HDF5 floor, the process CPU of writing the run's own
file objects (the same datasets, types, groups and attributes, read back from its file) with
one low-level h5py call each into HDF5's in-memory driver, then the image to disk with
fsync, as ``write_result`` does; and from them ``floor = (bare + C added + HDF5 floor) /
bare`` (figure ``floors: user run / bare with no Python around, <deck>``) and the Python
budget of a user run at the ratio 2, ``bare - C added - HDF5 floor`` (figure ``floors: Python
budget at user / bare = 2``), against the Python it spends today, ``user run - bare - C added
- HDF5 floor`` (figure ``floors: Python above the floors``).  Also the YAML floor, libyaml's
compose of the deck's text (``load_model``'s parser), and the compiled share of load + run +
write with no Python around, ``C of the user run / (that + HDF5 floor + YAML floor)``
(figure ``floors: compiled share ...``): issue 24's 60 % leaves Python the rest of C / 0.6."""

from __future__ import annotations

import argparse
import inspect
import os
import sys
import tempfile
import time
from pathlib import Path

import h5py
import numpy as np
import yaml

# common.ROOT: the checkout measured ($MBSIM_ROOT, set by before_after.py for each side,
# else this tree), put first on sys.path by common
sys.path.insert(0, str(Path(__file__).resolve().parent))

from common import ROOT, figure, kernel_functions, run_with_deck  # noqa: E402

DECKS = "governor,slider_crank:free,vehicle"
PHASES = ("set-up", "trajectory", "estimate", "outputs", "shapes", "write")


def timed(module, name, key, spent):
    """Wrap ``module.name`` so that its process CPU adds to ``spent[key]``; returns the
    original (to put back)."""
    f = getattr(module, name)

    def wrapper(*args, **kwargs):
        c0 = time.process_time()
        try:
            return f(*args, **kwargs)
        finally:
            spent[key] += time.process_time() - c0

    setattr(module, name, wrapper)
    return f


def deck_run(deck, scene):
    """(path, load_model's extra arguments as ``mbsim run`` passes them, spec, model, the
    deck's dynamic options, the bare run's options: one output, no estimate)."""
    from mbsim.api import load_model

    path = ROOT / "models" / f"{deck}.yaml"
    for_run = {"studies": False} if "studies" in inspect.signature(load_model).parameters else {}
    spec, model = load_model(path, scene=scene, **for_run)
    opts = dict(spec.analysis.get("dynamic", {}))
    bare = dict(opts, error_estimate=False,
                step=float(opts.get("t_end", 1.0)) - float(opts.get("t_start", 0.0)))
    return path, for_run, spec, model, opts, bare


def measure(deck, scene, repeats, tmp):
    """{phase: [ms per run]} of the user run of one deck, and the bare runs' ms."""
    import mbsim.analyses.dynamic as dyn
    import mbsim.view.geometry as geometry
    from mbsim.api import load_model
    from mbsim.output import hdf5

    path, for_run, spec, model, opts, bare = deck_run(deck, scene)
    out = Path(tmp) / f"{deck}.h5"
    hdf5.write_result(run_with_deck(model, "dynamic", dict(opts), spec), out)  # warm-up
    spent = dict.fromkeys(PHASES, 0.0)
    wrapped = [(dyn, "Prepared", "set-up"), (dyn, "main_trajectory", "trajectory"),
               (dyn, "estimate", "estimate"), (dyn, "build_result", "outputs"),
               (geometry, "scene_arrays", "shapes")]
    originals = [(m, n, timed(m, n, k, spent)) for m, n, k in wrapped]
    got = {k: [] for k in (*PHASES, "rest", "user run", "bare", "load")}
    try:
        for _ in range(repeats):
            for k in spent:
                spent[k] = 0.0
            c0 = time.process_time()
            res = run_with_deck(model, "dynamic", dict(opts), spec)
            c1 = time.process_time()
            hdf5.write_result(res, out)
            c2 = time.process_time()
            spent["write"] = c2 - c1
            for k in PHASES:  # (before the bare run, which calls the same functions)
                got[k].append(1e3 * spent[k])
            run_with_deck(model, "dynamic", dict(bare), spec)
            c3 = time.process_time()
            got["user run"].append(1e3 * (c2 - c0))
            got["rest"].append(1e3 * (c2 - c0) - sum(got[k][-1] for k in PHASES))
            got["bare"].append(1e3 * (c3 - c2))
            load_model(path, scene=scene, **for_run)
            got["load"].append(1e3 * (time.process_time() - c3))
    finally:
        for m, n, f in originals:
            setattr(m, n, f)
    t_span = float(opts.get("t_end", 1.0)) - float(opts.get("t_start", 0.0))
    with h5py.File(out, "r") as f:
        objects: list[str] = []
        f.visit(objects.append)
    return got, t_span, len(res.t), len(objects)


def wrap_kernels(lib, in_c):
    """Wrap every C kernel of ``lib`` (common.kernel_functions) so that its process CPU adds
    to ``in_c["t"]``; returns the originals [(lib, name, function)] to put back."""
    def kernel(f):
        def c_kernel(*args):
            c0 = time.process_time()
            try:
                return f(*args)
            finally:
                in_c["t"] += time.process_time() - c0
        return c_kernel

    originals = [(lib, n, getattr(lib, n)) for n in kernel_functions(lib)]
    for _, n, f in originals:
        setattr(lib, n, kernel(f))
    return originals


def file_objects(path):
    """The objects of the HDF5 file ``path`` in the file's order: (parent, name, None, attrs)
    for a group, (parent, name, (data, file type, memory type, space, creation properties),
    attrs) for a dataset."""
    items = []
    with h5py.File(path, "r") as f:
        items.append(("", "", None, dict(f.attrs)))

        def visit(name, obj):
            parent, _, leaf = name.rpartition("/")
            if isinstance(obj, h5py.Group):
                items.append((parent, leaf, None, dict(obj.attrs)))
                return
            data = np.asarray(obj[()], dtype=obj.dtype)
            items.append((parent, leaf, (data, obj.id.get_type(),
                                         h5py.h5t.py_create(obj.dtype, logical=True),
                                         obj.id.get_space(), obj.id.get_create_plist()),
                          dict(obj.attrs)))
        f.visititems(visit)
    return items


def _attr(oid, key, value):
    data = np.asarray(value.encode() if isinstance(value, str) else value)
    if isinstance(value, str):
        data = np.asarray(value, dtype=h5py.string_dtype())
    mtype = h5py.h5t.py_create(data.dtype, logical=True)
    space = (h5py.h5s.create(h5py.h5s.SCALAR) if data.ndim == 0
             else h5py.h5s.create_simple(data.shape))
    h5py.h5a.create(oid, key.encode(), mtype, space).write(data, mtype=mtype)


FLOOR_FILES = iter(range(1 << 62))


def write_floor(items, dest):
    """``items`` (file_objects) written with one low-level h5py call per object and
    attribute into HDF5's in-memory driver, then the image to ``dest`` with fsync."""
    fapl = h5py.h5p.create(h5py.h5p.FILE_ACCESS)
    fapl.set_fapl_core(1 << 16, False)
    fid = h5py.h5f.create(f"floor-{next(FLOOR_FILES)}".encode(), h5py.h5f.ACC_TRUNC,
                          fapl=fapl)
    ids = {"": h5py.h5g.open(fid, b"/")}
    for parent, name, ds, attrs in items:
        if ds is None and name:
            ids[f"{parent}/{name}".strip("/")] = oid = h5py.h5g.create(ids[parent],
                                                                        name.encode())
        elif ds is None:
            oid = ids[""]
        else:
            data, ftype, mtype, space, dcpl = ds
            oid = h5py.h5d.create(ids[parent], name.encode(), ftype, space, dcpl=dcpl)
            if data.size:
                oid.write(h5py.h5s.ALL, h5py.h5s.ALL, data, mtype=mtype)
        for key, value in attrs.items():
            _attr(oid, key, value)
    h5py.h5f.flush(fid)
    image = fid.get_file_image()
    del ids, oid
    fid.close()
    with open(dest, "wb") as out:
        out.write(image)
        out.flush()
        os.fsync(out.fileno())


def floors(deck, scene, repeats, tmp):
    """{name: [ms per run]}: the user run (its file included) and the bare run, the C
    kernels' CPU in each, and the HDF5 floor of the user run's file (module doc)."""
    from mbsim.fast import _lib
    from mbsim.output import hdf5

    path, _, spec, model, opts, bare = deck_run(deck, scene)
    out, copy = Path(tmp) / f"{deck}-floor.h5", Path(tmp) / f"{deck}-floor-copy.h5"
    hdf5.write_result(run_with_deck(model, "dynamic", dict(opts), spec), out)  # warm-up
    items = file_objects(out)
    write_floor(items, copy)
    in_c = {"t": 0.0}
    originals = wrap_kernels(_lib.library(), in_c)
    text = path.read_text()
    loader = getattr(yaml, "CSafeLoader", yaml.SafeLoader)
    got = {k: [] for k in ("user run", "user run C", "bare", "bare C", "HDF5 floor",
                           "YAML floor")}
    try:
        for _ in range(repeats):
            in_c["t"], c0 = 0.0, time.process_time()
            hdf5.write_result(run_with_deck(model, "dynamic", dict(opts), spec), out)
            c1, k1 = time.process_time(), in_c["t"]
            run_with_deck(model, "dynamic", dict(bare), spec)
            c2, k2 = time.process_time(), in_c["t"]
            write_floor(items, copy)
            c3 = time.process_time()
            yaml.compose(text, Loader=loader)
            c4 = time.process_time()
            for key, v in zip(got, (c1 - c0, k1, c2 - c1, k2 - k1, c3 - c2, c4 - c3)):
                got[key].append(1e3 * v)
    finally:
        for m, n, f in originals:
            setattr(m, n, f)
    return got


def split(deck, scene, repeats, tmp):
    """{phase: (total ms, C ms) per run, medians} of load + run + write with a fresh model
    each time, and the C share of the whole (list over the repeats)."""
    import mbsim.analyses.dynamic as dyn
    import mbsim.api as api
    import mbsim.view.geometry as geometry
    from mbsim.fast import _lib
    from mbsim.output import hdf5

    path = ROOT / "models" / f"{deck}.yaml"
    for_run = ({"studies": False} if "studies" in inspect.signature(api.load_model).parameters
               else {})  # fmt: skip
    out = Path(tmp) / f"{deck}-split.h5"
    lib = _lib.library()
    in_c = {"t": 0.0}
    spent: dict[str, list[float]] = {}

    def phase(module, name, key):
        f = getattr(module, name)

        def wrapper(*args, **kwargs):
            c0, k0 = time.process_time(), in_c["t"]
            try:
                return f(*args, **kwargs)
            finally:
                got = spent.setdefault(key, [0.0, 0.0])
                got[0] += time.process_time() - c0
                got[1] += in_c["t"] - k0
        setattr(module, name, wrapper)
        return f

    def user_run():
        spec, model = api.load_model(path, scene=scene, **for_run)
        res = run_with_deck(model, "dynamic", dict(spec.analysis.get("dynamic", {})), spec)
        hdf5.write_result(res, out)

    user_run()  # warm-up
    originals = wrap_kernels(lib, in_c)
    wrapped = [(api, "load_model", "load"), (dyn, "Prepared", "set-up"),
               (dyn, "main_trajectory", "trajectory"), (dyn, "estimate", "estimate"),
               (dyn, "build_result", "outputs"), (geometry, "scene_arrays", "shapes"),
               (hdf5, "write_result", "write")]
    originals += [(m, n, phase(m, n, k)) for m, n, k in wrapped]
    rows: dict[str, list[tuple[float, float]]] = {}
    shares = []
    try:
        for _ in range(repeats):
            spent.clear()
            in_c["t"] = 0.0
            c0 = time.process_time()
            user_run()
            total = time.process_time() - c0
            for k, (t, c) in spent.items():
                rows.setdefault(k, []).append((1e3 * t, 1e3 * c))
            rows.setdefault("rest", []).append(  # the run less its phases (option merging...)
                (1e3 * (total - sum(t for t, _ in spent.values())),
                 1e3 * (in_c["t"] - sum(c for _, c in spent.values()))))
            rows.setdefault("whole", []).append((1e3 * total, 1e3 * in_c["t"]))
            shares.append(in_c["t"] / total)
    finally:
        for m, n, f in originals:
            setattr(m, n, f)
    med = {k: (float(np.median([t for t, _ in v])), float(np.median([c for _, c in v])))
           for k, v in rows.items()}
    return med, shares


def print_floors(label, got):
    """The floors' lines and figures of one deck (module doc, ``--floors``)."""
    b, bc = got["bare"], got["bare C"]
    added = [u - b0 for u, b0 in zip(got["user run C"], bc)]
    floor = [(b0 + a + h) / b0 for b0, a, h in zip(b, added, got["HDF5 floor"])]
    budget = [b0 - a - h for b0, a, h in zip(b, added, got["HDF5 floor"])]
    above = [u - b0 - a - h for u, b0, a, h in zip(got["user run"], b, added, got["HDF5 floor"])]
    share = [c / (c + h + y) for c, h, y in
             zip(got["user run C"], got["HDF5 floor"], got["YAML floor"])]
    print("    floors: process CPU ms per run, medians [min-max]")
    for key, v in (*got.items(), ("C added by the user run", added),
                   ("Python budget at user / bare = 2", budget),
                   ("Python above the floors", above),
                   ("user / bare with no Python around", floor),
                   ("C share with no Python around, %", [100 * x for x in share])):
        print(f"    {key:<34} {np.median(v):8.3f} [{min(v):.3f}-{max(v):.3f}]", flush=True)
    figure(f"floors: user run / bare with no Python around, {label}", floor, "x")
    figure(f"floors: Python budget at user / bare = 2, {label}", budget, "ms")
    figure(f"floors: Python above the floors, {label}", above, "ms")
    figure(f"floors: HDF5 floor of the run's file, {label}", got["HDF5 floor"], "ms")
    figure(f"floors: compiled share of load + run + write with no Python around, {label}",
           [100 * x for x in share], "%")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--decks", default=DECKS, help=f"name[:scene],... (default {DECKS})")
    ap.add_argument("--split", action=argparse.BooleanOptionalAction, default=True,
                    help="also C / Python per phase of a fresh load + run + write")
    ap.add_argument("--floors", action=argparse.BooleanOptionalAction, default=True,
                    help="also the ratio with no Python around the kernels and HDF5")
    a = ap.parse_args(argv)
    with tempfile.TemporaryDirectory() as tmp:
        for item in a.decks.split(","):
            deck, _, scene = item.partition(":")
            got, t_span, nt, objects = measure(deck, scene or None, max(1, a.repeats), tmp)
            label = f"{deck}{' (' + scene + ')' if scene else ''}"
            print(f"\n=== {label}: {t_span:g} s, {nt} outputs; process CPU ms per run, median "
                  f"of {a.repeats} [min-max] ===")
            user = np.median(got["user run"])
            print(f"    HDF5 objects in the file: {objects}")
            for k, v in got.items():
                med = np.median(v)
                print(f"    {k:<12} {med:8.2f} [{min(v):.2f}-{max(v):.2f}]  "
                      f"{100 * med / user:5.1f} % of the user run", flush=True)
            figure(f"phases: user run / bare, {label}",
                   [u / b for u, b in zip(got["user run"], got["bare"])], "x")
            figure(f"phases: estimate / run without it, shapes and file, {label}",
                   [e / (u - e - s - w) for u, e, s, w in
                    zip(got["user run"], got["estimate"], got["shapes"], got["write"])], "x")
            figure(f"phases: load_model, {label}", got["load"], "ms")
            figure(f"phases: write, {label}", got["write"], "ms")
            figure(f"phases: HDF5 objects in the file, {label}", [objects], "objects")
            if a.floors:
                print_floors(label, floors(deck, scene or None, max(1, a.repeats), tmp))
            if not a.split:
                continue
            med, shares = split(deck, scene or None, max(1, a.repeats), tmp)
            print("    load + run + write, fresh model (as one `mbsim run`), ms per run, "
                  "medians: total / in the C kernels / outside them")
            for k, (t, c) in med.items():
                print(f"    {k:<12} {t:8.2f}  C {c:7.2f}  Python {t - c:7.2f}", flush=True)
            figure(f"phases: compiled share (process CPU), {label}",
                   [100 * x for x in shares], "%")
            figure(f"phases: Python outside the C kernels, load + run + write, {label}",
                   [med["whole"][0] - med["whole"][1]], "ms")


if __name__ == "__main__":
    main()
