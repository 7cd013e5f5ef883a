"""mbsim.deck.tree's limit screen: counts of characters that let a deck skip the event walk.

``_within_limits`` may only say "within" for text the exact walk (``_over_limit``) accepts;
every deck of models/ must pass it (that is what makes loading them cost one parse).
"""

from __future__ import annotations

from pathlib import Path

import pytest

from mbsim.deck import tree
from mbsim.errors import DeckError

MODELS = sorted((Path(__file__).resolve().parents[2] / "models").glob("*.yaml"))


@pytest.mark.parametrize("path", MODELS, ids=[p.stem for p in MODELS])
def test_screen_passes_every_model_deck(path):
    text = path.read_text()
    assert tree._within_limits(text)
    assert tree._over_limit(text) is None


def _block_nest(n: int) -> str:
    return "".join(" " * i + f"k{i}:\n" for i in range(n)) + " " * n + "end\n"


# (text, the limit lowered to make it bite) -- nesting, entries and values at the limit and
# one past it, in block and flow style and in the compact forms that nest on one line
CASES = [
    ("- " * 63 + "a\n", {}),
    ("- " * 64 + "a\n", {}),
    ("- " * 65 + "a\n", {}),
    ("[" * 64 + "]" * 64 + "\n", {}),
    ("[" * 65 + "]" * 65 + "\n", {}),
    ("a: " + "{b: " * 65 + "1" + "}" * 65 + "\n", {}),
    ("--- " + "- " * 65 + "a\n", {}),
    ("- " + "? " * 65 + "a\n", {}),
    (_block_nest(63), {}),
    (_block_nest(64), {}),
    (_block_nest(65), {}),
    ("a:\n" + "".join(f"- {i}\n" for i in range(11)), {"MBSIM_MAX_ITEMS": "10"}),
    ("a: [" + ", ".join(str(i) for i in range(11)) + "]\n", {"MBSIM_MAX_ITEMS": "10"}),
    ("a: {" + ", ".join(f"k{i}" for i in range(11)) + "}\n", {"MBSIM_MAX_ITEMS": "10"}),
    ("a: [" + ", ".join(str(i) for i in range(60)) + "]\n", {"MBSIM_MAX_NODES": "50"}),
    ("a: [?, ?, ?, ?, ?, ?, ?, ?]\n", {"MBSIM_MAX_NODES": "20"}),
    ("a: 1\nb: 2\nc: x\n", {"MBSIM_MAX_DECK_BYTES": "10"}),
    # small enough for the screen to pass, at and around the lowered limits
    ("a: " + "[" * 20 + "]" * 20 + "\n", {"MBSIM_MAX_DEPTH": "21"}),
    ("a: " + "[" * 20 + "]" * 20 + "\n", {"MBSIM_MAX_DEPTH": "22"}),
    ("a: " + "[" * 20 + "]" * 20 + "\n", {"MBSIM_MAX_DEPTH": "20"}),
    ("- " * 10 + "a\n", {"MBSIM_MAX_DEPTH": "20"}),
    ("- " * 10 + "a\n", {"MBSIM_MAX_DEPTH": "10"}),
    (_block_nest(10), {"MBSIM_MAX_DEPTH": "22"}),
    ("a: [" + ", ".join(str(i) for i in range(10)) + "]\n", {"MBSIM_MAX_ITEMS": "12"}),
    ("a: [" + ", ".join(str(i) for i in range(10)) + "]\n", {"MBSIM_MAX_NODES": "60"}),
]


@pytest.mark.parametrize("text, env", CASES)
def test_screen_never_passes_text_the_walk_refuses(text, env, monkeypatch):
    for key, value in env.items():
        monkeypatch.setenv(key, value)
    refused = tree._over_limit(text) is not None
    if tree._within_limits(text):
        assert not refused
        assert tree.compose(text, "deck.yaml") is not None
    if refused:  # compose refuses it with the walk's message whatever the screen said
        with pytest.raises(DeckError, match="MBSIM_MAX_"):
            tree.compose(text, "deck.yaml")


@pytest.mark.parametrize("levels", [63, 64, 70])
def test_depth_hidden_by_brackets_in_comments_is_judged_as_the_walk_judges_it(levels):
    # each level's ']' sits in a comment, so the screen's bracket count sees depth 1; the
    # composed tree's own depth check gives the walk's verdict (the mapping and 63 lists
    # are the most the default limit of 64 allows)
    text = "a: " + "[\n#]\n" * levels + "1" + "]" * levels + "\n"
    assert tree._within_limits(text)
    if tree._over_limit(text) is None:
        assert levels == 63
        assert tree.compose(text, "deck.yaml") is not None
    else:
        with pytest.raises(DeckError, match="MBSIM_MAX_DEPTH"):
            tree.compose(text, "deck.yaml")


def test_screen_lets_through_few_enough_brackets_for_the_composer():
    # the composer recurses once per flow level: more brackets than the screen allows go to
    # the walk even when comments hide their depth
    text = "a: " + "[\n#]\n" * (tree._SCREEN_BRACKETS + 1) + "1" + "]" * 2001 + "\n"
    assert not tree._within_limits(text)
