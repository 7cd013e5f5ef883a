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


def schur_structure_by_loops(rb, rows, nb, held=()):
    """schur_structure as written before its incidences and envelope products were arrays:
    a sorted list of (u, 7 s, body), the incidences of held bodies from other rows set aside,
    then per body its incidences g1 x g2 with pos[u1] >= pos[u2], one tuple at a time (every
    column: ``pair_code`` of ALL_COLUMNS)."""
    from mbsim.fast.dynamics import ALL_COLUMNS, with_held_incidences

    ma = rows.size
    own = {b: set() for b in held}
    for u, r in enumerate(rows):
        if rb[r, 0] in own and rb[r, 1] < 0:
            own[rb[r, 0]].add(u)
    inc, cross = [], []
    for u, r in enumerate(rows):
        for s in range(2):
            b = rb[r, s]
            if b >= 0:
                (cross if b in own and u not in own[b] else inc).append((u, 7 * s, b))
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
                    pairs.append((off[pu] + pv - fc[pu], g1, g2,
                                  pair_code(ALL_COLUMNS, ALL_COLUMNS)))
    pairs = np.array(pairs, dtype=np.int64).reshape(-1, 4)
    inc, pairs = with_held_incidences(inc, cross, pairs)  # the same rule for held bodies
    sidx = np.stack([np.asarray(rows, dtype=np.int64), order, fc, off])
    return sidx, inc, pairs


def test_the_schur_structure_is_the_loops_on_random_row_body_tables():
    """mbsim.fast.dynamics._schur_structure (arrays) gives the loops' arrays integer for
    integer, in their order (the Schur products are summed in it): random tables of rows on
    ground (-1) or bodies, random row subsets, no rows at all, random held bodies."""
    from mbsim.fast.dynamics import _schur_structure

    rng = np.random.default_rng(2411)
    for _ in range(300):
        nb, m = int(rng.integers(1, 10)), int(rng.integers(0, 30))
        rb = rng.integers(-1, nb, size=(m, 2)).astype(np.int64)
        rows = np.sort(rng.choice(m, size=int(rng.integers(0, m + 1)), replace=False)) \
            if m else np.zeros(0, dtype=np.int64)
        held = tuple(int(b) for b in np.flatnonzero(rng.random(nb) < 0.3))
        for got, want in zip(_schur_structure(rb, rows.astype(np.int64), nb, None, held),
                             schur_structure_by_loops(rb, rows.astype(np.int64), nb, held)):
            assert got.dtype == want.dtype and got.shape == want.shape
            assert np.array_equal(got, want)


def pair_code(mask_u, mask_v):
    """pair_codes' rule for one pair, with Python integers: the columns where the product
    can be nonzero, mask_v & (mask_u | p columns); the r column (0-2, 7: none) where that
    leaves at most one r column and all four p columns, else -1 - the mask."""
    from mbsim.fast.dynamics import P_COLUMNS

    mask = int(mask_v) & (int(mask_u) | P_COLUMNS)
    r = mask & ~P_COLUMNS
    if mask & P_COLUMNS == P_COLUMNS and r in (0, 1, 2, 4):
        return r.bit_length() - 1 if r else 7
    return -1 - mask


def test_pair_codes_are_pair_code_on_every_pair_of_masks():
    """The arrays' pair_codes equals the rule taken pair by pair on all 128 x 128 masks."""
    from mbsim.fast.dynamics import pair_codes

    u, v = np.meshgrid(np.arange(128), np.arange(128), indexing="ij")
    want = np.array([[pair_code(a, b) for b in range(128)] for a in range(128)])
    assert np.array_equal(pair_codes(u, v), want)
