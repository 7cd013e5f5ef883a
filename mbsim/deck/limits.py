"""Size limits on decks, checked while the YAML is parsed, before anything big is allocated.

Decks come from other people: a limit turns a deck that would take minutes or gigabytes
(a 10^7-point table, a 100 000-deep list, 10^12 output times) into one ``error:`` line that
names the limit and the environment variable that raises it (docs/deck.md, "Limits").
The defaults are far above the seed's decks (largest: 25 kB, nesting 7, lists of 12 items,
38 parameters, 2001 output times) and bound the load time to about a second.

Where each is checked: DECK_BYTES on the file's size before it is read (and on deck text
given otherwise); DEPTH, ITEMS and NODES on YAML's parser events as they come, before
anything is composed (mbsim.deck.tree._over_limit); NAME_CHARS, TABLE_POINTS,
POLYNOMIAL_TERMS and PARAMETERS on the composed tree; OUTPUTS with the analysis settings;
CASES on a sweep's --param lists before the cases are made (mbsim.sweep.make_cases).
"""

from __future__ import annotations

import os
from dataclasses import dataclass


@dataclass(frozen=True)
class Limit:
    key: str  # MBSIM_MAX_<KEY> raises it
    default: int
    what: str  # 'a deck file of {n} bytes'-style words for the message

    @property
    def env(self) -> str:
        return f"MBSIM_MAX_{self.key}"

    @property
    def value(self) -> int:
        """The default, or the environment's value when it is a positive integer."""
        raw = os.environ.get(self.env, "")
        try:
            n = int(raw)
        except ValueError:
            return self.default
        return n if n > 0 else self.default

    def exceeded(self, got: int | float | None = None) -> str:
        """The message for ``got`` over the limit: names the limit and how to raise it."""
        if got is None:
            over = f"over the limit of {self.value}"
        else:
            got_s = f"{got:.3g}" if isinstance(got, float) else str(got)
            over = f"over the limit: {got_s} > {self.value}"
        return f"{self.what} is {over} (set the environment variable {self.env} to raise it)"


DECK_BYTES = Limit("DECK_BYTES", 16 * 2**20, "deck file size (bytes)")
DEPTH = Limit("DEPTH", 64, "nesting depth of lists and mappings")
ITEMS = Limit("ITEMS", 100_000, "number of entries of one list or mapping")
NODES = Limit("NODES", 500_000, "number of values in the deck (every number, text, list and "
              "mapping)")
NAME_CHARS = Limit("NAME_CHARS", 200, "length of a key (characters)")
TABLE_POINTS = Limit("TABLE_POINTS", 100_000, "number of points of a table or polynomial")
POLYNOMIAL_TERMS = Limit("POLYNOMIAL_TERMS", 1000, "number of polynomial coefficients")
PARAMETERS = Limit("PARAMETERS", 10_000, "number of parameters")
OUTPUTS = Limit("OUTPUTS", 1_000_000, "number of output times (t_end - t_start)/step")
CASES = Limit("CASES", 100_000, "number of sweep cases (the product of the --param lists' "
              "lengths)")  # each case is a process's run and a file: 10^5 is days of work
FORMULA_CHARS = 10_000  # mbsim.expr.MAX_LENGTH: fixed, a formula is one line

ALL = (DECK_BYTES, DEPTH, ITEMS, NODES, NAME_CHARS, TABLE_POINTS, POLYNOMIAL_TERMS,
       PARAMETERS, OUTPUTS)


# -- analysis settings ---------------------------------------------------------------------------
# Tolerances are relative or absolute error bounds: 0 makes an adaptive integrator shrink its
# step forever (issue 13: `atol: 0` hung the compressor), 1 or more accepts any error.
OPEN_UNIT = {"rtol": "a relative tolerance", "atol": "an absolute tolerance",
             "accuracy": "a length in metres"}  # fmt: skip
POSITIVE = ("step", "h", "h_max", "max_steps")


def setting_problems(settings: dict, defaults: dict | None = None) -> list[tuple[str, str]]:
    """What is wrong with an analysis's settings: [(key, message)], empty when all is well.

    ``settings`` are the values given (deck and command line), ``defaults`` the analysis's
    own (``DEFAULTS`` of its module) for the time grid.  Checks: tolerances in (0, 1), positive
    steps, ``t_end > t_start``, and the number of output times against :data:`OUTPUTS`.
    """
    out: list[tuple[str, str]] = []
    eff = {**(defaults or {}), **{k: v for k, v in settings.items() if v is not None}}

    def number(key):
        v = eff.get(key)
        if v is None or isinstance(v, bool) or not isinstance(v, (int, float)):
            return None
        return float(v)

    for key, what in OPEN_UNIT.items():
        v = settings.get(key)
        if v is None:
            continue
        x = number(key)
        if x is None or not (0 < x < 1):  # also NaN
            out.append((key, f"{key} must be > 0 and < 1 ({what}), got {v!r}"))
    for key in POSITIVE:
        if settings.get(key) is None:
            continue
        x = number(key)
        if x is None or not x > 0 or x == float("inf"):
            out.append((key, f"{key} must be a finite number > 0, got {settings[key]!r}"))
    t0, t1, step = number("t_start"), number("t_end"), number("step")
    for key, x in (("t_start", t0), ("t_end", t1)):
        if settings.get(key) is not None and (x is None or x != x or abs(x) == float("inf")):
            out.append((key, f"expected a finite time, got {settings[key]!r}"))
    if out or t1 is None:
        return out
    t0 = t0 or 0.0
    if not t1 > t0:
        key = "t_end" if settings.get("t_end") is not None else "t_start"
        out.append((key, f"t_end must be greater than t_start, got t_end = {t1:g} s, "
                         f"t_start = {t0:g} s"))  # fmt: skip
    elif step is not None and step > 0:
        n = (t1 - t0) / step + 1
        if n > OUTPUTS.value:
            key = "step" if settings.get("step") is not None else "t_end"
            out.append((key, f"t_end = {t1:g} s, t_start = {t0:g} s, step = {step:g} s: "
                             f"{OUTPUTS.exceeded(float(n))}"))  # fmt: skip
    return out
