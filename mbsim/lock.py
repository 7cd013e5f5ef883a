"""One writer per output: a lock file beside a results file or inside a sweep's folder.

``mbsim run -o gov.h5`` holds ``gov.h5.lock`` from before its analysis until its file is
written; ``mbsim sweep -o DIR`` holds ``DIR/sweep.lock`` while its cases run.  A second
writer of the same output is refused (:class:`LockedError`, exit 2) with a message naming
the holder: process id, host, start time and command, all read from the lock file (one line
of JSON, written before the file is visible under its name, so a reader never sees half of
it).

The lock is released when the holder ends: normally, on an error, on Ctrl-C or SIGTERM (a
``with`` block).  A holder killed outright (``kill -9``, a crash) leaves its file behind; a
lock whose process no longer runs on this host is *stale* and is taken over with a warning
(the take-over is an atomic rename, so of two processes that find the same stale lock one
wins and the other is refused).  A lock from another host (a shared file system) cannot be
checked and is never taken over: the message says which file to delete when that run is gone.
"""

from __future__ import annotations

import json
import os
import socket
import sys
from datetime import datetime, timezone
from pathlib import Path

from mbsim.errors import UsageError


class LockedError(UsageError):
    """The output is being written by another process (exit 2)."""


def lock_path(output: str | Path) -> Path:
    """The lock file of a results file: ``<file>.lock`` beside it."""
    output = Path(output)
    return output.with_name(output.name + ".lock")


def _alive(pid: int) -> bool:
    """Does process ``pid`` run on this host?"""
    if pid <= 0:
        return False
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # someone else's process: it runs
        return True
    except OSError:
        return False
    return True


def _holder(path: Path) -> dict | None:
    """The lock file's record, None when it is gone or unreadable."""
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    return data if isinstance(data, dict) else None


def describe_holder(holder: dict | None) -> str:
    if not holder:
        return "another process (its lock file cannot be read)"
    return (
        f"process {holder.get('pid', '?')} on host {holder.get('host', '?')} since "
        f"{holder.get('started', '?')} ({holder.get('command', 'mbsim')})"
    )


class OutputLock:
    """``with OutputLock(path, what): ...`` holds the lock file ``path`` for the block.

    ``what`` names the output in messages (``output gov.h5``); ``warnings`` collects the
    take-over of a stale lock, for the caller to print.
    """

    def __init__(self, path: str | Path, what: str, command: str | None = None):
        self.path = Path(path)
        self.what = what
        self.command = command or " ".join(["mbsim", *sys.argv[1:3]])[:200]
        self.warnings: list[str] = []
        self.record: dict | None = None

    def acquire(self) -> OutputLock:
        record = {"pid": os.getpid(), "host": socket.gethostname(),
                  "started": datetime.now(timezone.utc).isoformat(timespec="seconds"),
                  "command": self.command}  # fmt: skip
        text = json.dumps(record) + "\n"
        for _ in range(3):  # a stale lock taken over, then one more try
            tmp = self.path.with_name(f".{self.path.name}.new-{os.getpid()}")
            try:
                tmp.write_text(text, encoding="utf-8")
                try:
                    os.link(tmp, self.path)  # atomic, fails if the lock exists
                except FileExistsError:
                    raise
                except OSError:  # a file system without hard links: create it exclusively
                    fd = os.open(self.path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o644)
                    with os.fdopen(fd, "w", encoding="utf-8") as fh:
                        fh.write(text)
                finally:
                    tmp.unlink(missing_ok=True)
            except FileExistsError:
                self._take_over_if_stale()
                continue
            except OSError as exc:
                raise UsageError(
                    f"{self.what}: cannot create the lock file {self.path}: {exc.strerror or exc}"
                ) from None
            self.record = record
            return self
        raise LockedError(self._refusal(_holder(self.path)))

    def _refusal(self, holder: dict | None) -> str:
        other_host = holder is not None and holder.get("host") != socket.gethostname()
        gone = (
            "if that run is gone (it runs on another host, which mbsim cannot check), "
            if other_host
            else "if that run is gone, "
        )
        return (
            f"{self.what} is in use: written by {describe_holder(holder)}; wait for it "
            f"to finish or, {gone}delete {self.path}"
        )

    def _take_over_if_stale(self) -> None:
        """Remove the lock at ``path`` if its process no longer runs on this host; else
        raise LockedError naming the holder."""
        holder = _holder(self.path)
        if holder is None:
            if not self.path.exists():
                return  # released meanwhile: try again
            raise LockedError(self._refusal(None))
        pid = holder.get("pid")
        if holder.get("host") != socket.gethostname() or not isinstance(pid, int) or _alive(pid):
            raise LockedError(self._refusal(holder))
        stale = self.path.with_name(f".{self.path.name}.stale-{os.getpid()}")
        try:
            os.rename(self.path, stale)  # one of two processes that found it stale wins
        except FileNotFoundError:
            return
        if _holder(stale) != holder:  # replaced between reading and renaming: put it back
            os.rename(stale, self.path)
            raise LockedError(self._refusal(_holder(self.path)))
        stale.unlink(missing_ok=True)
        self.warnings.append(
            f"{self.what}: took over the lock {self.path} of "
            f"{describe_holder(holder)}, which no longer runs"
        )

    def release(self) -> None:
        """Remove the lock file if it is still this process's."""
        if self.record is None:
            return
        if _holder(self.path) == self.record:
            self.path.unlink(missing_ok=True)
        self.record = None

    def __enter__(self) -> OutputLock:
        return self.acquire()

    def __exit__(self, *exc) -> bool:
        self.release()
        return False
