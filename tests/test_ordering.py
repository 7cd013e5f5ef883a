"""The Schur rows' reverse Cuthill-McKee order in numpy (mbsim.fast.ordering) is scipy's
(scipy.sparse.csgraph.reverse_cuthill_mckee on (B @ B.T).tocsr(), what schur_structure
used before): the same graph, neighbours in the same order, and the same permutation,
integer for integer, on every deck, on chains and on random row-body incidences."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest
import scipy.sparse as sp
from scipy.sparse.csgraph import reverse_cuthill_mckee as scipy_rcm

from mbsim.api import load_model
from mbsim.fast import System
from mbsim.fast.ordering import reverse_cuthill_mckee, row_graph
from mbsim.model import compile_model

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))
from common import chain_spec  # noqa: E402

DECKS = sorted((ROOT / "models").glob("*.yaml")) + \
    sorted((ROOT / "tests" / "analyses" / "data").glob("*.yaml"))


def assert_scipys(inc, ma, nb):
    indptr, indices = row_graph(inc, ma)
    B = sp.csr_matrix((np.ones(len(inc)), (inc[:, 0], inc[:, 2])), shape=(ma, nb))
    graph = (B @ B.T).tocsr()
    assert list(indptr) == list(graph.indptr)
    assert list(indices) == list(graph.indices)
    expected = scipy_rcm(graph, symmetric_mode=True) if ma else np.zeros(0, int)
    assert list(reverse_cuthill_mckee(indptr, indices)) == list(expected)


@pytest.mark.parametrize("deck", DECKS, ids=lambda p: p.name)
def test_the_schur_order_is_scipys_on_every_deck(deck):
    _, model = load_model(deck)
    system = System(model)
    assert_scipys(system.inc, system.m, model.nb)


@pytest.mark.parametrize("n", [1, 4, 64, 300])
def test_the_schur_order_is_scipys_on_chains(n):
    model = compile_model(chain_spec(n))
    system = System(model)
    assert_scipys(system.inc, system.m, model.nb)


def test_the_schur_order_is_scipys_on_random_incidences():
    """Rows on one or two of nb bodies, several components, isolated bodies."""
    rng = np.random.default_rng(24)
    for _ in range(200):
        ma, nb = int(rng.integers(0, 60)), int(rng.integers(1, 30))
        inc = sorted((u, 7 * s, int(b)) for u in range(ma)
                     for s, b in enumerate(rng.choice(nb, size=min(nb, int(rng.integers(1, 3))),
                                                      replace=False)))
        inc = np.array(sorted(inc, key=lambda x: (x[2], x[0], x[1])),
                       dtype=np.int64).reshape(-1, 3)
        assert_scipys(inc, ma, nb)


def schur_structure_by_loops(rb, rows, nb):
    """schur_structure as written before its incidences and envelope products were arrays
    (f6fe280): a sorted list of (u, 7 s, body), then per body its incidences g1 x g2 with
    pos[u1] >= pos[u2], one tuple at a time."""
    ma = rows.size
    inc = [(u, 7 * s, rb[r, s]) for u, r in enumerate(rows) for s in range(2) if rb[r, s] >= 0]
    inc = np.array(sorted(inc, key=lambda x: (x[2], x[0], x[1])), dtype=np.int64).reshape(-1, 3)
    indptr, indices = row_graph(inc, ma)
    order = reverse_cuthill_mckee(indptr, indices)
    pos = np.empty(ma, dtype=np.int64)
    pos[order] = np.arange(ma)
    fc = np.arange(ma, dtype=np.int64)
    np.minimum.at(fc, pos[np.repeat(np.arange(ma), np.diff(indptr))], pos[indices])
    off = np.concatenate([[0], np.cumsum(np.arange(ma) - fc + 1)[:-1]]).astype(np.int64) \
        if ma else fc.copy()
    pairs = []
    for b in range(nb):
        mine = np.flatnonzero(inc[:, 2] == b)
        for g1 in mine:
            for g2 in mine:
                pu, pv = pos[inc[g1, 0]], pos[inc[g2, 0]]
                if pu >= pv:
                    pairs.append((off[pu] + pv - fc[pu], g1, g2))
    sidx = np.stack([np.asarray(rows, dtype=np.int64), order, fc, off])
    return sidx, inc, np.array(pairs, dtype=np.int64).reshape(-1, 3)


def test_the_schur_structure_is_the_loops_on_random_row_body_tables():
    """mbsim.fast.dynamics.schur_structure (arrays) gives the loops' arrays integer for
    integer, in their order (the Schur products are summed in it): random tables of rows on
    ground (-1) or bodies, random row subsets, no rows at all."""
    from mbsim.fast.dynamics import schur_structure

    rng = np.random.default_rng(2411)
    for _ in range(300):
        nb, m = int(rng.integers(1, 10)), int(rng.integers(0, 30))
        rb = rng.integers(-1, nb, size=(m, 2)).astype(np.int64)
        rows = np.sort(rng.choice(m, size=int(rng.integers(0, m + 1)), replace=False)) \
            if m else np.zeros(0, dtype=np.int64)
        for got, want in zip(schur_structure(rb, rows.astype(np.int64), nb),
                             schur_structure_by_loops(rb, rows.astype(np.int64), nb)):
            assert got.dtype == want.dtype and got.shape == want.shape
            assert np.array_equal(got, want)
