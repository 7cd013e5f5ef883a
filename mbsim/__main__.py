"""`python -m mbsim ...` is the same as the `mbsim` command.

Ctrl-C or SIGTERM while the command's modules load (about 0.1 s: click, numpy) ends it with
the one line every interrupt gives, exit 1, not a traceback of the import; the command
itself then handles both (mbsim.cli)."""

import signal
import sys


def _interrupted(signum, frame):
    sys.stderr.write("error: interrupted\n")
    sys.exit(1)


_OLD = {sig: signal.signal(sig, _interrupted) for sig in (signal.SIGINT, signal.SIGTERM)}
from mbsim.cli import main  # noqa: E402  (after the handlers: the import is the window)

for _sig, _handler in _OLD.items():
    signal.signal(_sig, _handler)
main()
