"""The deck: YAML file -> validated :class:`~mbsim.deck.spec.DeckSpec` (format: docs/deck.md).

The loader is imported on first use, so that ``mbsim.deck.spec`` (plain dataclasses used by
the model and the tests) does not pull in YAML parsing, units and expressions.
"""

__all__ = ["ParsedDeck", "load_deck", "load_deck_text", "parse_deck"]


def __getattr__(name):
    if name in __all__:
        from mbsim.deck import loader

        return getattr(loader, name)
    raise AttributeError(f"module 'mbsim.deck' has no attribute {name!r}")
