"""The viewer page of the governor and the vehicle opened in a real headless Chromium
(mbsim.view.browser; installed by .ci/browser.sh): screenshots at two times must show a
drawing (not the blank background) and bodies that moved between them.

Skipped, with the reason, where no Chromium is found.
"""

from pathlib import Path

import numpy as np
import pytest

from mbsim.view.browser import dump_dom, find_chromium, screenshot

pytestmark = pytest.mark.skipif(find_chromium() is None,
                                reason="no Chromium on PATH (install it with .ci/browser.sh)")
MODELS = Path(__file__).resolve().parents[2] / "models"
VIEW = (slice(40, 690), slice(0, 770))  # rows, columns of the 3D view in a 1200 x 700 window


def _page(tmp_path, deck, options):
    from mbsim.api import load_model, run_model
    from mbsim.output import write_result
    from mbsim.view.page import write_page

    _spec, model = load_model(MODELS / deck)
    result = run_model(model, "dynamic", options, deck=_spec)
    assert result.complete, result.message
    h5 = write_result(result, tmp_path / f"{Path(deck).stem}.h5")
    return write_page([h5], tmp_path / f"{Path(deck).stem}.html"), result


def _pixels(png):
    from PIL import Image

    return np.asarray(Image.open(png).convert("RGB"), dtype=int)[VIEW]


def _bodies(img):
    """Mask of the 3D view's pixels that show a body or a marker: saturated (the shapes'
    colours, max - min channel > 40) or dark (tyres, joint outlines, max channel < 120); the
    background and the grey grid lines are neither."""
    return (img.max(axis=2) - img.min(axis=2) > 40) | (img.max(axis=2) < 120)


@pytest.mark.parametrize("deck, options, t1, fragment", [
    # the spindle turns at 11 rad/s: the balls swing round by 5.5 rad in 0.5 s
    ("governor.yaml", {"t_end": 0.5, "step": 0.01, "error_estimate": False}, 0.5, ""),
    # 24.6 m/s: the car drives 2.5 m in 0.1 s; the camera stays (follow=0)
    ("vehicle.yaml", {"t_end": 0.1, "step": 0.01, "error_estimate": False}, 0.1, "&follow=0"),
])  # fmt: skip
def test_viewer_page_draws_the_mechanism_and_moves_it(tmp_path, deck, options, t1, fragment):
    pytest.importorskip("PIL")
    page, result = _page(tmp_path, deck, options)
    a = _pixels(screenshot(page, tmp_path / "a.png", f"t=0{fragment}"))
    b = _pixels(screenshot(page, tmp_path / "b.png", f"t={t1}{fragment}"))
    for img in (a, b):
        assert _bodies(img).mean() > 0.005, "no bodies in the 3D view"
        assert len(np.unique(img.reshape(-1, 3), axis=0)) > 50, "no shaded bodies drawn"
    moved = float((_bodies(a) != _bodies(b)).mean())
    assert moved > 0.002, f"bodies moved over only {moved:.2%} of the view from t = 0 to {t1} s"


def test_viewer_page_reports_its_first_frame(tmp_path):
    page, _ = _page(tmp_path, "governor.yaml", {"t_end": 0.2, "step": 0.01,
                                                "error_estimate": False})
    dom = dump_dom(page, "t=0.1")
    assert 'data-first-frame-ms="' in dom, "the page did not finish its first frame"
    assert "t = 0.100 s" in dom
