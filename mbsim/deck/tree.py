"""YAML text -> a tree of :class:`Node` that remember their deck line; path edits.

PyYAML's loaders forget where a value came from and silently keep the last of two
equal keys.  Here the text is only *composed* (``yaml.compose``, safe tags) and the node
graph is turned into our own tree, so that every value knows its line and duplicate keys
are errors.  Scenes and ``--set`` overrides edit this tree (:func:`set_path`,
:func:`remove_path`) before validation, copy-on-write (:func:`cow`): the containers on the
edited paths are copied, the rest is shared with the tree as parsed; :func:`to_plain` gives
the plain ``raw`` tree.
"""

from __future__ import annotations

import difflib
import re
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import yaml

from mbsim.deck import limits
from mbsim.deck.schema import SCENE_KEYS, can_add
from mbsim.errors import DeckError, Where, quote

MERGE_TAG = "tag:yaml.org,2002:merge"
# Tags a list or mapping may carry: YAML's own (and none).  Anything else (`!!python/...`,
# `!!omap`, a local `!tag`) is refused rather than read as a plain list.
CONTAINER_TAGS = ("tag:yaml.org,2002:seq", "tag:yaml.org,2002:map")
# libyaml's parser when PyYAML has it: 15x faster on a 2.5 MB table (1.2 s instead of 20 s),
# same nodes and marks; the pure-Python one otherwise.
LOADER = getattr(yaml, "CSafeLoader", yaml.SafeLoader)


class _ComposeLoader(LOADER):  # type: ignore[misc, valid-type]
    """LOADER whose tag resolution (a Python call per scalar, through YAML 1.1's regexes)
    is remembered per (kind, text, implicit): a deck repeats its numbers and names (the
    governor's 900 scalars have 217 distinct texts), and the tag depends on nothing else
    (the safe loader has no path resolvers).  At most RESOLVED_KEPT texts are kept, each of
    at most RESOLVED_CHARS characters."""

    resolved: dict = {}

    def resolve(self, kind, value, implicit):
        key = (kind, value, implicit)
        tag = self.resolved.get(key)
        if tag is None:
            tag = super().resolve(kind, value, implicit)
            if len(self.resolved) < RESOLVED_KEPT and (value is None or
                                                       len(value) <= RESOLVED_CHARS):
                self.resolved[key] = tag
        return tag


RESOLVED_KEPT, RESOLVED_CHARS = 20_000, 100


@dataclass(eq=False, slots=True)
class Node:
    """One YAML value.

    kind: 'map' (value: dict[str, Node]), 'seq' (value: list[Node]) or 'scalar'
    (value: None, bool, int, float, str, or a datetime.date/datetime for an unquoted date,
    as YAML's safe loader reads it; `!!binary` is refused).  A date is a name or a text
    where one is expected (``name()``), and an error where a number is.
    """

    kind: str
    value: Any
    line: int | None = None  # 1-based deck line; None for values from --set
    text: str = ""  # scalars: the source text; names are read from it (`on`, `1` stay names)
    key_lines: dict[str, int | None] = field(default_factory=dict)  # maps: line of each key
    origin: str | None = None  # '--set' for values that did not come from the deck file

    def name(self) -> str | None:
        """The scalar as a name (plain `yes`, `1` give 'yes', '1'); None for non-scalars."""
        if self.kind != "scalar" or self.value is None:
            return None
        return self.value if isinstance(self.value, str) else self.text


def compose(text: str, file: str, origin: str | None = None) -> Node | None:
    """Parse YAML ``text`` into a Node tree (None for an empty document)."""
    try:
        # The limits are checked on the parser's event stream first (:func:`_over_limit`):
        # it stops at the first event past a limit, before anything is composed, so a 10^6-
        # point table or a 10^5-deep list costs a fraction of a second, and the message is
        # mbsim's own whatever the YAML library's version.
        over = None if _within_limits(text) else _over_limit(text)
        if over is not None:
            message, path, line = over
            raise DeckError(message, Where(file, path, line if origin is None else None))
        root = yaml.compose(text, Loader=_ComposeLoader)
    except RecursionError:  # pragma: no cover - the depth check comes first
        raise DeckError(limits.DEPTH.exceeded(), Where(file)) from None
    except yaml.MarkedYAMLError as exc:
        mark = exc.problem_mark or exc.context_mark
        what = exc.problem or ""
        if exc.context:  # 'while parsing a flow sequence (line 2, column 6)'
            cm = exc.context_mark
            at = f" (line {cm.line + 1}, column {cm.column + 1})" if cm is not None else ""
            what = f"{exc.context}{at}: {what}"
        line = mark.line + 1 if mark is not None and origin is None else None
        col = f" (line {mark.line + 1}, column {mark.column + 1})" if mark is not None else ""
        hint = _indent_hint(text, mark.line) if mark is not None and origin is None else ""
        raise DeckError(_one_line(f"not valid YAML: {what}{col}{hint}"),
                        Where(file, "", line)) from None
    except yaml.YAMLError as exc:  # ReaderError: control characters, bad encoding
        pos = getattr(exc, "position", None)
        line = text.count("\n", 0, pos) + 1 if pos is not None and origin is None else None
        reason = getattr(exc, "reason", None) or str(exc)
        char = getattr(exc, "character", None)
        bad = f" (character {char!r})" if char is not None else ""
        raise DeckError(_one_line(f"not a YAML text file: {reason}{bad}"),
                        Where(file, "", line)) from None
    if root is None:
        return None
    return _Converter(file, origin).convert(root, "")


def _indent_hint(text: str, row: int) -> str:
    """A block-structure error shows where YAML noticed it, usually one line after the
    mis-indented one: name both lines when their indentation differs."""
    lines = text.split("\n")
    if not 0 < row < len(lines):
        return ""
    prev = row - 1
    while prev > 0 and not lines[prev].strip():
        prev -= 1

    def indent(k: int) -> int:
        return len(lines[k]) - len(lines[k].lstrip(" "))

    if "\t" in lines[row][: indent(row) + 1] or "\t" in lines[prev][: indent(prev) + 1]:
        return "; YAML indents with spaces, not tabs"
    if indent(prev) == indent(row) or not lines[row].strip():
        return ""
    return (f"; check the indentation of lines {prev + 1} and {row + 1} ({indent(prev)} and "
            f"{indent(row)} spaces): keys of one mapping start in the same column")


# A block container's first entry starts at a line's indentation or after one of the compact
# indicators and node properties before it on that line (``- - a``, ``- ? a``, ``--- - a``,
# ``- &anchor key: v``): the ends of these groups are the columns block nesting can use.
_BLOCK_PREFIX = re.compile(r"^[ \t]*(?:(?:---|[-?:]|[&!][^ \t\n]*)[ \t]+)*", re.MULTILINE)
_PREFIX_GROUP = re.compile(r"(?:---|[-?:]|[&!][^ \t\n]*)[ \t]+")
_NOT_BRACKET = re.compile(r"[^\[\]{}]+")
# Flow brackets the screen lets through to the composer: libyaml's composer recurses in C,
# once per level (10^4 levels compose in 0.3 s, 10^5 overflow the stack), and brackets in
# comments or quotes may hide some of the depth from the screen.
_SCREEN_BRACKETS = 2000


def _within_limits(text: str) -> bool:
    """True when counts of characters prove ``text`` within the byte, depth, entry and value
    limits, so that composing it cannot cost more than its size; False when they do not
    (then :func:`_over_limit` walks the parser's events and finds the first place past one).

    Bounds, each from C-speed string operations (``str.count``, one regex over the lines):

    - entries of one list or mapping <= the ``,`` ``-`` ``:`` ``?`` in the text + 1 (a flow
      entry follows a comma or opens its collection, a block entry has its ``-``, ``:`` or
      ``?``);
    - values <= the characters + 3 per indicator ``-`` ``:`` ``?`` + the ``[`` ``{`` + 1 (a
      value is at least one character, an alias too, except an empty one after an indicator;
      a container is a bracket or has an indicator);
    - depth <= 2 C + B: block containers nest at columns that only grow, at most twice at one
      column (a list under a key at the key's column), and C counts the columns where one
      can start (the group ends of the lines' :data:`_BLOCK_PREFIX`, a line's indentation
      first); flow collections sit below block ones and nest at most B,
      the deepest running count of the brackets ``[ { ] }`` in the text.  Brackets inside
      quotes or comments may make B too small; that is safe because the composed tree's
      depth is checked again (:class:`_Converter`) and at most :data:`_SCREEN_BRACKETS`
      brackets are let through.
    """
    n = len(text)
    if n > limits.DECK_BYTES.value:
        return False
    colons, dashes, marks = text.count(":"), text.count("-"), text.count("?")
    if text.count(",") + colons + dashes + marks + 1 > limits.ITEMS.value:
        return False
    brackets = _NOT_BRACKET.sub("", text)
    opens = brackets.count("[") + brackets.count("{")
    values = n + 3 * (colons + dashes + marks) + opens + 1
    if opens > _SCREEN_BRACKETS or values > limits.NODES.value:
        return False
    flow = depth = 0
    for c in brackets:
        depth = depth + 1 if c in "[{" else max(0, depth - 1)
        flow = max(flow, depth)
    columns: set[int] = set()
    for prefix in set(_BLOCK_PREFIX.findall(text)):  # a few dozen distinct prefixes
        indent = len(prefix) - len(prefix.lstrip(" \t"))
        columns.add(indent)
        columns.update(m.end() for m in _PREFIX_GROUP.finditer(prefix, indent))
    return 2 * len(columns) + flow <= limits.DEPTH.value


def _over_limit(text: str) -> tuple[str, str, int | None] | None:
    """(message, key path, line) of the first place ``text`` goes past a limit of
    :mod:`mbsim.deck.limits` (bytes, nesting depth, entries of one list or mapping, values
    in all), else None.

    Walks the parser's events, one at a time, and stops at the first one past a limit: no
    node is built and nothing recurses, so the cost is that of the events up to there
    (about 1 us each with libyaml) and the memory that of the text.  A YAML syntax error
    is left for the composer to report with its line and column.
    """
    if len(text) > limits.DECK_BYTES.value:  # deck text not read from a file, --set values
        return limits.DECK_BYTES.exceeded(len(text)), "", None
    max_depth, max_items, max_nodes = limits.DEPTH.value, limits.ITEMS.value, limits.NODES.value
    start = (yaml.SequenceStartEvent, yaml.MappingStartEvent)
    end = (yaml.SequenceEndEvent, yaml.MappingEndEvent)
    value = (yaml.ScalarEvent, yaml.AliasEvent)
    # the open containers, innermost last: [events so far, events per entry (2 for a
    # mapping: key and value), line, key path, the mapping's last key]
    open_: list[list] = []
    nodes = 0
    parser = LOADER(text)
    try:
        while parser.check_event():
            event = parser.get_event()
            if isinstance(event, end):
                open_.pop()
                continue
            is_start = isinstance(event, start)
            if not (is_start or isinstance(event, value)):
                continue  # stream and document events
            nodes += 1
            path = ""
            if open_:
                top = open_[-1]
                if top[1] == 2 and top[0] % 2 == 0:  # a key of a mapping
                    top[4] = event.value if isinstance(event, yaml.ScalarEvent) else "?"
                if is_start or nodes > max_nodes:
                    path = (_join_key(top[3], top[4]) if top[1] == 2
                            else f"{top[3]}[{top[0]}]")  # fmt: skip
                top[0] += 1
                if top[0] > max_items * top[1]:
                    return limits.ITEMS.exceeded(), top[3], top[2]
            if nodes > max_nodes:
                return limits.NODES.exceeded(), path, event.start_mark.line + 1
            if is_start:
                if len(open_) >= max_depth:
                    return limits.DEPTH.exceeded(), path, event.start_mark.line + 1
                per = 2 if isinstance(event, yaml.MappingStartEvent) else 1
                open_.append([0, per, event.start_mark.line + 1, path, ""])
    except yaml.YAMLError:
        # PyYAML >= 6.0.4 refuses deep flow nesting (`[[[...`) in its scanner, which reads a
        # flow collection ahead before it yields the events above: count the brackets.
        line = _flow_too_deep(text, max_depth)
        return None if line is None else (limits.DEPTH.exceeded(), "", line)
    finally:
        parser.dispose()
    return None


def _join_key(path: str, key: str) -> str:
    key = key if len(key) <= 40 else key[:40] + "..."
    return f"{path}.{key}" if path else key


_FLOW_CHARS = re.compile(r"[\[\]{}\"'#]")


def _flow_too_deep(text: str, limit: int) -> int | None:
    """Line where flow brackets ``[ {`` open deeper than ``limit``, else None.

    A scan of the text, not of YAML's events (only called when the parser refused the text):
    quoted scalars and comments are skipped; a quote counts as one only where a scalar can
    start (after ``[ { , : -`` or at the start of a line), so ``[don't]`` is a plain word.
    """
    depth, pos, n = 0, 0, len(text)
    while True:
        m = _FLOW_CHARS.search(text, pos)
        if m is None:
            return None
        c, k = m.group(), m.start()
        pos = k + 1
        if c in "[{":
            depth += 1
            if depth > limit:
                return text.count("\n", 0, k) + 1
        elif c in "]}":
            depth = max(0, depth - 1)
        elif c == "#":
            if k == 0 or text[k - 1] in " \t\n":
                pos = text.find("\n", k)
                if pos < 0:
                    return None
        else:  # a quote
            j = k - 1
            while j >= 0 and text[j] in " \t":
                j -= 1
            if j >= 0 and text[j] not in "[{,:-\n":
                continue  # inside a plain scalar
            end = k
            while True:
                end = text.find(c, end + 1)
                if end < 0:
                    return None
                if c == "'" and end + 1 < n and text[end + 1] == "'":
                    end += 1  # '' inside single quotes
                    continue
                if c == '"':
                    b = end - 1
                    while text[b] == "\\":
                        b -= 1
                    if (end - 1 - b) % 2:  # an odd number of backslashes escapes it
                        continue
                break
            pos = end + 1


_STR_TAG, _INT_TAG, _FLOAT_TAG = ("tag:yaml.org,2002:str", "tag:yaml.org,2002:int",
                                  "tag:yaml.org,2002:float")
# numbers that int()/float() read exactly as YAML 1.1 does (no 0x, 0o17, 1_000, 1:30, .inf)
_PLAIN_INT = re.compile(r"-?(?:0|[1-9][0-9]*)")
MAX_INT_DIGITS = 300  # digits of a deck integer kept exact: any count or index, and below 1e308
_PLAIN_FLOAT = re.compile(r"-?(?:[0-9]+\.[0-9]*|\.[0-9]+)(?:[eE][-+][0-9]+)?")


class _Converter:
    def __init__(self, file: str, origin: str | None):
        self.file = file
        self.origin = origin
        self.constructor = yaml.constructor.SafeConstructor()
        self.done: dict[int, Node] = {}  # aliases share one Node (no exponential blow-up)
        self.active: set[int] = set()
        # read once per deck (an environment lookup per node costs seconds on 10^5 nodes)
        self.max_depth, self.max_items = limits.DEPTH.value, limits.ITEMS.value
        self.max_name = limits.NAME_CHARS.value

    def line(self, ynode: yaml.Node) -> int | None:
        return None if self.origin else ynode.start_mark.line + 1

    def fail(self, ynode: yaml.Node, message: str, path: str = "") -> DeckError:
        return DeckError(message, Where(self.file, path, self.line(ynode)))

    def scalar(self, ynode: yaml.ScalarNode, path: str, index: int | None = None) -> Node:
        """A scalar as YAML's safe loader reads it; plain strings and decimal numbers
        directly (a 10^5-point table is mostly these), the rest through the constructor.
        ``index``: the item number in the list at ``path`` (for the message only)."""
        tag, text = ynode.tag, ynode.value
        if tag == _STR_TAG:
            value = text
        elif tag == _INT_TAG and _PLAIN_INT.fullmatch(text):
            # an integer past float's range (~309 digits) is read as the float it overflows
            # to, inf, which the field's check refuses like 1e400 (int() raised OverflowError
            # where a float was needed, ValueError past 4300 digits)
            value = int(text) if len(text) <= MAX_INT_DIGITS else float(text)
        elif tag == _FLOAT_TAG and _PLAIN_FLOAT.fullmatch(text):
            value = float(text)
        else:
            where = path if index is None else f"{path}[{index}]"
            try:
                value = self.constructor.construct_object(ynode)
            except (yaml.YAMLError, ValueError, OverflowError):  # ValueError: a bad !!timestamp
                raise self.fail(ynode, f"unsupported YAML tag {quote(tag)}", where) from None
            if isinstance(value, bytes):  # `!!binary`: no field of a deck holds bytes
                raise self.fail(ynode, f"unsupported YAML tag {quote(tag)}", where)
        line = None if self.origin else ynode.start_mark.line + 1
        return Node("scalar", value, line, text, origin=self.origin)

    def convert(self, ynode: yaml.Node, path: str, depth: int = 0) -> Node:
        if type(ynode) is yaml.ScalarNode:  # shared by aliases or not, a scalar is a value
            return self.scalar(ynode, path)
        key = id(ynode)
        if key in self.done:
            return self.done[key]
        if key in self.active:
            raise self.fail(ynode, "recursive YAML alias")
        if depth >= self.max_depth:  # as _over_limit: a container at depth max_depth is too deep
            raise self.fail(ynode, limits.DEPTH.exceeded(), path)
        if not isinstance(ynode, yaml.ScalarNode):
            if ynode.tag not in CONTAINER_TAGS:
                raise self.fail(ynode, f"unsupported YAML tag {quote(ynode.tag)}", path)
            if len(ynode.value) > self.max_items:
                raise self.fail(ynode, limits.ITEMS.exceeded(len(ynode.value)))
        self.active.add(key)
        if isinstance(ynode, yaml.MappingNode):
            node = self.mapping(ynode, path, depth)
        else:
            scalar, convert, sn = self.scalar, self.convert, yaml.ScalarNode
            items = [scalar(v, path, i) if type(v) is sn else convert(v, f"{path}[{i}]", depth + 1)
                     for i, v in enumerate(ynode.value)]  # fmt: skip
            node = Node("seq", items, self.line(ynode))
        node.origin = self.origin
        self.active.discard(key)
        self.done[key] = node
        return node

    def mapping(self, ynode: yaml.MappingNode, path: str, depth: int = 0) -> Node:
        node = Node("map", {}, self.line(ynode))
        merged: list[Node] = []
        for knode, vnode in ynode.value:
            if knode.tag == MERGE_TAG:  # `<<: *defaults`: keys not given here are merged in
                sources = vnode.value if isinstance(vnode, yaml.SequenceNode) else [vnode]
                merged += [self.convert(s, path, depth + 1) for s in sources]
                continue
            if not isinstance(knode, yaml.ScalarNode):
                raise self.fail(knode, "a mapping key must be a plain name, not a list or mapping")
            name = knode.value
            if len(name) > self.max_name:
                raise self.fail(knode, f"key {quote(name, 40)}: "
                                f"{limits.NAME_CHARS.exceeded(len(name))}")
            here = f"{path}.{name}" if path else name
            if name in node.value:
                first = node.key_lines[name]
                raise DeckError(
                    f"duplicate key {quote(name)} (first given on line {first})",
                    Where(self.file, here, self.line(knode)),
                )
            node.value[name] = self.convert(vnode, here, depth + 1)
            node.key_lines[name] = self.line(knode)
        for source in merged:
            if source.kind != "map":
                raise self.fail(ynode, "`<<` must merge a mapping")
            for name, child in source.value.items():
                if name not in node.value:
                    node.value[name] = child
                    node.key_lines[name] = source.key_lines.get(name)
        return node


def _one_line(text: str) -> str:
    return " ".join(text.split())


def to_plain(node: Node | None) -> Any:
    """The tree as plain dicts, lists and scalars (the ``raw`` of a DeckSpec)."""
    if node is None:
        return None
    if node.kind == "map":
        return {k: to_plain(v) for k, v in node.value.items()}
    if node.kind == "seq":
        return [to_plain(v) for v in node.value]
    return node.value


def cow(node: Node) -> Node:
    """A shallow copy of a map or list node, to be edited without touching ``node``.

    Copy-on-write: :func:`set_path` and :func:`remove_path` copy every container below the
    one they are given on the way to the key they change, so ``cow(root)`` is all a
    scene, a ``--set`` or a study case needs to edit a deck tree that stays as parsed
    (:class:`mbsim.deck.loader.ParsedDeck`); the untouched branches stay shared.
    """
    return Node(node.kind, type(node.value)(node.value), node.line, node.text,
                dict(node.key_lines), node.origin)  # fmt: skip


def from_value(value: Any, file: str, path: str, origin: str = "--set") -> Node:
    """A --set VALUE (YAML scalar or flow text, or a Python value) as a Node."""
    if not isinstance(value, str):
        value = yaml.safe_dump(_pythonic(value), default_flow_style=True).strip()
        value = value.removesuffix("\n...")
    try:
        node = compose(value, file, origin=origin)
    except DeckError as exc:
        shown = value if len(value) <= 80 else value[:80] + f"... (+{len(value) - 80} characters)"
        raise DeckError(f"{origin} {path}={shown}: {exc.message}", Where(file, path)) from None
    return node if node is not None else Node("scalar", None, None, "", origin=origin)


def _pythonic(value: Any) -> Any:
    if hasattr(value, "tolist"):  # numpy arrays and scalars
        return value.tolist()
    if isinstance(value, (list, tuple)):
        return [_pythonic(v) for v in value]
    return value


class PathError(Exception):
    """A key path that does not lead anywhere; ``message`` says why (one line)."""

    def __init__(self, message: str):
        self.message = message
        super().__init__(message)


def split_path(path: str) -> list[str | int]:
    """'bodies.crank.r[1]' or 'bodies.crank.r.1' -> ['bodies', 'crank', 'r', 1]."""
    segs: list[str | int] = []
    for part in path.strip().split("."):
        m = re.fullmatch(r"([^\[\]]*)((?:\[\d+\])*)", part)
        if m is None or (not m.group(1) and not m.group(2)):
            raise PathError(f"bad key path {path!r}")
        if m.group(1):
            segs.append(int(m.group(1)) if m.group(1).isdigit() else m.group(1))
        segs += [int(i) for i in re.findall(r"\[(\d+)\]", m.group(2))]
    return segs


def join_path(segs: list[str | int]) -> str:
    out = ""
    for s in segs:
        out += f"[{s}]" if isinstance(s, int) else (f".{s}" if out else s)
    return out


def _step(node: Node, segs: list[str | int], i: int) -> tuple[str | int, int]:
    """Key into ``node`` for segs[i:], and how many segments it used (names may hold dots)."""
    seg = segs[i]
    if node.kind == "seq":
        if not isinstance(seg, int):
            raise PathError(f"{join_path(segs[:i])} is a list; expected an index, got {seg!r}")
        if not 0 <= seg < len(node.value):
            raise PathError(f"index {seg} is out of range (the list has {len(node.value)} items)")
        return seg, 1
    for n in range(len(segs) - i, 0, -1):  # longest match first: a body named 'arm.left'
        cand = ".".join(str(s) for s in segs[i : i + n])
        if cand in node.value:
            return cand, n
    return str(seg), 0


def _missing(node: Node, segs: list[str | int], i: int) -> PathError:
    here = segs[:i]
    keys = list(node.value)
    close = difflib.get_close_matches(str(segs[i]), keys, n=1)
    if close:
        return PathError(f"no such key; did you mean {join_path(here + [close[0]])}?")
    listed = ", ".join(keys[:12]) + (", ..." if len(keys) > 12 else "")
    where = join_path(here) or "the top level"
    return PathError(f"no such key; {where} has: {listed or 'nothing'}")


def _descend(root: Node, segs: list[str | int], can_add: Callable[[list], bool], create: bool):
    """Walk to the parent of the last key; copies containers on the way (aliases stay intact).

    Returns (parent, key); with ``create``, missing mappings on the way are made when
    ``can_add(path)`` allows them.
    """
    node, i = root, 0
    while True:
        if node.kind == "scalar":
            raise PathError(f"{join_path(segs[:i])} is a single value, not a mapping or list")
        key, used = _step(node, segs, i)
        if used == 0 and not (create and can_add(segs[: i + 1])):
            raise _missing(node, segs, i)
        used = used or 1
        if i + used == len(segs):
            return node, key
        child = node.value.get(key) if node.kind == "map" else node.value[key]
        if child is None:
            child = Node("map", {}, None, origin="--set")
        elif child.kind != "scalar":  # copy on descent: never edit a node shared by an alias
            child = cow(child)  # or by the parsed deck and its other variants
        if node.kind == "map" and key not in node.value:
            node.key_lines[key] = None
        node.value[key] = child
        node, i = child, i + used


def set_path(root: Node, path: str, value: Node, can_add: Callable[[list], bool]) -> None:
    """Replace the value at ``path`` (or add it where ``can_add(segments)`` allows)."""
    segs = split_path(path)
    parent, key = _descend(root, segs, can_add, create=True)
    parent.value[key] = value
    if parent.kind == "map":
        parent.key_lines[key] = value.line


def remove_path(root: Node, path: str) -> None:
    """Delete the key or list item at ``path``."""
    segs = split_path(path)
    parent, key = _descend(root, segs, lambda segs: False, create=False)
    del parent.value[key]
    if parent.kind == "map":
        parent.key_lines.pop(key, None)


# -- scenes and --set ----------------------------------------------------------------------------
def apply_override(root: Node, path: str, value: Any, file: str) -> None:
    """``--set PATH=VALUE``: VALUE is YAML text (``2000``, ``[1, 2, 3]``) or a Python value."""
    try:
        set_path(root, path, from_value(value, file, path), can_add)
    except PathError as exc:
        raise DeckError(f"cannot --set: {exc.message}", Where(file, path)) from None


def scene_names(root: Node) -> list[str]:
    scenes = root.value.get("scenes")
    return list(scenes.value) if scenes is not None and scenes.kind == "map" else []


def apply_scene(root: Node, name: str, file: str) -> None:
    """Apply ``scenes.<name>`` to the tree: ``remove`` paths, then ``set`` values, then merge
    its ``analysis`` settings (each as a set of ``analysis.<mode>.<key>``)."""
    known = scene_names(root)
    if name not in known:
        close = difflib.get_close_matches(name, known, n=1)
        hint = f"; did you mean {close[0]!r}?" if close else ""
        listed = ", ".join(known) or "the deck has none"
        raise DeckError(f"unknown scene {name!r}{hint} (scenes: {listed})",
                        Where(file, "scenes", root.key_lines.get("scenes")))  # fmt: skip
    scenes = root.value["scenes"]
    scene = _mapping(scenes.value[name], Where(file, f"scenes.{name}", scenes.key_lines[name]))
    for key in scene.value:
        if key not in SCENE_KEYS:
            close = difflib.get_close_matches(key, SCENE_KEYS, n=1)
            hint = f"; did you mean {close[0]!r}?" if close else f" (keys: {', '.join(SCENE_KEYS)})"
            w = Where(file, f"scenes.{name}.{key}", scene.key_lines[key])
            raise DeckError(f"unknown key {key!r} in a scene{hint}", w)
    here = f"scenes.{name}"
    if "remove" in scene.value:
        node = scene.value["remove"]
        for i, item in enumerate(node.value if node.kind == "seq" else [node]):
            w = Where(file, f"{here}.remove[{i}]", item.line)
            if not isinstance(item.value, str):
                raise DeckError("expected a key path such as bodies.rod", w)
            _edit(root, item.value, None, w, "remove")
    if "set" in scene.value:
        node = _mapping(scene.value["set"], Where(file, f"{here}.set", scene.key_lines["set"]))
        for key, item in node.value.items():
            _edit(root, key, item, Where(file, f"{here}.set.{key}", node.key_lines[key]), "set")
    if "analysis" in scene.value:
        w = Where(file, f"{here}.analysis", scene.key_lines["analysis"])
        for mode, settings in _mapping(scene.value["analysis"], w).value.items():
            mw = Where(file, f"{w.path}.{mode}", w.line)
            for key, item in _mapping(settings, mw).value.items():
                kw = Where(file, f"{mw.path}.{key}", settings.key_lines[key])
                _edit(root, f"analysis.{mode}.{key}", item, kw, "set")


def _mapping(node: Node, where: Where) -> Node:
    if node.kind != "map":
        raise DeckError("expected a mapping", where)
    return node


def _edit(root: Node, path: str, value: Node | None, where: Where, how: str) -> None:
    try:
        if value is None:
            remove_path(root, path)
        else:
            set_path(root, path, value, can_add)
    except PathError as exc:
        raise DeckError(f"cannot {how} {path}: {exc.message}", where) from None
