"""mbsim.output.stats: one set of signal statistics for studies and sweeps."""

from __future__ import annotations

import numpy as np
import pytest

import mbsim.study
import mbsim.sweep
from mbsim.output import stats


def test_studies_and_sweeps_use_the_same_statistics():
    assert mbsim.study.STATS is stats.STATS and mbsim.sweep.SUMMARIES is stats.STATS


def test_period_of_a_sine():
    """sin(2 pi t / T) sampled finely: the mean spacing of its upcrossings is T (linear
    interpolation of the crossings: error O(dt^2) at a zero crossing, far below 1e-6 here)."""
    t = np.linspace(0.0, 10.0, 100_001)
    assert stats.period(t, np.sin(2 * np.pi * t / 0.7), {}) == pytest.approx(0.7, rel=1e-6)
