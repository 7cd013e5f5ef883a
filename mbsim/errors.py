"""Exceptions that say where: deck errors name file, key path and line; analysis
errors name the model items (joints, bodies) involved, never bare matrix rows."""

from __future__ import annotations

from dataclasses import dataclass

QUOTE_LIMIT = 80  # characters of user text quoted in a message (a 1 MB name is not echoed)


def quote(text: object, limit: int = QUOTE_LIMIT) -> str:
    """``repr`` of user text, cut to about ``limit`` characters: 'abc...' (+1234 characters)."""
    text = str(text)
    if len(text) <= limit:
        return repr(text)
    return f"{text[:limit]!r}... (+{len(text) - limit} characters)"


@dataclass(frozen=True)
class Where:
    """A place in a deck: file, dotted key path (``joints.REV2.points.ball1.Q``), line."""

    file: str = "<deck>"
    path: str = ""
    line: int | None = None

    def child(self, key: str | int, line: int | None = None) -> Where:
        key = f"[{key}]" if isinstance(key, int) else str(key)
        if self.path and not key.startswith("["):
            path = f"{self.path}.{key}"
        else:
            path = f"{self.path}{key}"
        return Where(self.file, path, line if line is not None else self.line)

    def __str__(self) -> str:
        loc = self.file if self.line is None else f"{self.file}:{self.line}"
        return f"{loc}: {self.path}" if self.path else loc


class MbsimError(Exception):
    """Base of every error mbsim raises on purpose; the CLI prints these as one line."""

    exit_code = 1


class DeckError(MbsimError):
    """Bad input: the deck (or a --set override) cannot be turned into a model."""

    exit_code = 2

    def __init__(self, message: str, where: Where | None = None):
        self.message = message
        self.where = where or Where()
        super().__init__(f"{self.where}: {message}")


class UsageError(MbsimError):
    """A bad command-line request that is not about a deck: a missing results file, an
    unknown channel, an option out of range.  Printed without a deck location."""

    exit_code = 2


class ExpressionError(MbsimError):
    """A formula in a deck that does not parse or uses something not allowed."""

    exit_code = 2

    def __init__(self, message: str, text: str = "", column: int | None = None):
        self.message = message
        self.text = text
        self.column = column
        col = f" (column {column})" if column is not None else ""
        super().__init__(f"{message}{col} in {quote(text)}" if text else message)


class ModelError(MbsimError):
    """A deck that parses but describes an unusable model (e.g. redundant constraints)."""

    exit_code = 2

    def __init__(self, message: str, items: tuple[str, ...] = ()):
        self.items = tuple(items)
        super().__init__(message)


class AnalysisError(MbsimError):
    """A numerical failure during an analysis: names time and model items."""

    exit_code = 1

    def __init__(self, message: str, time: float | None = None, items: tuple[str, ...] = ()):
        self.time = time
        self.items = tuple(items)
        where = f"t = {time:.6g} s: " if time is not None else ""
        super().__init__(f"{where}{message}")


class ConvergenceError(AnalysisError):
    """Newton iteration that did not converge (names the worst constraints)."""


class SingularJacobianError(AnalysisError):
    """Rank-deficient constraint Jacobian (names the constraints involved)."""
