"""Studies: the deck's ``studies:`` section, the statistics, running, figures, tables, CLI,
and the bisection helper (mbsim/study.py, mbsim/cli_study.py, docs/studies.md)."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from mbsim.cli import main
from mbsim.deck import load_deck, load_deck_text
from mbsim.deck.schema import STUDY_STATS
from mbsim.errors import DeckError
from mbsim.output import read_result
from mbsim.study import STATS, growth, period, run_study, settle, study_figure, threshold

ROOT = Path(__file__).resolve().parents[1]
SLIDER = ROOT / "models" / "slider_crank.yaml"

# A small study on the slider-crank: two short inverse runs and a kinematic one.
STUDY = """
studies:
  quick:
    description: two rod lengths, a few steps
    cases:
      - {label: 'ℓ = 0.30 m', name: long, mode: inverse, set: {parameters.ell: 0.3},
         options: {t_end: 0.1, step: 0.02}}
      - {label: 'ℓ = 0.24 m', name: short, mode: inverse, set: {parameters.ell: 0.24},
         options: {t_end: 0.1, step: 0.02}}
      - {label: kinematic, mode: kinematic, options: {t_end: 0.1, step: 0.05}}
    figures:
      - {name: torque, y: drivers.crank.torque, ylabel: 'torque [N m]', cases: [long, short],
         title: Driving torque}
      - {name: slider, y: [bodies.slider.r.x, bodies.slider.rd.x], xlabel: 't [ms]',
         xscale: 1000}
    numbers:
      - {name: peak, y: drivers.crank.torque, stat: absmax, unit: N m, cases: [long, short]}
      - {name: x0, y: bodies.slider.r.x, stat: initial, unit: mm, scale: 1000}
      - {name: pin, y: points.pin_B.position, stat: final}
      - {name: dof, y: summary.dof}
      - {name: solves, y: counters.multiplier_solves, cases: [long]}
  other:
    description: one case
    cases:
      - {label: one, mode: kinematic, options: {t_end: 0.02, step: 0.01}}
"""


def deck_text(extra: str = STUDY) -> str:
    """The slider-crank deck without its own studies, plus `extra`."""
    return SLIDER.read_text().split("\nstudies:\n")[0] + "\n" + extra


@pytest.fixture
def deck(tmp_path) -> Path:
    path = tmp_path / "slider.yaml"
    path.write_text(deck_text())
    return path


# --------------------------------------------------------------------------- statistics


def test_stats_registry_matches_the_schema():
    assert tuple(STATS) == STUDY_STATS


def test_period_of_a_sine():
    t = np.linspace(0.0, 2.0, 2001)
    y = 3.0 + np.sin(2 * np.pi * t / 0.4 + 0.3)
    assert period(t, y) == pytest.approx(0.4, rel=1e-4)
    assert np.isnan(period(t[:100], y[:100]))  # less than two crossings


def test_settle_of_a_first_order_step():
    # y = 1 - exp(-(t - 1)/tau) after t = 1 enters the 2 % band at tau ln 50 (exact)
    tau, dt = 0.5, 1e-3
    t = np.arange(0.0, 8.0 + dt / 2, dt)
    y = np.where(t < 1.0, 0.0, 1.0 - np.exp(-(t - 1.0) / tau))
    assert settle(t, y, {"from": 1.0, "band": 0.02}) == pytest.approx(tau * np.log(50), abs=2 * dt)
    assert settle(t, np.ones_like(t), {}) == 0.0


@pytest.mark.parametrize("sigma, expect", [(-0.3, "<"), (0.0, "="), (0.3, ">")])
def test_growth_of_an_oscillation(sigma, expect):
    t = np.linspace(0.0, 20.0, 20001)
    y = 2.0 + np.exp(sigma * t) * np.sin(2 * np.pi * t)
    g = growth(t, y, {"from": 0.0})
    quarter = 5.0  # (20 - 0) / 4: the amplitude ratio of successive quarters is e^(sigma 5)
    assert g == pytest.approx(np.exp(sigma * quarter), rel=0.02)
    assert {"<": g < 1, "=": abs(g - 1) < 1e-3, ">": g > 1}[expect]


def test_simple_stats_and_windows():
    t = np.linspace(0.0, 1.0, 11)
    y = np.array([0, 1, 3, -4, 2, 0, 0, 1, 0, 0, 5.0])
    n = {"from": None}
    assert STATS["absmax"](t, y, n) == 5.0
    assert STATS["t_min"](t, y, n) == pytest.approx(0.3)
    assert STATS["range"](t, y, n) == 9.0
    assert STATS["max"](t, y, {"from": 0.15}) == 5.0
    assert STATS["initial"](t, y, {"from": 0.15}) == 3.0
    assert STATS["t_absmax"](t, -y, n) == pytest.approx(1.0)


# --------------------------------------------------------------------------- the deck section


def test_studies_are_read_as_plain_data(deck):
    spec = load_deck(deck)
    quick = spec.studies["quick"]
    assert quick["description"] == "two rod lengths, a few steps"
    case = quick["cases"][0]
    assert case["label"] == "ℓ = 0.30 m" and case["name"] == "long" and case["mode"] == "inverse"
    assert case["set"] == {"parameters.ell": 0.3} and case["scene"] is None
    assert case["options"] == {"t_end": 0.1, "step": 0.02}
    assert quick["cases"][2]["name"] == "kinematic"  # from the label
    fig = quick["figures"][1]
    assert fig["x"] == "time" and fig["xscale"] == 1000.0 and fig["scale"] == 1.0
    assert fig["y"] == ["bodies.slider.r.x", "bodies.slider.rd.x"] and fig["cases"] == []
    assert quick["figures"][0]["cases"] == ["long", "short"]
    num = quick["numbers"][0]
    assert (num["stat"], num["band"], num["from"], num["unit"]) == ("absmax", 0.02, None, "N m")
    assert quick["numbers"][2]["stat"] == "final"  # the default
    assert re.fullmatch(r".*slider\.yaml:\d+: studies\.quick\.figures\[1\]", fig["where"])


def test_a_deck_without_studies_has_none():
    spec = load_deck(SLIDER.parent / "governor.yaml")
    assert isinstance(spec.studies, dict)
    assert load_deck_text(deck_text("")).studies == {}


BAD = [
    (
        "studies: {s: {cases: [{label: a, mode: inverse}], figurs: []}}",
        r"studies\.s\.figurs: unknown key 'figurs' in a study; did you mean 'figures'\?",
    ),
    (
        "studies: {s: {cases: [{label: a, mode: invers}]}}",
        r"studies\.s\.cases\[0\]\.mode: expected mode .*did you mean 'inverse'\?",
    ),
    (
        "studies: {s: {cases: [{label: a, mode: inverse, scene: fre}]}}",
        r"cases\[0\]\.scene: unknown scene 'fre'; did you mean 'free'\?",
    ),
    (
        "studies: {s: {cases: [{label: a, mode: inverse, set: {parameters.el: 0.3}}]}}",
        r"cases\[0\]\.set\.parameters\.el: cannot set parameters\.el: .*did you mean",
    ),
    (
        "studies: {s: {cases: [{label: a, mode: inverse}, {label: a, mode: dynamic}]}}",
        r"studies\.s\.cases\[1\]: label 'a' is used twice",
    ),
    (
        "studies: {s: {cases: [{label: a, mode: inverse}],"
        " figures: [{name: f, y: q, cases: [b]}]}}",
        r"figures\[0\]\.cases\[0\]: unknown case \(label or name\) 'b'",
    ),
    (
        "studies: {s: {cases: [{label: a, mode: inverse}], numbers: [{name: n, y: q, stat: mx}]}}",
        r"numbers\[0\]\.stat: expected stat .*did you mean 'max'\?",
    ),
    (
        "studies: {s: {cases: [{label: a, mode: inverse}], numbers: [{name: n, y: q, band: 2}]}}",
        r"numbers\[0\]\.band: band must be between 0 and 1, got 2",
    ),
    (
        "studies: {all: {cases: [{label: a, mode: inverse}]}}",
        r"studies\.all: study name 'all' is reserved",
    ),
    ("studies: {s: {cases: []}}", r"studies\.s\.cases: expected at least one case"),
    ("studies: {s: {description: x}}", r"studies\.s: missing required key 'cases'"),
    ("studies: {s: {cases: {label: a}}}", r"studies\.s\.cases: expected a list"),
]


@pytest.mark.parametrize("text, message", BAD)
def test_study_errors_name_file_key_path_and_line(text, message):
    with pytest.raises(DeckError) as err:
        load_deck_text(deck_text("\n" + text + "\n"), "deck.yaml")
    line = deck_text("").count("\n") + 2
    assert re.search(rf"^deck\.yaml:{line}: .*{message}", str(err.value)), str(err.value)


LABELS = """
studies:
  s:
    cases:
      - {label: a, mode: inverse, options: {t_end: 0.02, step: 0.01}}
    figures:
      - name: f
        y: [bodies.slider.r, drivers.crank.torque]
        labels: [x, y, z, torque]
        caption: four curves per case
      - name: g
        y: [bodies.slider.r, drivers.crank.torque]
        labels: [x, y, torque]
"""


def test_figure_labels_of_the_wrong_length_are_a_deck_error_at_their_line():
    text = deck_text(LABELS)
    with pytest.raises(DeckError) as err:
        load_deck_text(text, "deck.yaml")
    line = text.splitlines().index("        labels: [x, y, torque]") + 1
    msg = str(err.value)
    assert "\n" not in msg
    assert msg.startswith(f"deck.yaml:{line}: studies.s.figures[1].labels: 3 labels given for 4 "
                          "curves per case (bodies.slider.r: 3, drivers.crank.torque: 1)"), msg
    # a selector whose width only the result knows (constraints.lam) counts as at least one
    bad = "studies: {s: {cases: [{label: a, mode: inverse}], figures: [{name: f, " \
          "y: [constraints.lam, bodies.slider.r.x], labels: [a]}]}}"  # fmt: skip
    with pytest.raises(DeckError, match=r"figures\[0\]\.labels: 1 labels given for at least 2"):
        load_deck_text(deck_text(bad), "deck.yaml")
    bad = "studies: {s: {cases: [{label: a, mode: inverse}], figures: [{name: f, y: q, " \
          "labels: q}]}}"  # fmt: skip
    with pytest.raises(DeckError, match=r"figures\[0\]\.labels: expected a list"):
        load_deck_text(deck_text(bad), "deck.yaml")


@pytest.mark.parametrize(("scene", "mode"), [(None, "inverse"), ("free", "dynamic")])
def test_label_counts_at_load_match_the_channels_of_a_result(scene, mode):
    """The widths the loader counts `labels` against (schema.STUDY_FIGURE_WIDTHS) are those
    of the channels an analysis writes; channels it cannot count are left to drawing."""
    from mbsim.api import load_model, run_model
    from mbsim.deck.loader import _curve_count
    from mbsim.output.export import select_columns

    spec, model = load_model(SLIDER, scene=scene)
    res = run_model(model, mode, {"t_end": 0.02, "step": 0.01}, deck=spec)
    counted = 0
    for name in res.channels:
        cols = select_columns(res, name)
        n = _curve_count(name.replace("/", "."))
        if n is not None:
            counted += 1
            assert n == len(cols), name
            for col in cols:  # one component, by label or index
                pick = f"{name}.{col.label}" if col.label else f"{name}[0]"
                assert _curve_count(pick.replace("/", ".")) == 1, pick
    assert counted == len(res.channels) - 1  # all but constraints.lam (no force elements here)


def test_a_scene_of_the_chosen_case_is_applied_only_when_run(deck):
    # loading with a scene leaves the studies as written (they are checked on the deck as is)
    spec = load_deck(deck, scene="free")
    assert "quick" in spec.studies


# --------------------------------------------------------------------------- running


def test_run_study_writes_files_figures_and_a_table(deck, tmp_path):
    out = run_study(deck, "quick", tmp_path / "out")
    assert out.ok, out.problems
    folder = tmp_path / "out" / "quick"
    assert sorted(p.name for p in folder.iterdir()) == [
        "kinematic.h5",
        "long.h5",
        "short.h5",
        "slider.png",
        "torque.png",
    ]
    assert [c.status for c in out.cases] == ["complete"] * 3
    res = read_result(folder / "short.h5")
    assert res.settings["study"] == {"study": "quick", "case": "short", "label": "ℓ = 0.24 m"}
    assert res.settings["overrides"] == {"parameters.ell": "0.24"}
    header, rows = out.table
    assert header[:4] == ["case", "mode", "status", "wall [s]"]
    assert "peak [N m]" in header and "x0 [mm]" in header and "dof" in header
    assert "pin.x" in header and "pin.z" in header  # one column per component
    by_case = {r[0]: dict(zip(header, r)) for r in rows}
    assert by_case["kinematic"]["peak [N m]"] == ""  # not asked for this case
    # x0 = sqrt(ell^2 - 0.1^2 - 0.2^2) (geometry.md §1.1), in mm by the scale
    assert out.values["short"]["x0 [mm]"] == pytest.approx(1000 * np.sqrt(0.24**2 - 0.05), 1e-9)
    assert out.values["long"]["dof"] == 0
    assert out.values["long"]["solves"] == 6  # t = 0, 0.02, ..., 0.1


def test_a_failing_case_does_not_stop_the_others(tmp_path):
    text = deck_text("""
studies:
  s:
    cases:
      - {label: ok, mode: kinematic, options: {t_end: 0.01, step: 0.01}}
      - {label: bad mass, mode: kinematic, set: {bodies.rod.mass: -1}}
    figures:
      - {name: f, y: bodies.slider.r.x}
      - {name: g, y: no.such.channel}
""")
    path = tmp_path / "d.yaml"
    path.write_text(text)
    out = run_study(path, "s", tmp_path)
    status = {c.name: c.status for c in out.cases}
    assert status == {"ok": "complete", "bad_mass": "failed"}
    assert "bodies.rod.mass: mass must be > 0, got -1" in out.cases[1].message
    assert out.cases[1].path is None
    assert not out.ok
    assert [p.name for p in out.figures] == ["f.png"]
    assert any("figure g" in p and "no channel" in p for p in out.problems)


def legend(figure) -> list[str]:
    return [t.get_text() for t in figure.axes[0].get_legend().get_texts()]


def test_figure_labels_replace_channel_and_component_names(tmp_path):
    path = tmp_path / "d.yaml"
    path.write_text(deck_text("""
studies:
  s:
    cases:
      - {label: long, mode: inverse, set: {parameters.ell: 0.3}, options: {t_end: 0.02, step: 0.01}}
      - {label: short, mode: inverse, set: {parameters.ell: 0.24},
         options: {t_end: 0.02, step: 0.01}}
    figures:
      - {name: one, y: [bodies.slider.r.x, bodies.crank.p], cases: [long],
         labels: [slider, e0, e1, e2, e3]}
      - {name: two, y: bodies.slider.r.x, labels: [slider x]}
      - {name: plain, y: [bodies.slider.r.x, bodies.slider.rd.x], cases: [long]}
      - {name: lam, y: constraints.lam, labels: [first row]}
"""))
    spec = load_deck(path)
    figs = {f["name"]: f for f in spec.studies["s"]["figures"]}
    assert figs["one"]["labels"] == ["slider", "e0", "e1", "e2", "e3"]
    assert figs["plain"]["labels"] == []
    out = run_study(path, "s", tmp_path)
    results = {c.name: (c.label, c.result) for c in out.cases}
    # one case: the labels alone; several: each after the case label
    one = legend(study_figure(figs["one"], [results["long"]]))
    assert one == ["slider", "e0", "e1", "e2", "e3"]
    assert legend(study_figure(figs["two"], list(results.values()))) == [
        "long slider x", "short slider x"]  # fmt: skip
    assert legend(study_figure(figs["plain"], [results["long"]])) == ["long x", "long x"]
    # constraints.lam has a column per constraint row: counted when the figure is drawn
    assert [p.name for p in out.figures] == ["one.png", "two.png", "plain.png"]
    (problem,) = out.problems
    assert re.fullmatch(r".*d\.yaml:\d+: studies\.s\.figures\[3\]: figure lam: labels: 1 given "
                        r"for \d+ curves of case 'long'; give one per channel or component",
                        problem), problem  # fmt: skip


@pytest.mark.slow
def test_parallel_cases_give_the_same_files(deck, tmp_path):
    serial = run_study(deck, "quick", tmp_path / "a")
    parallel = run_study(deck, "quick", tmp_path / "b", jobs=2)
    assert parallel.ok
    for c in serial.cases:
        a = read_result(tmp_path / "a" / "quick" / f"{c.name}.h5")
        b = read_result(tmp_path / "b" / "quick" / f"{c.name}.h5")
        assert np.array_equal(a.channel("bodies.slider.r").data, b.channel("bodies.slider.r").data)


def test_threshold_finds_a_known_rod_length():
    # x_C(0) = sqrt(ell^2 - 0.05) > 0.2  <=>  ell > 0.3 (geometry.md §1.1)
    # one step of 0.01 s: the criterion reads t = 0 (an analysis needs t_end > t_start)
    case = {"scene": None, "set": {}, "mode": "kinematic", "options": {"t_end": 0.01, "step": 0.01}}
    th = threshold(
        SLIDER,
        case,
        "parameters.ell",
        0.26,
        0.34,
        lambda r: r.channel("bodies.slider.r").data[0, 0] > 0.2,
        rtol=1e-3,
    )
    assert th.low <= 0.3 <= th.high and th.high - th.low <= 1e-3 * 0.34
    assert len(th.runs) >= 8 and th.runs[0][:2] == (0.26, False)
    with pytest.raises(ValueError, match="must be False at"):
        threshold(
            SLIDER,
            case,
            "parameters.ell",
            0.31,
            0.34,
            lambda r: r.channel("bodies.slider.r").data[0, 0] > 0.2,
        )


# --------------------------------------------------------------------------- CLI


def test_cli_list_run_and_errors(deck, tmp_path):
    runner = CliRunner()
    res = runner.invoke(main, ["study", str(deck), "--list"])
    assert res.exit_code == 0, res.output
    assert re.search(r"^quick\s+3 cases \(inverse, kinematic\)\s+two rod lengths", res.output, re.M)
    assert re.search(r"^other\s+1 case \(kinematic\)", res.output, re.M)

    res = runner.invoke(main, ["study", str(deck), "quick", "-o", str(tmp_path / "o")])
    assert res.exit_code == 0, res.output
    assert "figure -> " in res.output and "peak [N m]" in res.output
    assert re.search(r"ℓ = 0.24 m\s+inverse\s+complete", res.output)
    assert (tmp_path / "o" / "quick" / "torque.png").stat().st_size > 1000

    res = runner.invoke(main, ["study", str(deck), "all", "-o", str(tmp_path / "o"), "-q"])
    assert res.exit_code == 0, res.output
    assert (tmp_path / "o" / "other" / "one.h5").exists()

    res = runner.invoke(main, ["study", str(deck), "quik"])
    assert res.exit_code == 2
    assert "unknown study 'quik'; did you mean 'quick'? (studies: quick, other)" in res.output

    res = runner.invoke(main, ["study", str(deck)])
    assert res.exit_code == 2 and "name a study" in res.output


def test_cli_exit_1_when_a_case_fails(tmp_path):
    path = tmp_path / "d.yaml"
    path.write_text(
        deck_text("""
studies:
  s:
    cases: [{label: bad, mode: kinematic, set: {bodies.rod.mass: -1}}]
""")
    )
    res = CliRunner().invoke(main, ["study", str(path), "s", "-o", str(tmp_path)])
    assert res.exit_code == 1
    assert "study s, case bad: failed:" in res.output


# ------------------------------------------------------------- one parse per study (issue 12)
MODELS = ROOT / "models"


def fingerprint(spec) -> tuple:
    """What a case's spec decides: the tree after scene and overrides, the parameters, the
    items kept, the initial coordinates of the compiled model."""
    from mbsim.model import compile_model

    model = compile_model(spec)
    return (spec.raw, spec.parameters, list(spec.bodies), list(spec.joints),
            list(spec.drivers), list(spec.forces), spec.analysis, model.q0.tolist())  # fmt: skip


@pytest.mark.parametrize("deck_name", ["vehicle", "governor", "compressor"])
def test_cases_of_a_parsed_deck_equal_fresh_loads_and_leave_it_as_written(deck_name):
    """Every scene and every study case built from one ParsedDeck (copy-on-write edits)
    gives the spec that reading the file afresh with that scene and overrides gives, and
    the parsed tree is the same afterwards (no case's edit leaks into another)."""
    from mbsim.deck.loader import parse_deck
    from mbsim.deck.tree import to_plain
    from mbsim.study import overrides_of

    path = MODELS / f"{deck_name}.yaml"
    parsed = parse_deck(path)
    as_written = to_plain(parsed.root)
    variants = [(None, {})] + [(s, {}) for s in parsed.spec().raw.get("scenes", {})]
    for st in load_deck(path).studies.values():
        variants += [(c["scene"], overrides_of(c)) for c in st["cases"]]
    for scene, overrides in variants:
        case = parsed.spec(scene, overrides, studies=False)
        assert fingerprint(case) == fingerprint(load_deck(path, overrides, scene)), scene
        assert case.studies == {}
    assert to_plain(parsed.root) == as_written
    assert fingerprint(parsed.spec()) == fingerprint(load_deck(path))


def test_switching_items_on_in_one_case_leaves_them_off_in_the_next():
    """The governor's engine and load are `active: false` as written and switched on by
    the scene `governed`: dropping `active` (copy-on-write) must not reach the parsed tree."""
    from mbsim.deck.loader import parse_deck

    parsed = parse_deck(MODELS / "governor.yaml")
    on = parsed.spec("governed", studies=False)
    off = parsed.spec(overrides={"parameters.k": "2000"}, studies=False)
    assert {"engine", "load"} <= set(on.forces)
    assert not {"engine", "load"} & set(off.forces)
    assert parsed.root.value["forces"].value["engine"].value["active"].value is False


@pytest.mark.parametrize("overrides, message", [
    ({"bodies.spindle.mass": "-1"}, "bodies.spindle.mass: mass must be > 0, got -1"),
    ({"parameters.kk": "1"}, "cannot --set"),
    ({"joints.REV1.active": "maybe"}, "joints.REV1.active: expected true or false"),
])  # fmt: skip
def test_bad_overrides_of_a_parsed_deck_fail_as_a_fresh_load_does(overrides, message):
    """Same error text (file, key path, line) from a case of a parsed deck as from
    load_deck with the same overrides."""
    from mbsim.deck.loader import parse_deck

    path = MODELS / "governor.yaml"
    with pytest.raises(DeckError) as fresh:
        load_deck(path, overrides)
    with pytest.raises(DeckError) as case:
        parse_deck(path).spec(None, overrides, studies=False)
    assert str(case.value) == str(fresh.value)
    assert message in str(case.value) and str(path) in str(case.value)


def test_a_study_reads_and_parses_its_deck_once(deck, tmp_path, monkeypatch):
    """`mbsim study` of three cases: one read of the file, one YAML parse, no deep copy."""
    import copy

    import mbsim.deck.loader as loader
    from mbsim.deck.tree import Node

    counts = {"compose": 0, "read": 0}
    compose, read_bytes, deepcopy = loader.compose, Path.read_bytes, copy.deepcopy

    def counted_compose(*args, **kwargs):
        counts["compose"] += 1
        return compose(*args, **kwargs)

    def counted_read(self):
        counts["read"] += self.suffix == ".yaml"
        return read_bytes(self)

    def no_deepcopy(x, *args, **kwargs):
        assert not isinstance(x, Node), "deepcopy of a deck tree"
        return deepcopy(x, *args, **kwargs)

    monkeypatch.setattr(loader, "compose", counted_compose)
    monkeypatch.setattr(Path, "read_bytes", counted_read)
    monkeypatch.setattr(copy, "deepcopy", no_deepcopy)
    res = CliRunner().invoke(main, ["study", str(deck), "quick", "-o", str(tmp_path), "-q"])
    assert res.exit_code == 0, res.output
    assert counts == {"compose": 1, "read": 1}


# --------------------------------------------------------------------------- issue 15 additions


def test_settle_is_nan_for_an_oscillation_that_does_not_die_out():
    """A growing (or undamped) oscillation has no steady state: its 2 % band around the last
    value is left again in the last tenth of the window, so ``settle`` is NaN, not the time
    of the last sample (which the governor's k = 1000 case used to print as 19.9 s)."""
    t = np.linspace(0.0, 20.0, 2001)
    y = 1.0 - np.exp(-t) + 0.01 * np.exp(0.1 * t) * np.sin(2 * np.pi * t)
    assert np.isnan(settle(t, y, {}))
    y_damped = 1.0 - np.exp(-t) + 0.01 * np.exp(-0.5 * t) * np.sin(2 * np.pi * t)
    assert 3.0 < settle(t, y_damped, {}) < 5.0  # enters 2 % of the unit step near ln 50


def test_study_columns_difference_and_driver_function(deck, tmp_path):
    """``A - B`` of two one-column selectors and ``drivers.D.function`` (the driver's f(t)
    from the deck, at the output times: the slider-crank's crank angle pi/2 - 2 pi t, as the
    deck defines it), in figures and numbers; 'does not settle' printed for a NaN settle."""
    from mbsim.study import study_columns

    extra = STUDY.replace("      - {name: dof, y: summary.dof}", """\
      - {name: dof, y: summary.dof}
      - {name: x minus z, y: bodies.slider.r.x - bodies.slider.r.z, stat: max, cases: [long]}
      - {name: angle, y: drivers.crank.function, stat: final, cases: [long]}""")
    path = tmp_path / "d.yaml"
    path.write_text(deck_text(extra))
    out = run_study(path, "quick", tmp_path / "out")
    res = out.cases[0].result
    r, f = res.channel("bodies/slider/r").data, study_columns(res, "drivers.crank.function")
    (diff,) = study_columns(res, "bodies.slider.r.x - bodies.slider.r.z")
    assert np.array_equal(diff.data, r[:, 0] - r[:, 2]) and diff.unit == "m"
    (plus,) = study_columns(res, "bodies.slider.r.x + bodies.slider.r.z")
    assert np.array_equal(plus.data, r[:, 0] + r[:, 2])
    spec = load_deck(path)
    expr = spec.drivers["crank"].function
    assert f[0].unit == "rad"
    assert f[0].data == pytest.approx(np.pi / 2 - 2 * np.pi * res.t, abs=1e-12), expr
    assert out.values["long"]["x minus z"] == pytest.approx(np.max(r[:, 0] - r[:, 2]))
    assert out.values["long"]["angle"] == pytest.approx(np.pi / 2 - 2 * np.pi * 0.1)
    with pytest.raises(ValueError, match="one column"):
        study_columns(res, "bodies.slider.r - bodies.slider.r.z")
    with pytest.raises(KeyError, match="no driver 'nope'"):
        study_columns(res, "drivers.nope.function")


def test_table_says_does_not_settle():
    from mbsim.study import CaseOutcome, number_table

    t = np.linspace(0.0, 20.0, 2001)
    res = __import__("mbsim.result", fromlist=["Result"]).Result("dynamic", t)
    res.add("y", 1.0 + 0.01 * np.exp(0.1 * t) * np.sin(2 * np.pi * t), "m")
    st = {"numbers": [{"name": "transition", "y": "y", "stat": "settle", "scale": 1.0,
                       "unit": "", "cases": [], "from": None, "band": 0.02, "where": "w"}]}
    case = CaseOutcome("c", "c", "dynamic", "complete", result=res)
    header, rows, values = number_table(st, [case])
    assert header[-1] == "transition [s]" and rows[0][-1] == "does not settle"
    assert np.isnan(values["c"]["transition [s]"])
