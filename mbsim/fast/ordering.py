"""The fill-reducing order of the Schur matrix's rows, in numpy alone (no scipy import).

The Schur matrix S = J M^-1 J^T couples two constraint rows when they share a body; its
rows are ordered by reverse Cuthill-McKee (Cuthill and McKee 1969; George and Liu 1981,
sec. 4.3) so that its envelope is narrow.  This module builds that row graph and the order
exactly as ``scipy.sparse.csgraph.reverse_cuthill_mckee`` does on the graph
``(B @ B.T).tocsr()`` (B the (m_a, nb) row-body incidence as csr), neighbours listed in the
order scipy's sparse product lists them, so that the order (and with it every Schur
factorization's round-off) is the one mbsim had with scipy: tests/test_ordering.py
compares the two.  Importing scipy.sparse costs about 0.1 s, and `mbsim check` builds a
System without needing it.
"""

from __future__ import annotations

import numpy as np


def row_graph(inc, ma):
    """(indptr (m_a + 1,), indices (nnz,)) int64: the rows coupled to each active row
    through a body, itself included, in the order of scipy's csr product B @ B.T.

    inc: (ninc, 3) int, (row position u, column offset, body) per incidence.
    """
    body_rows: dict[int, list[int]] = {}
    row_bodies: list[list[int]] = [[] for _ in range(ma)]
    for u, _, b in sorted({(int(u), 0, int(b)) for u, _, b in inc}):
        row_bodies[u].append(b)
    for u in range(ma):
        row_bodies[u].sort()
        for b in row_bodies[u]:
            body_rows.setdefault(b, []).append(u)
    indptr = [0]
    indices: list[int] = []
    for u in range(ma):
        seen: dict[int, None] = {}  # first appearance, as scipy's csr_matmat
        for b in row_bodies[u]:
            for v in body_rows[b]:
                seen.setdefault(v)
        indices.extend(reversed(seen))  # csr_matmat emits its linked list from the head
        indptr.append(len(indices))
    return np.array(indptr, dtype=np.int64), np.array(indices, dtype=np.int64)


def reverse_cuthill_mckee(indptr, indices):
    """(n,) int64: the reverse Cuthill-McKee order of a symmetric graph in csr form, by the
    rule of scipy.sparse.csgraph.reverse_cuthill_mckee(symmetric_mode=True): seeds in order
    of increasing degree (a self-loop counting twice; numpy's argsort of int32 degrees),
    each level's new nodes sorted by degree (stable), the whole order reversed."""
    n = indptr.size - 1
    degree = np.diff(indptr).astype(np.int32)
    owner = np.repeat(np.arange(n), np.diff(indptr))
    degree[np.unique(owner[indices == owner])] += 1
    seeds = np.argsort(degree)
    visited = np.zeros(n, dtype=bool)
    order: list[int] = []
    for seed in seeds:
        if visited[seed]:
            continue
        visited[seed] = True
        order.append(int(seed))
        start = len(order) - 1
        while start < len(order):
            end = len(order)
            for i in order[start:end]:
                new = [int(j) for j in indices[indptr[i]:indptr[i + 1]] if not visited[j]]
                for j in new:
                    visited[j] = True
                new.sort(key=lambda j: degree[j])  # stable, as scipy's insertion sort
                order.extend(new)
            start = end
        if len(order) == n:
            break
    return np.array(order[::-1], dtype=np.int64)
