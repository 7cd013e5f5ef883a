"""Issue 23, command-line hunt: an output path never destroys a file the user keeps.  A
command whose output is one of its own inputs (the deck of ``run -o``, the results file of
``export --csv``), a file of the other kind (a deck under ``run -o``, a results file under
``export --csv``), ``-`` or an empty name is refused before any work: one ``error:`` line
naming the option, exit 2, and the file is unchanged."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest

from tests.test_hardening import cli, one_error

ROOT = Path(__file__).resolve().parents[1]
SLIDER = ROOT / "models" / "slider_crank.yaml"


@pytest.fixture(scope="module")
def results(tmp_path_factory):
    """A kinematic result of the slider-crank, 0.1 s."""
    folder = tmp_path_factory.mktemp("outputs")
    out = folder / "slider.h5"
    res = cli("run", SLIDER, "--mode", "kinematic", "--t-end", "0.1", "-o", out, "-q")
    assert res.exit_code == 0, res.stderr
    return out


def test_run_output_that_is_the_deck_is_refused_and_the_deck_kept(tmp_path):
    deck = tmp_path / "deck.yaml"
    shutil.copy(SLIDER, deck)
    text = deck.read_bytes()
    one_error(cli("run", deck, "--mode", "kinematic", "-o", deck), 2, "-o", "is the input file")
    assert deck.read_bytes() == text
    link = tmp_path / "link.h5"  # the same file under another name
    link.symlink_to(deck)
    one_error(cli("run", deck, "--mode", "kinematic", "-o", link), 2, "is the input file")
    assert deck.read_bytes() == text


def test_run_output_over_a_file_that_is_not_hdf5_is_refused(tmp_path):
    other = tmp_path / "notes.txt"
    other.write_text("keep me\n")
    one_error(cli("run", SLIDER, "--mode", "kinematic", "-o", other), 2, "not an HDF5 file")
    assert other.read_text() == "keep me\n"


@pytest.mark.parametrize("name", ["-", ""])
def test_run_output_dash_or_empty_is_a_usage_error(tmp_path, monkeypatch, name):
    monkeypatch.chdir(tmp_path)
    one_error(cli("run", SLIDER, "--mode", "kinematic", "-o", name), 2, "-o")
    assert list(tmp_path.iterdir()) == []


def test_run_output_over_an_earlier_result_or_an_empty_file_is_written(results, tmp_path):
    out = tmp_path / "again.h5"
    shutil.copy(results, out)
    assert cli("run", SLIDER, "--mode", "kinematic", "--t-end", "0.1", "-o", out,
               "-q").exit_code == 0
    empty = tmp_path / "empty.h5"
    empty.touch()
    assert cli("run", SLIDER, "--mode", "kinematic", "--t-end", "0.1", "-o", empty,
               "-q").exit_code == 0


@pytest.mark.parametrize("option", ["--csv", "--parquet"])
def test_export_over_its_own_results_file_is_refused(results, option):
    before = results.read_bytes()
    one_error(cli("export", results, option, results), 2, option, "is the input file")
    assert results.read_bytes() == before


def test_export_csv_over_another_results_file_or_dash_is_refused(results, tmp_path):
    other = tmp_path / "other.h5"
    shutil.copy(results, other)
    one_error(cli("export", results, "--csv", other), 2, "--csv", "is an HDF5 file")
    assert other.read_bytes() == results.read_bytes()
    one_error(cli("export", results, "--csv", "-"), 2, "--csv", "standard output")


def test_plot_data_and_view_over_their_input_are_refused(results):
    before = results.read_bytes()
    one_error(cli("plot", results, "bodies.crank.r", "-o", results.with_suffix(".png"),
                  "--data", results), 2, "--data", "is the input file")
    one_error(cli("view", results, "-o", results), 2, "-o", "is the input file")
    assert results.read_bytes() == before


@pytest.mark.parametrize("args, needle", [
    (["--dpi", "0"], "--dpi and --size"),        # was ZeroDivisionError in render.py
    (["--size", "0"], "--dpi and --size"),
    (["--size", "1e6"], "--dpi and --size"),     # was MemoryError drawing an 8e7-pixel frame
    (["--dpi", "nan"], "--dpi and --size"),
    (["--fps", "inf"], "--fps"),                 # was a GIF of 0 ms frames
    (["--fps", "nan"], "--fps"),
])
def test_animate_frame_options_out_of_range_are_usage_errors(results, tmp_path, args, needle):
    out = tmp_path / "a.gif"
    one_error(cli("animate", results, "-o", out, *args), 2, needle)
    assert not out.exists()


def test_animate_of_a_file_that_is_not_results_names_the_file(tmp_path):
    bad = tmp_path / "bad.h5"
    bad.write_bytes(b"\x89HDF\r\n\x1a\n" + b"\0" * 100)  # truncated: h5py's words before
    one_error(cli("animate", bad, "-o", tmp_path / "a.gif"), 2, f"{bad}: not an HDF5 file")


@pytest.mark.parametrize("mode", ["kinematic", "dynamic"])
def test_run_failing_before_its_first_output_replaces_the_file_marked_incomplete(
        results, tmp_path, mode):
    """A driver 1/t at t = 0: exit 1 wrote no file, so an earlier result of that name stayed
    and looked current.  Now the file is written with no output time, marked incomplete,
    with the error as its message, and it reads back with `export`."""
    from mbsim.output import read_result

    deck = tmp_path / "deck.yaml"
    deck.write_text(SLIDER.read_text().replace("function: pi/2 + omega*t",
                                               "function: pi/2 + omega*t + 1/t"))
    out = tmp_path / "out.h5"
    shutil.copy(results, out)  # the earlier, complete run
    one_error(cli("run", deck, "--mode", mode, "--t-end", "0.05", "-o", out), 1,
              "t = 0 s", "the function of driver crank is not finite", "marked incomplete")
    res = read_result(out)
    assert res.status == "incomplete" and len(res.t) == 0
    assert "the function of driver crank is not finite" in res.message
    assert cli("export", out, "--csv", tmp_path / "out.csv").exit_code == 0


def test_view_of_a_folder_skips_files_that_are_not_results_by_name(results, tmp_path):
    """A folder holding another program's HDF5 file: 'error: DIR: "Unable to synchronously
    open object (object 'time' doesn't exist)"', naming neither the file nor the problem."""
    import h5py

    folder = tmp_path / "cases"
    folder.mkdir()
    shutil.copy(results, folder / "k=1.h5")
    with h5py.File(folder / "other.h5", "w") as f:
        f["x"] = [1.0, 2.0]
    res = cli("view", folder, "-o", tmp_path / "v.html")
    assert res.exit_code == 0, res.stderr
    assert f"warning: skipping {folder / 'other.h5'}: an HDF5 file without mbsim results" \
        in res.stderr
    (folder / "k=1.h5").unlink()
    one_error(cli("view", folder, "-o", tmp_path / "w.html"), 2, "no result files",
              "other.h5: an HDF5 file without mbsim results")


@pytest.mark.parametrize("command", [
    ["run", SLIDER, "--mode", "kinematic", "--t-end", "0.05", "-o", "{name}.h5"],
    ["export", "{results}", "--csv", "{name}.csv"],
    ["plot", "{results}", "bodies.crank.r", "-o", "{name}.png"],
    ["animate", "{results}", "-o", "{name}.gif"],
])
def test_output_name_longer_than_the_file_system_takes_is_a_usage_error(results, tmp_path,
                                                                        command):
    """A 300-character file name: OSError ENAMETOOLONG traceback from pathlib's is_file."""
    name = str(tmp_path / ("a" * 300))
    args = [str(a).format(name=name, results=results) for a in command]
    one_error(cli(*args), 2, "File name too long")


@pytest.mark.parametrize("fps", ["0.001", "1e-300"])
def test_animate_fps_below_a_gif_frame_duration_is_a_usage_error(results, tmp_path, fps):
    """--fps 0.001: a frame of 1000 s overflowed the GIF's 16-bit duration (PIL traceback)."""
    one_error(cli("animate", results, "-o", tmp_path / "a.gif", "--fps", fps), 2, "--fps")


def test_mp4_writer_reports_an_ffmpeg_that_stops_instead_of_dying_of_sigpipe(tmp_path):
    """With SIGPIPE's default action (the command's) a write to an ffmpeg that had exited
    ended mbsim silently, exit -13; now an OSError with ffmpeg's message."""
    import subprocess
    import sys

    from mbsim.view.render import mp4_encoder

    if mp4_encoder() is None:
        pytest.skip("no MP4 encoder (imageio-ffmpeg or ffmpeg)")
    code = (
        "import signal; signal.signal(signal.SIGPIPE, signal.SIG_DFL)\n"
        "from pathlib import Path; from PIL import Image\n"
        "from mbsim.view.render import _write_mp4\n"
        "images = (Image.new('RGB', (64, 64)) for _ in range(200))\n"
        "try:\n"
        f"    _write_mp4(images, Path({str(tmp_path / 'no' / 'x.mp4')!r}), 20.0)\n"
        "except OSError as exc:\n"
        "    print('OSError', exc)\n")
    p = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                       timeout=120, cwd=ROOT)
    assert p.returncode == 0, (p.returncode, p.stderr)
    assert p.stdout.startswith("OSError ffmpeg failed"), p.stdout


@pytest.mark.parametrize("extra", [["--title", "$x^$"], ["--title", r"$\undefined$"],
                                   ["--label", r"$\frac$"]])
def test_plot_titles_and_labels_are_plain_text(results, tmp_path, extra):
    """'$x^$' ended the plot in matplotlib's math-text parser (exit 2 with a pyparsing
    message); a deck name with '$' did the same."""
    out = tmp_path / "p.png"
    res = cli("plot", results, "bodies.crank.r", "-o", out, *extra)
    assert res.exit_code == 0, res.stderr
    assert out.is_file()


@pytest.mark.parametrize("command", [["export", "{f}", "--csv", "{d}/x.csv"],
                                     ["plot", "{f}", "--list"], ["compare", "{f}", "{f}"],
                                     ["view", "{f}", "-o", "{d}/x.html"],
                                     ["animate", "{f}", "-o", "{d}/x.gif"]])
def test_an_hdf5_file_whose_time_is_a_group_is_not_a_results_file(tmp_path, command):
    """Another program's file with a /time group and a mode attribute: h5py's TypeError
    traceback in every reader."""
    import h5py

    f = tmp_path / "other.h5"
    with h5py.File(f, "w") as h:
        h.attrs["mode"] = "kinematic"
        h.create_group("time")
    args = [a.format(f=f, d=tmp_path) for a in command]
    one_error(cli(*args), 2, f"{f}: an HDF5 file without mbsim results")


def test_a_file_of_a_newer_layout_is_refused_not_misread(results, tmp_path):
    import h5py

    newer = tmp_path / "newer.h5"
    shutil.copy(results, newer)
    with h5py.File(newer, "a") as f:
        f.attrs["layout_version"] = 99
    one_error(cli("export", newer, "--csv", tmp_path / "x.csv"), 2, "layout 99",
              "update mbsim")
