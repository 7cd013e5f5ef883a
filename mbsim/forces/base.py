"""Force elements: the contract every type implements.

Contract of a force type (a class registered in ``FORCES``):

1. ``type``: the deck name; ``description``: one line for ``mbsim list forces``.
2. ``from_spec(spec, body_index) -> element``: compile a ForceSpec (names -> indices,
   laws -> callables); raise DeckError with ``spec.where`` for what the loader cannot know.
3. ``apply(st, t, F, n_local)``: ADD this element's loads to the accumulators
   ``F`` (nb, 3) global forces at the centroids and ``n_local`` (nb, 3) torques about the
   centroids in body frames.  ``st`` is :class:`mbsim.core.State` (r, p, rd, pd, A,
   omega, omega_local).  A point force F at body point s' contributes F to F[b] and
   s' x (A^T F) to n_local[b]; the equations turn these into Q_r = F and Q_p = 2 G^T n'
   (Haug Ch. 11).
4. ``potential(st) -> float``: stored energy of the conservative part (0 if none), for the
   energy monitor and minimum-potential-energy equilibrium.
5. ``channels(st, t) -> dict[name, (value, unit)]``: optional outputs (length, force, ...).
6. ``channels_many(states, t) -> dict[name, (values (nt, ...), unit)]``: the channels at
   every output at once (``states``: :class:`mbsim.core.States`, ``t`` (nt,)); the default
   evaluates ``channels`` output by output; a type overrides it with array code where it can.
   ``potential_many(states) -> (nt,)`` and ``loads_many(states, t, F, n_local)`` (adding to
   (nt, nb, 3) arrays) likewise for ``potential`` and ``apply``.
7. ``describe(model) -> str``: optional, one line for ``mbsim info`` (e.g. the step limit a
   contact's impacts need).
"""

from __future__ import annotations

from abc import ABC, abstractmethod

import numpy as np


class ForceElement(ABC):
    type = ""
    description = ""
    name = ""

    @abstractmethod
    def apply(self, st, t, F, n_local) -> None:
        """Contract item 3."""

    def potential(self, st) -> float:
        return 0.0

    def channels(self, st, t) -> dict:
        return {}

    def channels_many(self, states, t) -> dict:
        """Contract item 6: ``channels`` at each output, stacked (time first)."""
        rows = [self.channels(states[k], t[k]) for k in range(len(t))]
        if not rows:
            return {}
        return {key: (np.array([np.asarray(r[key][0], dtype=float) for r in rows]), unit)
                for key, (_, unit) in rows[0].items()}

    def loads_many(self, states, t, F, n_local) -> None:
        """Contract item 6: ``apply`` at each output, adding to F, n_local (nt, nb, 3)."""
        for k in range(len(t)):
            self.apply(states[k], t[k], F[k], n_local[k])

    def potential_many(self, states) -> np.ndarray:
        """Contract item 6: ``potential`` at each output, (nt,)."""
        return np.array([self.potential(states[k]) for k in range(len(states))], dtype=float)
