"""The fuzzing campaign of issue 13, as a test: seeded mutations of the seed decks
(models/*.yaml) go through `mbsim check` in-process (click's CliRunner), a subset also
through a short `mbsim run`; no exception may escape, every failure is one ``error:`` line
with exit code 1 or 2, no case may exceed its time limit, and no result marked complete may
hold NaN or inf.

Mutations (the issue's list): keys deleted or renamed; values replaced by wrong types, NaN,
inf, 1e308, 0, -1, huge lists, empty or unicode strings, long text; bodies swapped; files
truncated; duplicate keys; broken indentation; tabs; deep nesting; Python tags.

The default run tries N_DEFAULT decks (about 20 s here); ``pytest -m slow`` tries N_SLOW.
Run with ``-s`` to see the figures (decks tried, clean errors, passed, tracebacks, hangs,
NaN in complete results).
"""

from __future__ import annotations

import math
import random
import re
import signal
import time
from pathlib import Path

import h5py
import numpy as np
import pytest
import yaml
from click.testing import CliRunner

from mbsim.cli import main

MODELS = sorted((Path(__file__).resolve().parents[1] / "models").glob("*.yaml"))
N_DEFAULT, RUN_DEFAULT = 300, 12
N_SLOW, RUN_SLOW = 2000, 200
CHECK_LIMIT = 20.0  # s per `check` (the slowest seed deck takes ~0.3 s)
RUN_LIMIT = 60.0  # s per short `run` (t_end 0.02 s)
SEED = 20261123
LOADER = getattr(yaml, "CSafeLoader", yaml.SafeLoader)  # libyaml: the generator's own cost
DUMPER = getattr(yaml, "CSafeDumper", yaml.SafeDumper)  # is then ~1/10 of the campaign's

WEIRD = [
    None, True, "abc", "", "ünïcødé ∑ 名前", "x" * 5000, [], {}, [1, 2], {"a": 1},
    float("nan"), float("inf"), -float("inf"), 1e308, -1e308, 1e300, 0, -1, 0.0, 1e-320,
    "1e308", "-1e308", "nan", "inf", "9**9**9", "sqrt(-1)", "exp(exp(exp(exp(10))))",
    "1/0", "30*deg", "deg(30)", "'360 deg * t'", "2*pie", "__import__('os')", "t" * 3,
    list(range(2000)), [[1, 2, 3]] * 50,
]  # fmt: skip


class Hang(BaseException):
    """Raised by the alarm: a case ran past its time limit (BaseException: nothing in mbsim
    may swallow it)."""


def _alarm(signum, frame):
    raise Hang


def _paths(node, prefix=()):
    """Every (path, value) in a plain YAML tree."""
    out = [(prefix, node)]
    if isinstance(node, dict):
        for k, v in node.items():
            out += _paths(v, prefix + (k,))
    elif isinstance(node, list):
        for i, v in enumerate(node):
            out += _paths(v, prefix + (i,))
    return out


def _parent(tree, path):
    node = tree
    for k in path[:-1]:
        node = node[k]
    return node


def _structural(rng: random.Random, tree) -> str:
    """One mutation of the loaded deck, dumped back to YAML text."""
    paths = [p for p, _ in _paths(tree) if p]
    path = rng.choice(paths)
    parent, key = _parent(tree, path), path[-1]
    op = rng.choice(["delete", "rename", "replace", "replace", "replace", "swap", "deep"])
    if op == "delete":
        del parent[key]
    elif op == "rename" and isinstance(parent, dict):
        key_s = str(key)
        new = rng.choice([key_s + "x", key_s[:-1], key_s.upper(), "ü" + key_s, key_s * 2, "", "1"])
        parent[new] = parent.pop(key)
    elif op == "swap" and isinstance(tree.get("bodies"), dict) and len(tree["bodies"]) > 1:
        a, b = rng.sample(list(tree["bodies"]), 2)
        tree["bodies"][a], tree["bodies"][b] = tree["bodies"][b], tree["bodies"][a]
    elif op == "deep":  # PyYAML cannot dump it: a marker, replaced in the text below
        parent[key] = f"DEEP{rng.choice([40, 70, 400, 2000, 100_000])}"
    else:
        parent[key] = rng.choice(WEIRD)
    text = yaml.dump(tree, Dumper=DUMPER, sort_keys=False, allow_unicode=True, width=10**6)
    return re.sub(r"DEEP(\d+)", lambda m: "[" * int(m[1]) + "1" + "]" * int(m[1]), text)


def _textual(rng: random.Random, text: str) -> str:
    lines = text.split("\n")
    k = rng.randrange(len(lines))
    op = rng.choice(["truncate", "duplicate", "indent", "dedent", "tab", "byte", "tag", "key"])
    if op == "truncate":
        return text[: rng.randrange(len(text))]
    if op == "duplicate":
        lines.insert(k, lines[k])
    elif op == "indent":
        lines[k] = " " * rng.randint(1, 3) + lines[k]
    elif op == "dedent":
        lines[k] = lines[k][1:]
    elif op == "tab":
        lines[k] = "\t" + lines[k]
    elif op == "byte":
        pos = rng.randrange(len(text))
        return text[:pos] + rng.choice(["\x00", "\x07", "\ufffe", "{", "]", ":", "&a", "*a",
                                        "!!binary ", "%", "'"]) + text[pos:]  # fmt: skip
    elif op == "tag":
        return text.replace("title:", "title: !!python/object/apply:os.system "
                            f'["true {rng.randrange(10**6)}"]\nold_title:', 1)  # fmt: skip
    else:  # a key at the top level that is not a key: a huge flow list
        n = rng.choice([10, 5000, 100_001])  # the last one over MBSIM_MAX_ITEMS
        lines.append("zz: [" + ", ".join("1" for _ in range(n)) + "]")
    return "\n".join(lines)


def mutated_decks(n: int, seed: int = SEED):
    """n (name, text) pairs, deterministic for a seed."""
    rng = random.Random(seed)
    seeds = [(p.stem, p.read_text()) for p in MODELS]
    for i in range(n):
        stem, text = seeds[i % len(seeds)]
        if rng.random() < 0.6:
            tree = yaml.load(text, Loader=LOADER)
            for _ in range(rng.choice([1, 1, 1, 2, 3])):
                text = _structural(rng, tree)
        else:
            text = _textual(rng, text)
        yield f"{stem}_{i}", text


def _one_error_line(stderr: str) -> bool:
    """Exactly one `error:` line; anything else on stderr must be a `warning:` line."""
    lines = [ln for ln in stderr.splitlines() if ln.strip()]
    return sum(ln.startswith("error: ") for ln in lines) == 1 and all(
        ln.startswith(("error: ", "warning: ")) for ln in lines)


def _invoke(runner, args, limit):
    old = signal.signal(signal.SIGALRM, _alarm)
    signal.setitimer(signal.ITIMER_REAL, limit)
    t0 = time.perf_counter()
    try:
        res = runner.invoke(main, args)
    except Hang:  # raised outside the command body
        res = None
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, old)
    return res, time.perf_counter() - t0


def _nonfinite(path: Path) -> int:
    """Datasets of a complete results file holding NaN or inf."""
    bad = 0
    with h5py.File(path, "r") as f:
        if f.attrs.get("status") != "complete":
            return 0

        def visit(name, obj):
            nonlocal bad
            if isinstance(obj, h5py.Dataset) and obj.dtype.kind == "f":
                bad += int(not np.isfinite(obj[()]).all())

        f.visititems(visit)
    return bad


def campaign(tmp_path: Path, n: int, n_run: int) -> dict:
    runner = CliRunner()
    fig = {"decks tried": 0, "clean errors": 0, "passed": 0, "tracebacks": 0, "hangs": 0,
           "runs tried": 0, "runs complete": 0, "runs clean errors": 0,
           "NaN in complete results": 0, "slowest check s": 0.0}  # fmt: skip
    failures = []
    passed = []
    for name, text in mutated_decks(n):
        deck = tmp_path / f"{name}.yaml"
        deck.write_text(text, encoding="utf-8", errors="surrogatepass")
        fig["decks tried"] += 1
        res, dt = _invoke(runner, ["check", str(deck)], CHECK_LIMIT)
        fig["slowest check s"] = max(fig["slowest check s"], round(dt, 2))
        if res is None or isinstance(res.exception, Hang):
            fig["hangs"] += 1
            failures.append((name, "hang"))
            continue
        exc = res.exception
        if exc is not None and not (isinstance(exc, SystemExit) and exc.code in (1, 2)):
            fig["tracebacks"] += 1
            failures.append((name, repr(exc)[:300]))
            continue
        if res.exit_code == 0:
            fig["passed"] += 1
            passed.append(deck)
        elif _one_error_line(res.stderr) and "Traceback" not in res.output:
            fig["clean errors"] += 1
        else:
            fig["tracebacks"] += 1
            failures.append((name, f"not one error line: {res.stderr[:300]!r}"))
        if res.exit_code != 0:
            deck.unlink()  # keep the tmp folder small (a few decks hold 10^5-item lists)
    rng = random.Random(SEED + 1)
    for deck in rng.sample(passed, min(n_run, len(passed))):
        mode = "kinematic" if deck.name.startswith("slider_crank") else "dynamic"
        out = deck.with_suffix(".h5")
        fig["runs tried"] += 1
        res, dt = _invoke(runner, ["run", str(deck), "-m", mode, "--t-end", "0.02", "--step",
                                   "0.01", "-o", str(out), "-q"], RUN_LIMIT)  # fmt: skip
        if res is None or isinstance(res.exception, Hang):
            fig["hangs"] += 1
            failures.append((deck.name, "run hang"))
            continue
        exc = res.exception
        if exc is not None and not (isinstance(exc, SystemExit) and exc.code in (1, 2)):
            fig["tracebacks"] += 1
            failures.append((deck.name, "run: " + repr(exc)[:300]))
            continue
        if res.exit_code == 0:
            fig["runs complete"] += 1
        elif _one_error_line(res.stderr):
            fig["runs clean errors"] += 1
        else:
            fig["tracebacks"] += 1
            failures.append((deck.name, f"run: not one error line: {res.stderr[:300]!r}"))
        if out.exists():
            fig["NaN in complete results"] += _nonfinite(out)
    fig["failures"] = failures[:10]
    return fig


def _report(fig: dict) -> None:
    print("\nfuzz: " + ", ".join(f"{k} {v}" for k, v in fig.items() if k != "failures"))
    for name, why in fig["failures"]:
        print(f"  {name}: {why}")


def _assert_clean(fig: dict, n: int) -> None:
    _report(fig)
    assert fig["decks tried"] == n
    assert fig["tracebacks"] == 0, fig["failures"]
    assert fig["hangs"] == 0, fig["failures"]
    assert fig["NaN in complete results"] == 0
    # the campaign must exercise both sides: decks that pass and decks that fail cleanly
    assert fig["clean errors"] > n // 4 and fig["passed"] > n // 10
    assert fig["runs complete"] > 0 and fig["runs tried"] == fig["runs complete"] + fig[
        "runs clean errors"]
    assert math.isclose(fig["decks tried"], fig["clean errors"] + fig["passed"])


def test_generator_is_seeded():
    a = [t for _, t in mutated_decks(20)]
    assert a == [t for _, t in mutated_decks(20)]
    assert len(set(a)) == 20  # every deck differs


def test_fuzz_check_and_short_runs(tmp_path):
    _assert_clean(campaign(tmp_path, N_DEFAULT, RUN_DEFAULT), N_DEFAULT)


@pytest.mark.slow
def test_fuzz_check_and_short_runs_long(tmp_path):
    _assert_clean(campaign(tmp_path, N_SLOW, RUN_SLOW), N_SLOW)
