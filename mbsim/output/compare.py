"""Regression comparison of two results (``mbsim compare A.h5 B.h5 --rtol R --atol A``).

`b` is the reference (golden) result. An element passes when

    |a - b| <= atol + rtol * |b|                       (numpy.isclose, b the reference)

and its *scaled* error is ``|a - b| / (atol + rtol * |b|)``, so a comparison passes when
every scaled error is at most 1. ``rtol = atol = 0`` asks for exact equality. NaN equals
NaN (and nothing else); equal infinities are equal.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from mbsim.result import Result


@dataclass
class Difference:
    """The worst element of one channel."""

    channel: str  # slash path
    time: float  # output time of the worst element, s
    index: tuple  # full index into the channel data, time index first: (it,) or (it, j)
    a: float  # value in the compared result
    b: float  # value in the reference result
    abs_err: float  # |a - b| (inf where exactly one of a, b is NaN)
    scaled: float  # abs_err / (atol + rtol |b|); > 1 fails; inf for a difference at zero tolerance

    @property
    def failed(self) -> bool:
        """True when this element is outside the tolerance."""
        return not self.scaled <= 1.0


def scaled_error(
    a: np.ndarray, b: np.ndarray, rtol: float, atol: float
) -> tuple[np.ndarray, np.ndarray]:
    """Elementwise ``(abs_err, scaled)`` of `a` against the reference `b` (same shape).

    Equal values (including equal infinities) and NaN/NaN pairs have zero error; a NaN
    against a number has ``abs_err = scaled = inf``.
    """
    a = np.asarray(a, dtype=float)
    b = np.asarray(b, dtype=float)
    with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
        same = (a == b) | (np.isnan(a) & np.isnan(b))
        diff = np.where(same, 0.0, np.abs(a - b))
        diff = np.where(np.isnan(diff), np.inf, diff)  # NaN vs number, inf - inf handled above
        tol = atol + rtol * np.abs(b)
        tol = np.where(np.isnan(tol), 0.0, tol)
        scaled = np.where(tol > 0.0, diff / np.where(tol > 0.0, tol, 1.0), np.inf)
        scaled = np.where(np.isinf(diff), np.inf, scaled)  # e.g. a finite against b = inf
        scaled = np.where(diff == 0.0, 0.0, scaled)
    return diff, scaled


def _worst(
    name: str, t: np.ndarray, a: np.ndarray, b: np.ndarray, rtol: float, atol: float
) -> Difference | None:
    if a.size == 0:
        return None
    diff, scaled = scaled_error(a, b, rtol, atol)
    # worst scaled error, ties (e.g. all zero or all inf) broken by the absolute error
    order = np.lexsort((diff.ravel(), scaled.ravel()))
    flat = int(order[-1])
    index = tuple(int(i) for i in np.unravel_index(flat, a.shape))
    return Difference(
        channel=name,
        time=float(t[index[0]]) if t.size > index[0] else float("nan"),
        index=index,
        a=float(a[index]),
        b=float(b[index]),
        abs_err=float(diff[index]),
        scaled=float(scaled[index]),
    )


def _check_time(a: Result, b: Result, rtol: float, atol: float) -> str | None:
    ta = np.asarray(a.t, dtype=float).reshape(-1)
    tb = np.asarray(b.t, dtype=float).reshape(-1)
    if ta.shape != tb.shape:
        return f"time axes differ: {ta.size} samples in a, {tb.size} in b"
    worst = _worst("time", tb, ta, tb, rtol, atol)
    if worst is not None and worst.failed:
        return (
            f"time axes differ: sample {worst.index[0]} is t = {worst.a!r} s in a, "
            f"{worst.b!r} s in b"
        )
    return None


MONITORS = ("monitors/", "error/")  # step sizes, violations, error estimates: they differ
# between two tolerances of the same motion; compared only when asked (monitors=True)


def channel_atol(b: np.ndarray, rtol: float) -> float:
    """The default absolute tolerance of a channel: rtol times its range in the reference
    (max - min over all its components; its largest magnitude when it is constant), so that
    round-off about zero (2e-21 in a channel that spans 0.2) does not count."""
    b = np.asarray(b, dtype=float)
    finite = b[np.isfinite(b)]
    if not finite.size:
        return 0.0
    span = float(np.ptp(finite))
    return rtol * (span if span > 0 else float(np.abs(finite).max()))


def compare_results(
    a: Result,
    b: Result,
    rtol: float = 1e-9,
    atol: float | None = 0.0,
    channels: list[str] | None = None,
    monitors: bool = True,
) -> tuple[bool, list[Difference], list[str]]:
    """Compare result `a` with the reference result `b`, element by element.

    Parameters
    ----------
    a : Result
        The result under test.
    b : Result
        The reference (golden) result; relative errors are taken against its values.
    rtol, atol : float
        Tolerances of ``|a - b| <= atol + rtol |b|``; both 0 means exact equality.  ``atol``
        None: each channel's own, :func:`channel_atol` (``mbsim compare``'s default).
    channels : list of str, optional
        Channel names (dots or slashes) to compare; default the channels of both results.
    monitors : bool
        Compare the ``monitors/`` and ``error/`` channels too (when ``channels`` is None).

    Returns
    -------
    ok : bool
        True when there is no problem and every element is within tolerance.
    differences : list of Difference
        The worst element of every compared channel, worst (largest ``scaled``) first;
        channels that pass are included, ``Difference.failed`` tells them apart.
    problems : list of str
        Structural mismatches: a channel missing in one result, different shapes,
        different time axes, different status.
    """
    if rtol < 0 or (atol is not None and atol < 0):
        raise ValueError(f"tolerances must be >= 0, got rtol={rtol}, atol={atol}")
    problems: list[str] = []
    if a.status != b.status:
        problems.append(f"status differs: a is {a.status!r}, b is {b.status!r}")
    time_problem = _check_time(a, b, rtol, 0.0 if atol is None else atol)
    if time_problem:
        problems.append(time_problem)
    if channels is None:
        names = list(b.channels) + [n for n in a.channels if n not in b.channels]
        if not monitors:
            names = [n for n in names if not n.startswith(MONITORS)]
    else:
        names = list(dict.fromkeys(c.replace(".", "/").strip("/") for c in channels))
    tb = np.asarray(b.t, dtype=float).reshape(-1)
    differences: list[Difference] = []
    for name in names:
        missing = [label for label, r in (("a", a), ("b", b)) if name not in r.channels]
        if len(missing) == 2 and channels is not None:  # a name in neither file: usage error
            raise KeyError(_unknown_channel(name, a, b))
        if missing:
            problems.append(f"channel {name!r} missing in {' and '.join(missing)}")
            continue
        da = np.asarray(a.channels[name].data, dtype=float)
        db = np.asarray(b.channels[name].data, dtype=float)
        if time_problem and da.shape[1:] == db.shape[1:] and da.shape[:1] != db.shape[:1]:
            continue  # different time axes: said once above, not once per channel
        if da.shape != db.shape:
            problems.append(f"channel {name!r}: shape {da.shape} in a, {db.shape} in b")
            continue
        tol = channel_atol(db, rtol) if atol is None else atol
        worst = _worst(name, tb, da, db, rtol, tol)
        if worst is not None:
            differences.append(worst)
    differences.sort(key=lambda d: (d.scaled, d.abs_err), reverse=True)
    ok = not problems and not any(d.failed for d in differences)
    return ok, differences, problems


def _unknown_channel(name: str, a: Result, b: Result) -> str:
    """Message for a --channels name in neither file: a component of a channel (compare takes
    whole channels), a group, or a close name."""
    import difflib

    known = list(dict.fromkeys(list(b.channels) + list(a.channels)))
    base = name.rpartition("/")[0]
    dotted = name.replace("/", ".")
    if base in known:
        return (f"{dotted!r} is a component; --channels takes whole channels: "
                f"{base.replace('/', '.')}")
    group = [n for n in known if n.startswith(name + "/")]
    if group:
        return (f"{dotted!r} is a group; --channels takes channels: "
                f"{', '.join(n.replace('/', '.') for n in group[:6])}{', ...' * (len(group) > 6)}")
    close = difflib.get_close_matches(name, known, n=3)
    hint = f"; did you mean {', '.join(c.replace('/', '.') for c in close)}?" if close else ""
    return f"no channel {dotted!r} in either file{hint}"


def compare_files(
    path_a: str | Path,
    path_b: str | Path,
    rtol: float = 1e-9,
    atol: float | None = 0.0,
    channels: list[str] | None = None,
    monitors: bool = True,
) -> tuple[bool, list[Difference], list[str]]:
    """:func:`compare_results` on two HDF5 result files (`path_b` the reference)."""
    from mbsim.output.hdf5 import read_result

    return compare_results(read_result(path_a), read_result(path_b), rtol, atol, channels,
                           monitors)
