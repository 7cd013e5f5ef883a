"""The click options shared by the commands (mbsim.cli_options)."""

from __future__ import annotations

from mbsim.api import ANALYSES
from mbsim.cli import check, info, run
from mbsim.cli_dynamic import bench_command
from mbsim.cli_options import MODES, SETTINGS
from mbsim.cli_study import study_command
from mbsim.cli_sweep import sweep_command


def params(command) -> set[str]:
    return {p.name for p in command.params}


def test_the_mode_choice_is_every_analysis():
    assert set(MODES) == set(ANALYSES)


def test_run_and_sweep_take_the_same_analysis_settings():
    for command in (run, sweep_command):
        assert set(SETTINGS) <= params(command)
        assert {"sets", "scene", "quiet", "mode"} <= params(command)
    for command in (info, check, bench_command):
        assert {"sets", "scene"} <= params(command)
    assert {"jobs", "quiet"} <= params(study_command) and "jobs" in params(sweep_command)
