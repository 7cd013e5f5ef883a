"""Governor deck (Tables 12.6.1-12.6.6): the book's counts and assembly back to Table 12.6.6."""

from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from mbsim.analyses.assembly import assemble
from mbsim.api import load_model
from mbsim.cli import main
from mbsim.options import deck_context
from mbsim.rotations import from_axis_angle
from tests.reference import equations as eq

DECK = Path(__file__).resolve().parents[2] / "models" / "governor.yaml"

# Table 12.6.6 with Ball 1's e3 corrected to -0.3827 (see the deck's header).
TABLE = {
    "spindle": ([0.0, 0.2, 0.0], [1.0, 0, 0, 0]),
    "ball1": ([0.11314, 0.08686, 0.0], [0.9239, 0, 0, -0.3827]),
    "ball2": ([-0.11314, 0.08686, 0.0], [0.9239, 0, 0, 0.3827]),
    "collar": ([0.0, 0.05, 0.0], [1.0, 0, 0, 0]),
}


def test_book_counts():
    spec, model = load_model(DECK)
    assert model.nq == 35  # nc = 5 bodies x 7 (ground counted, as in the book)
    assert model.m == 33  # nh = 2 distances + 3 x 5 revolute + 5 translational + 6 ground + 5
    asm = assemble(model, hold=deck_context(spec, shapes=False).hold)
    assert asm.rank == 33 and asm.dof == 2 and not asm.redundant_items


def test_info_prints_book_listing():
    out = CliRunner().invoke(main, ["info", str(DECK)])
    assert out.exit_code == 0, out.output
    assert "nc = 35" in out.output and "nh = 33" in out.output
    assert "DOF = 35 - 33 = 2" in out.output
    assert "Rank of Phi_q at the assembled configuration: 33" in out.output


def test_table_is_on_the_manifold():
    _, model = load_model(DECK)
    # Table 12.6.6 is given to 4-5 digits: |Phi| at the table ~ 1e-5 (rounding), and the
    # assembled configuration differs from it by the same order.
    assert np.abs(eq.phi(model, model.q0)).max() < 1e-4


@pytest.mark.parametrize("seed", range(5))
def test_assembly_from_perturbed_estimates_returns_to_table(seed):
    """Perturb every body (except the held independent coordinates, spindle e2 and collar y)
    by up to 1 cm and 5 deg; assembly must come back to Table 12.6.6 within 1e-4."""
    rng = np.random.default_rng(seed)
    spec, model = load_model(DECK)
    q = model.q0.copy().reshape(model.nb, 7)
    for name in TABLE:
        b = model.body_index(name)
        dr = rng.uniform(-1, 1, 3)
        dr *= 0.01 / np.linalg.norm(dr) * rng.uniform(0.5, 1.0)
        if name == "collar":
            dr[1] = 0.0  # held
        q[b, :3] += dr
        axis = rng.normal(size=3)
        if name in ("spindle", "collar"):
            axis[1] = 0.0  # a tilt, keeping e2 (spin) as given
        dp = from_axis_angle(axis, np.deg2rad(rng.uniform(2.5, 5.0)))
        p = q[b, 3:]
        # quaternion product dp * p (Haug Ch. 6): rotate the estimate by up to 5 deg
        q[b, 3:] = np.concatenate([[dp[0] * p[0] - dp[1:] @ p[1:]],
                                   dp[0] * p[1:] + p[0] * dp[1:] + np.cross(dp[1:], p[1:])])
        if name in ("spindle",):
            q[b, 5] = model.q0[7 * b + 5]
    asm = assemble(model, q.reshape(-1), hold=deck_context(spec, shapes=False).hold)
    assert asm.residual < 1e-10
    qa = asm.q.reshape(model.nb, 7)
    for name, (r, p) in TABLE.items():
        b = model.body_index(name)
        assert np.abs(qa[b, :3] - r).max() < 1e-4, name
        assert np.abs(qa[b, 3:] - p).max() < 1e-4, name
