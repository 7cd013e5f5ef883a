"""Progress lines: on a terminal, carriage-return updates with ETA, rate-limited; elsewhere
nothing; the kinematic analysis calls the callback once per output step."""

import io
from pathlib import Path

import pytest
from click.testing import CliRunner

from mbsim.progress import Progress, format_duration, terminal_progress

MODELS = Path(__file__).resolve().parents[1] / "models"


class FakeTTY(io.StringIO):
    def isatty(self):
        return True


class FakeClock:
    def __init__(self):
        self.now = 100.0

    def __call__(self):
        return self.now


def drive(progress, clock, n=101, t_end=1.0, wall_per_step=0.01):
    """n output steps from t = 0 to t_end, `wall_per_step` s of (fake) wall time each."""
    for k in range(n):
        progress(k * t_end / (n - 1), t_end)
        clock.now += wall_per_step


def test_tty_updates_carry_eta_and_are_rate_limited():
    stream, clock = FakeTTY(), FakeClock()
    p = terminal_progress(stream, label="kinematic")
    assert isinstance(p, Progress) and p.tty
    p.clock = clock
    drive(p, clock)  # 1 s of wall time in 100 steps of 0.01 s
    text = stream.getvalue()
    assert text.startswith("\r") and "\n" not in text
    # at most one update per 0.2 s: 1 s of wall time gives at most 5
    assert 3 <= p.updates <= 5 and text.count("\r") == p.updates
    last = text.split("\r")[-1]
    assert "kinematic" in last and "ETA" in last and "steps/s" in last and "/ 1 s" in last
    assert "%" in last and "steps" in last
    p.close()
    assert stream.getvalue().endswith("\r") and stream.getvalue().split("\r")[-2].strip() == ""


def test_line_contents():
    """81 calls over t = 0 .. 0.8 s of 1 s in 0.8 s of wall time: 80 steps / 0.8 s = 100
    steps/s; ETA = 0.8 s x (1 - 0.8) / 0.8 = 0.2 s."""
    clock = FakeClock()
    p = Progress(FakeTTY(), label="kinematic", clock=clock)
    t0 = clock.now
    for k in range(81):
        clock.now = t0 + k / 100
        p(k / 100, 1.0)
    line = p.line(0.8, 1.0, t0 + 0.8)
    assert line == "kinematic  t = 0.8 / 1 s   80%  81 steps  100 steps/s  ETA 0:00"


def test_eta_of_a_slow_run():
    stream, clock = FakeTTY(), FakeClock()
    p = Progress(stream, label="dynamic", clock=clock)
    p(0.0, 10.0)
    clock.now += 30.0  # 1 simulated second in 30 s: 9 more take 270 s
    p(1.0, 10.0)
    assert stream.getvalue().rstrip().endswith("ETA 4:30")


def test_not_a_terminal_or_disabled_gives_nothing():
    stream = io.StringIO()
    assert terminal_progress(stream) is None
    assert terminal_progress(FakeTTY(), enabled=False) is None
    forced = terminal_progress(stream, enabled=True)
    assert forced is not None and not forced.tty  # forced onto a pipe: plain lines, rarely


def test_short_run_draws_nothing():
    stream, clock = FakeTTY(), FakeClock()
    p = Progress(stream, clock=clock)
    drive(p, clock, n=10, wall_per_step=0.001)  # 10 ms in all
    p.close()
    assert stream.getvalue() == ""


@pytest.mark.parametrize("seconds, text", [(0, "0:00"), (59.6, "1:00"), (3725, "1:02:05"),
                                           (float("nan"), "--:--"), (float("inf"), "--:--")])
def test_format_duration(seconds, text):
    assert format_duration(seconds) == text


def test_kinematic_calls_progress_once_per_output_step():
    from mbsim.api import load_model, run_model

    calls = []
    spec, model = load_model(MODELS / "slider_crank.yaml")
    res = run_model(model, "kinematic", {"t_end": 0.1, "progress": lambda t, te: calls.append(
        (t, te))}, deck=spec)
    assert len(calls) == len(res.t) == 21
    assert [c[0] for c in calls] == list(res.t) and {c[1] for c in calls} == {0.1}
    assert "progress" not in res.settings


def test_run_without_terminal_prints_no_progress(tmp_path):
    from mbsim.cli import main

    r = CliRunner().invoke(main, ["run", str(MODELS / "slider_crank.yaml"), "--mode",
                                  "kinematic", "--t-end", "0.05", "-o", str(tmp_path / "a.h5")])
    assert r.exit_code == 0, r.output
    assert "ETA" not in r.output and "\r" not in r.output


def run_on_terminal(*args, timeout=120):
    """`python -m mbsim ARGS` with standard error on a pseudo-terminal (what a user at a
    terminal sees) and standard output on a pipe: (exit code, stdout, stderr text)."""
    import os
    import subprocess
    import sys

    pty = pytest.importorskip("pty")  # POSIX
    master, slave = pty.openpty()
    proc = subprocess.Popen([sys.executable, "-m", "mbsim", *map(str, args)],
                            stdin=subprocess.DEVNULL, stdout=subprocess.PIPE, stderr=slave,
                            cwd=MODELS.parent)  # the mbsim of this tree
    os.close(slave)
    chunks = []
    try:
        while True:
            try:
                data = os.read(master, 4096)
            except OSError:  # EIO: the child closed the terminal (exited)
                break
            if not data:
                break
            chunks.append(data)
        out = proc.stdout.read().decode()
        proc.wait(timeout=timeout)
    finally:
        os.close(master)
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    return proc.returncode, out, b"".join(chunks).decode()


def test_progress_on_a_real_terminal(tmp_path):
    """A 100 s kinematic run (20001 output steps at about 0.1 ms each: about 2 s of wall
    time, far over the 0.2 s a line waits for): on a terminal the line is redrawn in place
    with time, steps, rate and ETA, then blanked; with -q the terminal gets nothing
    (--no-progress takes the same path; without a terminal:
    test_run_without_terminal_prints_no_progress)."""
    args = ["run", MODELS / "slider_crank.yaml", "--mode", "kinematic", "--t-end", "100"]
    code, out, err = run_on_terminal(*args, "-o", tmp_path / "a.h5")
    assert code == 0, (out, err)
    assert "kinematic: complete" in out and "ETA" not in out  # the summary is on stdout
    updates = [u for u in err.split("\r") if u.strip()]
    assert updates and "\n" not in err, repr(err)
    for u in updates:
        assert u.startswith("kinematic  t = ") and "/ 100 s" in u and "%" in u, u
        assert "steps" in u and "steps/s" in u and "ETA " in u, u
    assert err.endswith("\r") and err.split("\r")[-2].strip() == ""  # blanked at the end
    code, out, err = run_on_terminal(*args, "-o", tmp_path / "b.h5", "-q")
    assert code == 0 and out == err == "", (out, err)


def test_dynamic_calls_progress_once_per_output_step():
    from mbsim.api import load_model, run_model

    calls = []
    spec, model = load_model(MODELS / "governor.yaml")
    res = run_model(model, "dynamic", {"t_end": 0.1, "progress": lambda t, te: calls.append(
        (t, te))}, deck=spec)
    assert [c[0] for c in calls] == list(res.t) and {c[1] for c in calls} == {0.1}
    assert "progress" not in res.settings
