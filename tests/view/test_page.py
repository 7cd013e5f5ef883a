"""``mbsim view``: the page is self-contained (no server, no network), holds every case's
data, and the command fails in one line on bad input."""

import base64
import json
import re
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from mbsim.cli import main
from mbsim.view.page import build_page, natural_key

MODELS = Path(__file__).resolve().parents[2] / "models"


def run(*args):
    return CliRunner().invoke(main, [str(a) for a in args])


def page_data(html: str) -> dict:
    m = re.search(r'<script id="mbsim-data" type="application/json">(.*?)</script>', html, re.S)
    return json.loads(m.group(1))


def f32(b64: str) -> np.ndarray:
    return np.frombuffer(base64.b64decode(b64), "<f4")


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    """Slider-crank kinematic runs of three crank speeds, as a sweep folder would hold."""
    d = tmp_path_factory.mktemp("sweep")
    for w in (10, 200, 50):
        res = run("run", MODELS / "slider_crank.yaml", "--mode", "kinematic", "--t-end", "0.1",
                  "--set", f"parameters.omega=-{w}", "-o", d / f"w{w}.h5")
        assert res.exit_code == 0, res.output
    return d


def test_page_is_self_contained(runs):
    html = build_page([runs / "w10.h5"])
    assert not re.search(r"<(script|link|img|iframe)[^>]+(src|href)=", html, re.I)
    viewer = (Path(__file__).resolve().parents[2] / "mbsim" / "view" / "viewer.js").read_text()
    for call in ("fetch(", "XMLHttpRequest", "import(", "http"):
        assert call not in viewer
    assert html.count("<script") == 3  # three.js, the data, the viewer
    data = page_data(html)
    (case,) = data["cases"]
    assert case["nt"] == 21 and case["mode"] == "kinematic"
    slider = next(b for b in case["bodies"] if b["name"] == "slider")
    assert f32(slider["r"]).reshape(-1, 3).shape == (21, 3)
    assert "v" in slider and "f" in slider  # its shape's triangles


def test_channels_keep_their_digits_through_float32(runs):
    """Channels travel as float32 deviations from their mean: 7 digits of the variation."""
    from mbsim.output import read_result

    case = page_data(build_page([runs / "w10.h5"]))["cases"][0]
    ch = next(c for c in case["channels"] if c["name"] == "bodies/slider/r")
    got = f32(ch["data"]).reshape(-1, 3) + np.array(ch["offset"])
    want = read_result(runs / "w10.h5").channels["bodies/slider/r"].data
    span = np.ptp(want, axis=0).max()
    assert np.abs(got - want).max() <= 1e-6 * span


def test_a_folder_of_runs_gives_cases_in_numeric_order(runs):
    labels = [c["label"] for c in page_data(build_page([runs]))["cases"]]
    assert labels == ["w10", "w50", "w200"]
    assert sorted(["k10", "k200", "k50"], key=natural_key) == ["k10", "k50", "k200"]


def test_linear_modes_become_cases_that_oscillate(tmp_path):
    out = tmp_path / "lin.h5"
    res = run("run", MODELS / "governor.yaml", "--mode", "linear", "-o", out)
    assert res.exit_code == 0, res.output
    (case,) = page_data(build_page([out]))["cases"]  # one oscillating pair, 2 neutral modes
    assert "mode 3" in case["label"] and "Hz" in case["label"]
    ball = next(b for b in case["bodies"] if b["name"] == "ball1")
    r = f32(ball["r"]).reshape(-1, 3)
    assert np.ptp(r, axis=0).max() > 1e-3  # it moves
    np.testing.assert_allclose(r[0], r[-1], atol=1e-6)  # one full period


def test_view_command_writes_the_page(runs, tmp_path):
    out = tmp_path / "v.html"
    res = run("view", runs / "w10.h5", runs / "w50.h5", "-o", out)
    assert res.exit_code == 0, res.output
    assert res.output.startswith(f"view -> {out}")
    assert len(page_data(out.read_text())["cases"]) == 2


@pytest.mark.parametrize("args, words", [
    (["{runs}/w10.h5", "-o", "{tmp}/no/folder/v.html"], "does not exist"),
    (["{tmp}/missing.h5"], "no such file"),
    (["{deck}"], "not an HDF5 file"),
    (["{tmp}"], "no result files"),
])  # fmt: skip
def test_view_command_bad_input_is_one_error_line(runs, tmp_path, args, words):
    args = [a.format(runs=runs, tmp=tmp_path, deck=MODELS / "governor.yaml") for a in args]
    res = run("view", *args)
    assert res.exit_code == 2, res.output
    lines = res.output.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error:") and words in lines[0]
