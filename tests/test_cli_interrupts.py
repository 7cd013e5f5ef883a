"""Issue 23, command-line hunt: Ctrl-C and SIGTERM at any point of `mbsim run` end in one
``error:`` line and exit 1, and whatever the run computed is kept.  The signals are sent to
this process from inside the command (the command runs in-process under CliRunner, in the
main thread, where it installs its handlers), at the point under test."""

from __future__ import annotations

import os
import signal
from pathlib import Path

import pytest

from mbsim.output import read_result
from tests.test_hardening import cli, one_error

ROOT = Path(__file__).resolve().parents[1]
SLIDER = ROOT / "models" / "slider_crank.yaml"
FREE = ("run", SLIDER, "--scene", "free", "--mode", "dynamic", "--t-end", "0.05")


def test_sigterm_while_the_deck_loads_is_one_interrupt_line(tmp_path, monkeypatch):
    """SIGTERM before the run's own handlers (modules, deck) killed the command silently,
    exit -15 (143 in a shell); now it is Ctrl-C's line and exit 1, and SIGTERM's action is
    given back afterwards."""
    import mbsim.cli

    load = mbsim.cli._load

    def load_then_term(*args, **kwargs):
        os.kill(os.getpid(), signal.SIGTERM)
        return load(*args, **kwargs)

    monkeypatch.setattr(mbsim.cli, "_load", load_then_term)
    before = signal.getsignal(signal.SIGTERM)
    one_error(cli(*FREE, "-o", tmp_path / "x.h5"), 1, "interrupted")
    assert not (tmp_path / "x.h5").exists()  # nothing had run
    assert signal.getsignal(signal.SIGTERM) == before


def test_interrupt_during_the_error_estimate_exits_1_keeping_the_complete_run(
        tmp_path, monkeypatch):
    """Ctrl-C while the estimate's companion ran: the companion stops, the run (complete to
    t_end) is written without an estimate, and the command said so with exit 0, as if it
    had not been interrupted; now exit 1 and a line that says what is kept."""
    import mbsim.analyses.estimate as est

    coarse = est.coarse_estimate

    def interrupted_companion(*args, **kwargs):
        try:
            os.kill(os.getpid(), signal.SIGINT)  # as the companion's loop takes it
            return coarse(*args, **kwargs)
        except KeyboardInterrupt:
            return est.INTERRUPTED, "the companion run was interrupted (Ctrl-C) before it finished"

    monkeypatch.setattr(est, "coarse_estimate", interrupted_companion)
    out = tmp_path / "x.h5"
    one_error(cli(*FREE, "-o", out), 1, "interrupted", "after the run reached its end",
              "complete, without an error estimate")
    res = read_result(out)
    assert res.complete and res.t[-1] == pytest.approx(0.05, abs=1e-12)


@pytest.mark.parametrize("part, said", [
    ("estimate", "complete, without an error estimate"),
    ("build_result", "complete"),
])
def test_interrupt_after_the_integration_keeps_its_outputs(tmp_path, monkeypatch, part, said):
    """A Ctrl-C after the run reached t_end, in the error estimate outside its companion's
    own handling or in building the result (its first attempt): the run's outputs are kept,
    complete (without an estimate where the estimate was interrupted), and the command says
    so (exit 1)."""
    import mbsim.analyses.dynamic as dyn

    original, calls = getattr(dyn, part), []

    def interrupted(*args, **kwargs):
        calls.append(1)
        if len(calls) == 1:
            os.kill(os.getpid(), signal.SIGINT)  # lands outside the analysis' own tries
        return original(*args, **kwargs)

    monkeypatch.setattr(dyn, part, interrupted)
    out = tmp_path / "x.h5"
    one_error(cli(*FREE, "-o", out), 1, "interrupted", "after the run reached its end", said)
    res = read_result(out)
    assert res.complete and res.t[-1] == pytest.approx(0.05, abs=1e-12)
