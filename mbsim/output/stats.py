"""Statistics of one signal over time: the ``numbers:`` of a deck's study and a sweep's
``--summary`` (final value, extremes, period, transition time, growth of an oscillation).

``STATS`` maps a statistic name to ``f(t, y, number) -> float`` over the output times
``t`` (nt,) and one scalar column ``y`` (nt,); ``number`` is the deck's entry (keys
``from``: start of the window in s, ``band``: relative settling band).  The names are
``mbsim.deck.schema.STUDY_STATS``.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np


def _window(t: np.ndarray, y: np.ndarray, number: dict) -> tuple[np.ndarray, np.ndarray]:
    """The samples at t >= number['from'] (all samples when it is None)."""
    start = number.get("from")
    if start is None:
        return t, y
    keep = t >= start - 1e-12
    return t[keep], y[keep]


def upcrossings(t: np.ndarray, y: np.ndarray, level: float) -> np.ndarray:
    """Times at which y crosses `level` upwards, by linear interpolation (s)."""
    d = y - level
    k = np.nonzero((d[:-1] < 0) & (d[1:] >= 0))[0]
    return t[k] - d[k] * (t[k + 1] - t[k]) / (d[k + 1] - d[k])


def period(t: np.ndarray, y: np.ndarray, number: dict | None = None) -> float:
    """Mean time between upward crossings of the mean of y over the window (s); NaN with
    fewer than two crossings.  For a periodic signal with one maximum and one minimum per
    cycle this is its period."""
    t, y = _window(t, y, number or {})
    if len(y) < 3:
        return float("nan")
    times = upcrossings(t, y, float(np.mean(y)))
    return float(np.mean(np.diff(times))) if len(times) >= 2 else float("nan")


def settle(t: np.ndarray, y: np.ndarray, number: dict | None = None) -> float:
    """Transition time: from the window's start t0 until y enters, for good, the band
    ``|y - y_end| <= band |y_end - y(t0)|`` around its final value (the 2 % settling time
    with the default band 0.02).  0 when y never leaves it; NaN ("does not settle") when y
    is still outside the band in the last tenth of the window: then ``y_end`` is no steady
    state (a growing or undamped oscillation, or a run too short)."""
    number = number or {}
    t, y = _window(t, y, number)
    change = abs(y[-1] - y[0])
    if change == 0.0:
        return 0.0
    outside = np.nonzero(np.abs(y - y[-1]) > number.get("band", 0.02) * change)[0]
    if len(outside) == 0:
        return 0.0
    k = outside[-1]
    if t[k] > t[-1] - 0.1 * (t[-1] - t[0]):
        return float("nan")
    return float(t[min(k + 1, len(t) - 1)] - t[0])


def growth(t: np.ndarray, y: np.ndarray, number: dict | None = None) -> float:
    """Growth of an oscillation: peak-to-peak range of y in the last quarter of the window
    over that in the third quarter.  Below 1 the motion dies out (stable), above 1 it grows
    (unstable); a constant-amplitude oscillation gives 1.  The quarters must span at least
    one period of the oscillation."""
    t, y = _window(t, y, number or {})
    q = np.linspace(t[0], t[-1], 5)
    third = y[(t >= q[2]) & (t <= q[3])]
    last = y[t >= q[3]]
    if len(third) < 2 or len(last) < 2:
        return float("nan")
    r3, r4 = float(np.ptp(third)), float(np.ptp(last))
    return r4 / r3 if r3 > 0 else (1.0 if r4 == 0 else float("inf"))


def _at(t, y, number, pick):
    t, y = _window(t, y, number)
    return float(t[pick(y)])


STATS: dict[str, Callable[[np.ndarray, np.ndarray, dict], float]] = {
    "final": lambda t, y, n: float(_window(t, y, n)[1][-1]),
    "initial": lambda t, y, n: float(_window(t, y, n)[1][0]),
    "max": lambda t, y, n: float(np.max(_window(t, y, n)[1])),
    "min": lambda t, y, n: float(np.min(_window(t, y, n)[1])),
    "absmax": lambda t, y, n: float(np.max(np.abs(_window(t, y, n)[1]))),
    "mean": lambda t, y, n: float(np.mean(_window(t, y, n)[1])),
    "range": lambda t, y, n: float(np.ptp(_window(t, y, n)[1])),
    "t_max": lambda t, y, n: _at(t, y, n, np.argmax),
    "t_min": lambda t, y, n: _at(t, y, n, np.argmin),
    "t_absmax": lambda t, y, n: _at(t, y, n, lambda v: np.argmax(np.abs(v))),
    "period": period,
    "settle": settle,
    "growth": growth,
}
TIME_STATS = ("t_max", "t_min", "t_absmax", "period", "settle")  # results in s
RATIO_STATS = ("growth",)  # dimensionless
