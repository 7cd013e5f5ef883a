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
