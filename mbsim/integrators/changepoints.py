"""Change points of a mechanism: one measure, one policy, one completion, one step across.

A change point is a configuration where the active rows of Phi_q approach a rank loss, as
at the flat position of a parallelogram linkage: the independent rows admit a second
solution branch there, and every solve through a factor of Phi_q (or of Phi_u, or of the
Schur complement S = Phi_q M^-1 Phi_q^T) amplifies round-off.  The gcp and index-1
families (:mod:`mbsim.integrators.gcp`, :mod:`mbsim.integrators.index1`) pass such points
with the same four pieces, all of them here:

1. **The measure** s: an estimate of sigma_min / sigma_max of the active constraint
   Jacobian, dimensionless and linear in the distance to the point (0.35 theta on the four
   parallel cranks of models/parallel_fourbar.yaml, theta in rad from the flat position).
   Each family reads it from the factor it computes anyway: index-1 from the Schur factor
   of its accelerations, whose pivots go as sigma^2 (:func:`measure_from_schur`: the square
   root of the smallest pivot / diagonal that mbsim/fast/kernels.c reports); gcp from the LU
   factor of Phi_u (:func:`measure_from_lu`: smallest / largest |pivot|).
2. **The policy** (:class:`Policy`): every threshold, once, in terms of s, the tolerances and
   the machine epsilon; its docstring gives each derivation.
3. **Tangent coordinates** v = C q, C = (N^T M N)^-1 N^T M, N an orthonormal basis of the
   null space of Phi_q at a reference point (the M-orthogonal projection onto its tangent
   space: Mani, Haug & Atkinson 1985; Potra & Yen 1991).  They complete Phi_q to the square
   matrix A = [Phi_q; C]; the state follows from v, vd by one Newton completion
   (:func:`newton`, shared with gcp's coordinate partition), the accelerations from the
   reduced equations (T^T M T) v'' = T^T (Q - M p), T = A^-1 [0; I], p = A^-1 [gamma; 0]
   (Haug Sec. 11.4 with T in place of [I; -Phi_u^-1 Phi_v]), which solve only A: no Schur
   complement, whose condition is the square of Phi_q's.
4. **The step across** (:class:`Approach`): a motion that approaches the point slowly meets
   the round-off of the constraint equations themselves there; the step across the point is
   chosen to keep its stages clear of it.
"""

from __future__ import annotations

import ctypes
import dataclasses

import numpy as np
import scipy.linalg as la
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from mbsim.integrators.base import SAFETY
from mbsim.integrators.rk import StageFailure

EPS = float(np.finfo(float).eps)

# -- the policy ------------------------------------------------------------------------------
# The two numbers the policy takes from elsewhere (tests/integrators/test_policy.py checks
# that each agrees with its source); every threshold is derived from them in Policy.
SCHUR_PIVOT_FLOOR = 1e-8  # mbsim/fast/kernels.c PIVOT_FLOOR: the Schur factor's smallest
# pivot / diagonal below which the kernels raise the pivot
DEFAULT_RTOL = 1e-6  # mbsim.analyses.dynamic.DEFAULTS: the rtol of a run that asks none
NEWTON_MARGIN = 1e-2  # the completion's Newton stop as a fraction of atol: Hairer & Wanner,
# Solving ODEs II, Sec. IV.8 (the simplified Newton iteration of implicit RK methods), stop
# at kappa x Tol with kappa in [1e-2, 1e-1], so that the iteration error is a fraction of
# what the error test accepts; the low end, as the completion's error enters every stage
NEWTON_FLOOR = 1e-12  # m: the completion's Newton stop at least this: measured, not derived;
# next to a change point no stopping rule decides the completion's error (Policy doc,
# ``newton_tol``)


@dataclasses.dataclass(frozen=True)
class Policy:
    """The thresholds of one run near change points, each derived below from the machine
    epsilon eps, the run's tolerances (rtol; atol in m or rad) and the integrator's error
    exponent -1/k (k: the order of its error estimate + 1; 0 for fixed steps).  s is the
    measure of the module doc: dimensionless, ~ sigma_min / sigma_max of the active Phi_q,
    linear in the distance to the point.  Error norms are the scaled RMS norms of the error
    test (1 = the tolerance); a length L (m) is the mechanism's size, with atol <= rtol L, so
    that a distance d is d / (rtol L) tolerances.

    tangent: s below which a step's stages are in tangent coordinates (0: never).  A solve
        through a factor whose smallest pivot ratio is s perturbs its solution by eps / s
        relative; the switch is the s at which the family's solves leave round-off as large
        as the error test allows, rtol:
        - gcp solves three times in a row through Phi_u: q by Newton on Phi(u, v) = 0, qd
          from Phi_u ud = nu - Phi_v vd with Phi_q(q), qdd with Phi_q(q) and gamma(q, qd): the
          accelerations carry eps s^-3, so s_gcp = (eps / rtol)^(1/3) (:meth:`law`) =
          6.1e-4, 2.8e-3, 1.3e-2 at rtol 1e-6, 1e-8, 1e-10.
        - index-1 integrates q and qd and solves once, for the accelerations, through the
          Schur complement S = Phi_q M^-1 Phi_q^T, whose pivots go as s^2: a state off the
          constraints by its round-off moves qdd by e_S = eps s^-2 of max |qdd|.  Its
          tangent coordinates complete q, then qd, then solve for qdd, each through
          A = [Phi_q; C] whose smallest singular value goes as s, as gcp's three solves do:
          e_T = eps s^-3.  (Measured on the four cranks against the exact accelerations,
          from q perturbed by 4 ulps, s from 4e-5 to 4e-2: e_S = 0.2-1.9 eps s^-2 and e_T =
          0.04-0.6 eps s^-3 under the default and the Prescott OpenBLAS kernels alike, e_T
          the same with C taken 0.003, 0.06 or 0.3 rad from the point: it is the chain of
          solves, not C's reference point; tests/integrators/test_policy.py.)  So the
          Schur path is the more accurate wherever it solves the equations, i.e. above
          s_f = sqrt(SCHUR_PIVOT_FLOOR) = 1e-4: below that pivot ratio (~ s^2) the kernels
          raise the pivot and its accelerations are off by 0.4-0.9 of max |qdd|.  What the
          tangent coordinates have besides is an error test that takes the probed
          round-off off (``noise_err``, index-1 ``_stage_noise``); the Schur path's error
          test sees its round-off and cuts the steps for it.  That gives two limits, and
          the switch must lie between them:
          - from below, where the Schur path's round-off begins to cut the steps: a
            relative error e of the stage accelerations moves a step's qd by ~ h e |qdd|,
            i.e. e h / (rtol T) tolerances (|qd| ~ T |qdd|), with steps h ~ T rtol^(1/k):
            e_S reaches one tolerance at s = sqrt(eps rtol^-(1 - 1/k)) (:meth:`index1_law`;
            DOP853 1.3e-4, 3.5e-4, 9.7e-4 at rtol 1e-9, 1e-10, 1e-11).  Measured: with the
            switch at the floor alone projection-dop853 at rtol 1e-11 crawled at 1.4e-5 s
            next to the dead centre of tests/integrators/test_changepoints.py and the deck's
            eleven passages ended 2.98e-8 m off (bound 1.5e-8 m); at 2e-4 both pass.
          - from above, where tangent steps go wrong: a step retried in tangent coordinates
            whose stage comes to s ~ 5e-5 can pass its error test with a true error 30 x
            the tolerance (error norm 0.954, projection-dop853 at rtol 1e-10 under Haswell
            with newton_tol's lower clamp moved to 2.220446e-12: a stage at s = 6.3e-5, the
            run 2.8e-9 m off).  Measured: the four cranks at rtol 1e-9 under
            OpenBLAS Prescott, switch 3e-4 ... 1e-3: 4.0e-8 m (2.97e-10 m at 2e-4 or less;
            the step 0.4471 -> 0.4659 s, a stage at s = 5.4e-5, the energy up 6.6e-7 J);
            the shaken four cranks (tests/integrators/test_index1_tangent.py::
            test_rheonomic_linkage) at rtol 1e-10 under Haswell, switch 3e-4 or more:
            2.54e-8 m (passes at 1e-4 ... 2.5e-4).  Which stage lands how close to the
            point is the run's round-off, so this limit is not a law of rtol, and the
            derived lower limit crosses it (3.5e-4 at rtol 1e-10).
          The derived lower limit is not sharp either: at rtol 1e-10 the runs pass with
          switches from 1e-4 up.  Until the tangent step's error test sees the error of
          such a step, the switch is the measured law s_index1 = max(s_f, (eps /
          rtol)^(2/3)) (the square of gcp's; 1e-4 down to rtol 2.2e-10, 1.7e-4 at 1e-10,
          7.9e-4 at 1e-11), which passes every case above (and .ci/matrix's kernels on
          f6fe280): a fitted exponent, not a derivation.  The derived lower limit as the
          switch fails at the dead centre, over starts perturbed by 4 ulps (w0 = 10.51
          rad/s, six starts each; docs/benchmarks.md, "Change points as one component"):
          Dormand-Prince 5(4) at rtol 1e-11 gets 3.7e-4 against the law's 7.9e-4, and
          projection crawls in 5 of 6 starts (36-119 s CPU) against 1 of 6 (40 s; the others
          0.6-0.7 s) with the law; DOP853 at rtol 1e-10 gets 3.5e-4 against 1.7e-4, and at
          w0 = 10.505 its errors are 2-3x the law's (6.8e-11 ... 3.1e-10 m against 3.0e-11
          ... 1.1e-10 m).  The limit's dependence on k runs against the measurements: too
          low for 5(4), too high for DOP853.
          Against the blind spot above, an index-1 tangent step that crosses the point with
          a stage whose probed round-off exceeds the tolerance is taken again with its
          stages clear of the point (index-1 ``_clear_crossing``; it catches such a step
          only where one draw of the probe sees its round-off, not always): the stage's
          round-off is probed and carried to the step's end (:meth:`stage_reach`), and the
          step is retried with every stage at s >= (its round-off at s = 1)^(1/3) (the law
          s^-3 of the three solves; :func:`clear_of_crossing`).  What counts as a crossing
          (:func:`crossing_in_step`: slopes within a quarter of the V's) is a geometric
          choice, not derived.
        A fixed-step run has no error test: nothing in it sees either path's round-off or
        the accuracy its steps deliver (rk4 at 0.25 ms: 1e-12 m on the four cranks, far
        below any default).  Its switch is where the tangent coordinates themselves meet
        the accuracy of a run that asks none, :meth:`law` at DEFAULT_RTOL = 6.1e-4, for
        both families (index-1 at s_f instead: 1.3e-11 m).  An index-1 run whose measure
        at the start, s0, is already below its switch (a tight tolerance, or fixed steps,
        on a model whose regular states have a small s0) meets the switch nowhere; a
        change point is where s falls from its regular value towards 0, so the switch is
        taken below s0, at sqrt(s_f s0) (:meth:`at_start`): the midpoint of s_f and s0 on
        the log scale in which the round-off laws above are powers, as many decades of
        round-off from the regular states as from the floor.  A start at or below s_f (at
        the change point itself, where no branch is known) takes no tangent coordinates.
    noise_s: below this s a tangent step's round-off is not taken off its error test
        (index-1 ``_stage_noise``): s = eps^(1/3) = 6.1e-6 (:meth:`law` at rtol 1), where
        the three solves' round-off eps s^-3 is as large as the accelerations themselves,
        so that a probe of it measures nothing and taking it off would pass any step.
    noise_err: error norms above this are probed for round-off: SAFETY^k (base.SAFETY =
        0.9; 0.43 for DOP853, k = 8; 0.59 for Dormand-Prince 5(4), k = 5), the norm above
        which the step-size controller makes the next step smaller than this one (h_new =
        h SAFETY err^(-1/k), the PI memory aside).  Below it the step passes and the next
        one grows whatever the round-off is; the probe costs two completions.
    cut: a step cut below this x a reference step is cut by round-off, not by truncation
        error: (eps / rtol)^(1/k).  At the reference step the error norm was ~1; an
        embedded estimate of truncation error falls like h^k, so at cut x that step it is
        eps / rtol, the round-off of q ~ L in tolerances (0.062, 0.11, 0.20 at rtol 1e-6,
        1e-8, 1e-10 for DOP853; 0.012, 0.034, 0.073 for 5(4)).  Two uses: once a passage's
        steps are cut below cut x its first tangent step, the error test of the full q
        (index-1) is left out; once an adaptive step is cut below cut x the last step before
        the approach, the approach tries a step across the point (:class:`Approach`).
        1 for fixed steps (no cuts).
    branch_jump: a completion that moves q by more than this many tolerances started off
        the step's branch (gcp rejects the stage; index-1 dense output completes another
        interpolant).  The prediction it starts from (an RK combination, or the RK
        interpolant) is accurate to the local error, ~1 tolerance; where the coordinates
        change (s = tangent) the other branch lies tangent x L away, tangent / rtol
        tolerances.  The threshold is the geometric mean of the two, sqrt(tangent / rtol):
        a factor sqrt(tangent / rtol) from each (gcp 25, 530, 1.1e4; index-1 10, 100, 1300
        at rtol 1e-6, 1e-8, 1e-10).  Where tangent <= rtol the two branches lie within one
        tolerance of each other, which the error test cannot tell apart: no check (inf).
    newton_tol: the completion's Newton tolerance on max |dq| (m or rad):
        max(NEWTON_MARGIN atol, NEWTON_FLOOR).  The margin 1e-2 is Hairer & Wanner's
        (Solving ODEs II, Sec. IV.8: the Newton iteration of an implicit RK step stops at
        kappa Tol, kappa in [1e-2, 1e-1], so that its error is a fraction of what the error
        test accepts); its low end, since the completion's error enters every stage.  No
        ceiling: a loose atol stops Newton loosely, as the error test allows.  The floor
        1e-12 m is measured, not derived, and no stop derived from eps, the coordinates'
        size and s does better, because next to a change point the stop does not decide
        the completion's error.  The computed residual cannot tell apart the points of a
        ball of width ~ eps |q| / s along A's soft direction (the residual's round-off, eps
        |q|, carried through A or Phi_u: 2.4e-12 m at s = 9e-5 on the four cranks), and
        Newton ends anywhere in it whatever its tolerance: where depends on where it
        started; the velocities and accelerations there differ (v'' by ~ eps s^-2
        relative).  Measured (benchmarks/newton_floor.py; docs/benchmarks.md, "The Newton
        floor"): gcp-dop853 on the four cranks at rtol 1e-11 under OpenBLAS Prescott with
        the floor eps / sqrt(SCHUR_PIVOT_FLOOR) = 2.2e-12 m, a stage at s = 9.15e-5
        completed from its prediction (1.5e-10 m off) ends 6.5e-13 m from the exact q with
        v'' off by 1.2e-6 of 116 (-1.2e-6, 1.5e-6, 3.9e-7, 5.8e-8 with the tolerances
        2.2e-12, 1e-12, 3e-13, 1e-13; -3.2e-6 ... 3.0e-6 from the prediction moved by 1e-10
        m; 7.7e-13 from the exact q).  Its step's error norm does not see it (DOP853's norm
        divides the fifth-order estimate, 135 tolerances in vd, by a tenth of the
        third-order one's truncation error, 7e4 tolerances: 0.38; the full q 0.71), which
        leaves vd 350 tolerances off at the step's end, and the run ends 6.57e-9 m off:
        3.8e-11 m with that one stage completed from the exact q, 2.75e-11 m with the floor
        1e-12, where the same step's full-q norm came to 4.86.  Every rule tried leaves
        1e-10 m or more at rtol 1e-11 under some kernel where the others leave 7e-12 ...
        3e-11 m: 1e-12 (1.2e-10 m, Haswell), 2.2e-12 (6.57e-9 m, Prescott), the floor eps
        max |x| / s with s of the factor just solved with (3.0e-9 m, Haswell), a stop once
        |dx| stops halving (1.3e-9 ... 4.7e-9 m, default, Haswell, SkylakeX): the draw, not
        the rule.  A round-off probe that completes again from the result moved by 4 ulps
        does not see this error (the result is a fixed point of the computed iteration: the
        same v'' eight times in eight); completed again from the prediction, Newton's start,
        moved by 4 ulps or by its own distance, v'' spreads over +-3e-6, ~900 tolerances of
        vd at the step's end.  The stop at the ball with a gcp clearing probed that way held
        every gcp case within its bound on four kernels, but the index-1 tangent
        completions share the stop, and it broke their slow crossing of the dead centre
        at rtol 1e-11 (a run turned back, 1.07e-2 m off; docs/benchmarks.md, "The Newton
        floor"; tests/integrators/test_index1_tangent.py's slow perturbed-start check).  A
        fixed-step run has no atol: the floor alone.
    kept_residual: a Newton that stops moving above its tolerance (gcp's projected
        Hermite fallback) is kept where its residual max |Phi| is within 1e2 newton_tol,
        i.e. one atol (m) above 1e-10 m: one absolute tolerance, what the error test
        cannot tell from zero.  The index-1 projection's own rule is :meth:`projection_kept`.
    newton_iter: the completion's most Newton iterations: quadratic convergence doubles the
        correct digits per iteration, from one (a start within the local error) to the 16
        of a double in ceil(log2(-log10 eps)) = 4; twice that for a start outside the
        quadratic regime.
    rank_lost: s at which the active Phi_q has lost rank (no partition exists): n eps, the
        backward error of its QR or LU factor (Higham, Accuracy and Stability, Thm 19.4;
        n = nq), below which a pivot is round-off.
    """

    tangent: float
    noise_s: float
    noise_err: float
    cut: float
    branch_jump: float
    newton_tol: float
    kept_residual: float
    newton_iter: int
    rank_lost: float

    @staticmethod
    def law(rtol):
        """(eps / rtol)^(1/3): the s below which three solves' round-off exceeds rtol."""
        return (EPS / rtol) ** (1.0 / 3.0)

    @staticmethod
    def index1_law(rtol, k):
        """max(s_f, sqrt(eps rtol^-(1 - 1/k))): the s at which the Schur path's round-off
        eps s^-2 moves an index-1 step's qd by one tolerance, the lower limit of the
        index-1 switch (class doc, ``tangent``; not the switch itself); k: the error
        exponent's -1/k."""
        return max(float(np.sqrt(SCHUR_PIVOT_FLOOR)),
                   float(np.sqrt(EPS * rtol ** -(1.0 - 1.0 / k))))

    @classmethod
    def for_run(cls, family, rtol, atol, fixed, tangent=True, *, exponent, n):
        """The policy of a run: family 'gcp' | 'index-1'; fixed: a fixed-step run;
        tangent: False takes no tangent coordinates (index-1 option ``tangent_steps``);
        exponent: the integrator's error exponent -1/k (0: no error estimate); n: nq."""
        k = -1.0 / exponent if exponent and not fixed else 0.0
        newton_tol = cls.newton_tolerance(None if fixed else atol)
        if fixed:
            s = cls.law(DEFAULT_RTOL)
        elif family == "gcp":
            s = cls.law(rtol)
        else:
            s = max(float(np.sqrt(SCHUR_PIVOT_FLOOR)), float(cls.law(rtol) ** 2))
        return cls(
            tangent=s if tangent else 0.0,
            noise_s=cls.law(1.0),
            noise_err=SAFETY ** k if k else 1.0,
            cut=(EPS / rtol) ** (1.0 / k) if k else 1.0,
            branch_jump=cls.jump(s, rtol),
            newton_tol=newton_tol,
            kept_residual=1e2 * newton_tol,
            newton_iter=2 * int(np.ceil(np.log2(-np.log10(EPS)))),
            rank_lost=n * EPS)

    @staticmethod
    def newton_tolerance(atol):
        """newton_tol (class doc): max(NEWTON_MARGIN atol, NEWTON_FLOOR) (m or rad); atol
        None (fixed steps): the floor alone."""
        return NEWTON_FLOOR if atol is None else max(NEWTON_MARGIN * atol, NEWTON_FLOOR)

    @staticmethod
    def stage_reach(tableau, h):
        """(n_stages + 1, 2): how far an error a in one stage's acceleration reaches the end
        of a step of size h (s): y_new = y + h sum b_i K_i moves the end's velocities by h
        |b_i| a and its positions by h^2 |(b^T A)_i| a (columns: s, s^2; rows: the stages at
        tableau.C, then the step's end).  The end is the next step's start, whose derivative
        enters that step with b_0: its row takes stage 0's reach; stage 0 (this step's
        start, a state already taken) gets none.  Zero rows (DOP853's stages 2-5) reach the
        end only through later stages."""
        b = np.abs(tableau.B)
        bA = np.zeros(b.size)  # (A: (n_stages, n_stages - 1) when the last column is 0)
        bA[: tableau.A.shape[1]] = np.abs(tableau.B @ tableau.A[: b.size])
        reach = np.zeros((b.size + 1, 2))
        reach[:-1, 0], reach[:-1, 1] = h * b, h * h * bA
        reach[-1] = reach[0]
        reach[0] = 0.0
        return reach

    @staticmethod
    def projection_kept(proj_tol):
        """The residual max |Phi| (m) up to which an index-1 projection with tolerance
        proj_tol that stops moving is kept (Index1._project, and the compiled step through
        mbsim/fast/stepper.py's proj_fail): 1e3 proj_tol, at least 1e-11.  With
        the default proj_tol = 1e-3 atol within [1e-14, 1e-10] this is atol within
        [1e-11, 1e-7]: one absolute tolerance, as ``kept_residual``; the 1e-11 is 1e3 x
        that default's floor, and matters only for a projection_tol option below it."""
        return max(1e3 * proj_tol, 1e-11)

    @staticmethod
    def jump(s, rtol):
        """branch_jump for the switch s (class doc)."""
        return float(np.sqrt(s / rtol)) if s > rtol else np.inf

    def at_start(self, s0, rtol):
        """The policy of an index-1 run whose measure at its start is s0 (class doc,
        ``tangent``)."""
        floor = float(np.sqrt(SCHUR_PIVOT_FLOOR))
        if self.tangent <= s0:
            return self
        if s0 <= floor:
            return self.off()
        s = float(np.sqrt(floor * s0))
        return dataclasses.replace(self, tangent=s, branch_jump=self.jump(s, rtol))

    def off(self):
        """The same policy without tangent coordinates."""
        return dataclasses.replace(self, tangent=0.0)


def measure_from_schur(pivot_ratio):
    """s from the Schur factor's smallest pivot / diagonal (~ sigma^2; <= 0 at the point)."""
    return float(np.sqrt(max(pivot_ratio, 0.0)))


def measure_from_lu(fac, sparse):
    """s from an LU factor (scipy's lu_factor, or splu when sparse): smallest / largest
    |pivot| (at the four-bar's flat position 0.2 x the angle from it)."""
    d = np.abs(fac.U.diagonal() if sparse else np.diag(fac[0]))
    return float(d.min() / d.max()) if d.size and d.max() > 0 else 1.0


# -- tangent coordinates --------------------------------------------------------------------
def mass_times(system, q, X):
    """M(q) X, M block diagonal (System.mass_blocks)."""
    Mb = system.mass_blocks(q)
    nb = Mb.shape[0]
    return np.einsum("bij,bjk->bik", Mb, X.reshape(nb, 7, -1)).reshape(X.shape)


def tangent_map(system, q, Jd):
    """C (k, nq) of the tangent coordinates at q (Jd: dense Phi_q there, (m, nq), full row
    rank); None where the mass matrix is singular on the tangent space (a massless motion:
    no M-orthogonal projection)."""
    m, n = Jd.shape
    Qf, _ = la.qr(Jd.T, check_finite=False)
    N = Qf[:, m:n]
    MN = mass_times(system, q, N)
    try:
        cf = la.cho_factor(N.T @ MN, check_finite=False)
    except la.LinAlgError:
        return None
    return la.cho_solve(cf, MN.T, check_finite=False)  # C N = I


def factor(system, J, C):
    """LU of A = [Phi_q; C] (nq x nq)."""
    system.counters["factorizations"] += 1
    if system.sparse:
        try:
            return spla.splu(stacked(J, C).tocsc())
        except RuntimeError as exc:
            raise StageFailure(f"singular [Phi_q; C] ({exc})") from exc
    return la.lu_factor(np.vstack([J, C]), check_finite=False)


def stacked(J, C):
    """[J; C] as CSR (J: CSR (m, nq), C: dense (k, nq)): sp.vstack's matrix, built from the
    arrays (0.28 against 0.43 ms on the 40-loop four-bar, 1-2 per tangent completion)."""
    if not (sp.issparse(J) and J.format == "csr"):
        return sp.vstack([J, sp.csr_matrix(C)], format="csr")
    i, j = np.nonzero(C)
    ptr = J.indptr[-1] + np.cumsum(np.bincount(i, minlength=C.shape[0]))
    return sp.csr_matrix((np.concatenate([J.data, C[i, j]]),
                          np.concatenate([J.indices, j.astype(J.indices.dtype)]),
                          np.concatenate([J.indptr, ptr.astype(J.indptr.dtype)])),
                         shape=(J.shape[0] + C.shape[0], J.shape[1]))


def solve(system, fac, b, trans=False):
    """A^-1 b (A^-T b) with a factor of :func:`factor` (or any LU of the same kind)."""
    if system.sparse:
        return fac.solve(b, trans="T" if trans else "N")
    return la.lu_solve(fac, b, trans=1 if trans else 0, check_finite=False)


def basis(system, fac, k):
    """T = A^-1 [0; I] (nq x k): the tangent space with C T = I."""
    n = system.nq
    E = np.zeros((n, k))
    E[n - k:] = np.eye(k)
    return solve(system, fac, E)


def newton(system, t, q, correction, tol, max_iter):
    """The one Newton completion of both families: q on Phi(q, t) = 0 and the family's own
    equations for its independent coordinates.  correction(T, q) -> (dq (nq,), fac) gives
    the Newton step from the terms T at q (gcp coordinates: dq on u from Phi_u; tangent
    coordinates: dq from A = [Phi_q; C] on [Phi; C q - v]).  Returns (q, T, fac, ok): T, fac
    of the last iterate; ok unless Newton neither stopped moving (max |dq| <= tol) nor left
    max |Phi| <= tol within max_iter iterations (corrections may stagnate at round-off
    while the constraints hold: that is kept)."""
    s = system
    x = np.array(q, dtype=float)
    for _ in range(max_iter):
        T = s.terms(x, t, jac=True, nu=s.rheonomic)
        dx, fac = correction(T, x)
        x -= dx
        s.counters["newton_iterations"] += 1
        if np.abs(dx).max(initial=0.0) <= tol:
            return x, T, fac, True  # Phi_q of this iterate is within tol of Phi_q(x)
    return x, T, fac, bool(np.abs(T.phi).max(initial=0.0) <= tol)


def complete(system, t, q, v, vd, C, tol, max_iter):
    """(q, qd, fac, T) in tangent coordinates: q on Phi(q, t) = 0 with C q = v by
    :func:`newton` from q, qd from A qd = [nu; vd], fac the LU of A at the last iterate, T
    its constraint terms.  qd is None where Newton failed (the caller says why)."""
    s = system

    def correction(T, x):
        fac = factor(s, T.jac, C)
        return solve(s, fac, np.concatenate([T.phi, C @ x - v])), fac

    x, T, fac, ok = newton(s, t, q, correction, tol, max_iter)
    if not ok:
        return x, None, fac, T
    nu = T.nu if s.rheonomic else np.zeros(s.m)
    return x, solve(s, fac, np.concatenate([nu, vd])), fac, T


def accelerations(system, t, q, qd, fac, k):
    """(qdd, power) from the reduced equations (module doc): (T^T M T) v'' = T^T (Q - M p), the
    constraint forces dropping out (T^T Phi_q^T = 0); power = Q.qd - lam.nu with lam from
    A^T [lam; mu] = Q - M qdd (mu = 0)."""
    s = system
    G = s.terms(q, t, qd=qd, phi=False, jac=False, gamma=True, nu=s.rheonomic)
    Tb = basis(s, fac, k)
    p = solve(s, fac, np.concatenate([G.gamma, np.zeros(k)]))
    Q = s.generalized_forces(q, qd, t)
    MTp = mass_times(s, q, np.column_stack([Tb, p]))
    try:
        a = la.solve(Tb.T @ MTp[:, :k], Tb.T @ (Q - MTp[:, k]), assume_a="sym",
                     check_finite=False)
    except la.LinAlgError as exc:
        raise StageFailure(f"t = {t:.6g} s: singular reduced mass matrix ({exc})") from exc
    s.counters["factorizations"] += 1
    qdd = Tb @ a + p
    power = float(Q @ qd)
    if s.rheonomic:
        r = Q - mass_times(s, q, qdd[:, None])[:, 0]
        lam = solve(s, fac, r, trans=True)[: s.m]
        power -= float(lam @ G.nu)
    return qdd, power


# -- the step across -------------------------------------------------------------------------
class Approach:
    """A motion's approach to a change point, and the step across it.

    Near the point the tangent coordinates' accelerations carry round-off that grows like
    s^-3 (the policy's three solves): the completed state lies on a computed constraint set
    u w = eps whose curvature near the crossing u = w = 0 is ~ eps / theta^3.  A motion that
    approaches the point slowly has its steps cut by that noise as it nears the point,
    ~ distance^3, and never arrives.  A step across instead whose stages stay clear of the
    point meets only the noise of its nearest stage, which falls with the step (a DOP853
    step of 1e-2 s with the point midway between its stages at c = 1/3 and 0.6 keeps them
    1.3e-3 s from it).  Fixed steps meet the same noise wherever a stage lands next to the
    point.

    So after each accepted step the integrator reports s (the measure, linear in the
    distance to the point; :meth:`accepted`, whose measure part, with :meth:`near`, is C's
    mb_approach_accepted and mb_approach_near in mbsim/fast/step.c, called here and by the
    loop of many steps there).  The approach is followed from the first state whose s lies
    within two steps of the policy's switch at the speed s fell over the last step,
    s < tangent + 2 h (-ds/dt) (:meth:`near`): the steps that reach the switch are then two
    accepted states of the approach, enough to extrapolate; it ends where s rises above the
    s at which it began.  Meanwhile the time d to the point is extrapolated linearly from
    the last two states (:func:`crossing_time`), and :meth:`step` gives the step to try
    instead of the one proposed: the step whose stages, dense output's included, lie
    farthest from the point (:func:`clear_step`) among
    - adaptive steps that cross it, of at most the larger of the proposed step and the
      last step before the approach (their truncation error), once the proposed step has
      been cut below the policy's ``cut`` x that last one (what cuts it is round-off;
      uncut, the controller's steps pass the point as they are: a motion that turns short
      of the point, where the prediction is wrong, keeps them), tried again only once d
      has halved; the error test decides;
    - fixed steps h: a step in [h/2, 3h/2] once d < 3h/2 (the point then at most half a
      step from the nearest step end of the unmoved grid), where the motion dwells in the
      tangent region: where s changes by less than the policy's switch over the widest gap
      between stage times (at the speed -ds/dt of the last step), so that stages cannot
      help landing next to the point.  A faster passage has at most one stage of a step
      in that gap, which the tangent coordinates take as they are: moving it would only
      put the step's stages in the coordinates' near-singular Phi_u on either side.
    A step across counts as taken when it was accepted at the size tried (a rejected step
    comes back at most base.SAFETY x its size).
    """

    def __init__(self, stages, h_fixed, policy):
        from mbsim.fast import _lib, stepper

        lib = _lib.library()
        if lib.mb_approach_size() != ctypes.sizeof(stepper.ApproachState):
            raise _lib.KernelBuildError("mb_approach in step.c and mbsim.fast.stepper's "
                                        "ApproachState differ (an edit on one side only)")
        self._near, self._accepted = lib.mb_approach_near, lib.mb_approach_accepted
        # the measure: tangent, rate -ds/dt (> 0: approaching), the last accepted state
        # (t, s) and the s where the approach began (NaN: none); C reads and writes it
        self.c = stepper.ApproachState(policy.tangent, 0.0, np.nan, np.nan, np.nan)
        self.stages, self.h_fixed = stages, h_fixed  # stages: stage_times
        self.tangent, self.cut = policy.tangent, policy.cut
        self.h_far = None  # the last accepted step before the approach
        self.points = ()  # (t, s) of the last two accepted states of the approach
        self.d_tried = np.inf  # the predicted distance at the last step tried across
        self.tried = None  # the step size tried by the current step, if any

    @property
    def rate(self):
        """-ds/dt between the last two accepted states (> 0: approaching)."""
        return self.c.rate

    @property
    def last(self):
        """(t, s) of the last accepted state, or None."""
        return None if np.isnan(self.c.last_t) else (self.c.last_t, self.c.last_s)

    @property
    def entry(self):
        """s where the approach began, or None (no approach)."""
        return None if np.isnan(self.c.entry) else self.c.entry

    def near(self, h):
        """s below which a state after a step of size h belongs to the approach (class
        doc): the s where it began, or the switch plus two steps' fall (mb_approach_near)."""
        return self._near(ctypes.addressof(self.c), h)

    def accepted(self, t, h, s):
        """After an accepted step of size h to t, s there (None: not comparable with the
        earlier ones, e.g. a new coordinate partition); True when it was a step across."""
        across = self.tried is not None and h >= SAFETY * self.tried
        self.tried = None
        if s is None:
            self.points = ()
            self.c.rate, self.c.last_t, self.c.last_s = 0.0, np.nan, np.nan
            return across
        self.measured(t, h, s, self._accepted(ctypes.addressof(self.c), t, h, s))
        return across

    def measured(self, t, h, s, clear):
        """The rest of :meth:`accepted` once its measure is taken (mb_approach_accepted,
        here or in the loop of many steps): ``clear``, the state after the step of size h to
        t is clear of the approach (h the last step before it), else one of its states."""
        self.tried = None
        if clear:
            self.h_far, self.points, self.d_tried = h, (), np.inf
        else:
            self.points = (self.points + ((t, s),))[-2:]

    def step(self, h_abs):
        """The step to try instead of h_abs, or None (class doc)."""
        self.tried = None
        if len(self.points) < 2:
            return None
        d = crossing_time(self.points)
        if d is None:
            return None
        if self.h_fixed is not None:
            h = self.h_fixed
            if d >= 1.5 * h:
                return None
            if self.rate * h * np.diff(self.stages).max() >= self.tangent:
                return None  # a passage, not a dwell (class doc)
            moved = clear_step(self.stages, d, 0.5 * h, 1.5 * h)[0]
            if moved == h:
                return None
        else:
            if self.h_far is None or h_abs >= self.cut * self.h_far:
                return None
            h_cap = max(h_abs, self.h_far)
            if not (d < h_cap and d <= 0.5 * self.d_tried):
                return None
            self.d_tried = d
            moved = clear_step(self.stages, d, d * (1 + EPS ** 0.5), h_cap)[0]
        self.tried = moved
        return moved


def crossing_in_step(c, s, s0, s1, h, agree=0.25):
    """(d, r) of a change point crossed inside a step of size h, read off the measure of
    its states and stages: s0, s1 (at its start and end), s (at the stage times c h, c in
    (0, 1)); d (s) from the start, r (1/s) the speed |ds/dt|.  s is linear in the distance
    to the point, so a crossing makes s = r |t - d| (a V): r = (s0 + s1) / h and d = s0 / r
    from the step's ends, checked against the slopes the stages give on either side (each
    within ``agree`` of r; a side without a stage more than a quarter step from d is not
    checked, but one side must be).  None where the stages do not show that V, as where the
    motion turns short of the point (a dwell: s falls and rises again without reaching 0,
    its slopes at the ends are not those of the ends' V)."""
    if not (s0 > 0.0 and s1 > 0.0 and h > 0.0):
        return None
    r = (s0 + s1) / h
    d = s0 / r
    t = np.asarray(c) * h
    s = np.asarray(s)
    checked = 0
    before = np.flatnonzero((t > 0.0) & (t < 0.5 * d))
    if before.size:
        i = before[0]  # the stage nearest the start: the slope of the falling side
        if abs((s0 - s[i]) / t[i] - r) > agree * r:
            return None
        checked += 1
    after = np.flatnonzero((t < h) & (t > 0.5 * (d + h)))
    if after.size:
        i = after[-1]  # the stage nearest the end: the slope of the rising side
        if abs((s1 - s[i]) / (h - t[i]) - r) > agree * r:
            return None
        checked += 1
    return (d, r) if checked else None


def clear_of_crossing(c, weights, d, r, h):
    """The step h' in [d (1 + sqrt eps), h] that takes the crossing of :func:`crossing_in_step`
    with its stages clear of the point, or None where no step does (a dwell) or the step h
    already does.  c: the stage times (0 and 1 included: the step's ends are states of the
    run); weights: (len(c), 2), the tangent round-off of each stage carried to the step's
    end (Policy.stage_reach) in tolerances at s = 1 (dimensionless), its columns scaling
    with the step as h and h^2: stage i is clear of the point where its distance |c_i h' -
    d| at the speed r leaves s above its clearance s_c = w_i(h')^(1/3) (round-off ~ s^-3,
    class Policy, ``tangent``: there it carries one tolerance).  Among the steps that clear
    every stage, the longest."""
    c = np.asarray(c, float)
    w = np.asarray(weights, float)
    live = w.max(axis=1) > 0.0
    if not live.any() or not 0.0 < d < h:
        return None

    def clear(hp):
        f = hp / h
        s_c = np.maximum(w[live, 0] * f, w[live, 1] * f * f) ** (1.0 / 3.0)
        return bool((r * np.abs(c[live] * hp - d) >= s_c).all())

    if clear(h):
        return None
    lo = d * (1.0 + EPS ** 0.5)
    cands = np.concatenate([d / (0.5 * (c[1:] + c[:-1])), np.linspace(lo, h, 257)])
    cands = np.sort(cands[(cands >= lo) & (cands < h)])[::-1]
    for hp in cands:
        if clear(hp):
            return float(hp)
    return None


def crossing_time(approach):
    """The time from the last of two states (t, s) to the change point ahead, s the measure
    (linear in the distance to it), extrapolated linearly; None unless s falls."""
    (t1, s1), (t2, s2) = approach
    if not 0.0 < s2 < s1:
        return None
    d = s2 * (t2 - t1) / (s1 - s2)
    return d if np.isfinite(d) else None


def stage_times(tableau):
    """A tableau's stage times in [0, 1], sorted, those of its dense output's extra stages
    included (DOP853's widest gap: 1/3 to 0.6; DP5's: 0.3 to 0.8; RK4's: 0 to 1/2)."""
    return np.unique(np.concatenate([tableau.C, getattr(tableau, "C_EXTRA", ()), [1.0]]))


def clear_step(c, d, lo, hi):
    """The step h in [lo, hi] whose stages lie farthest from a point d ahead, and that
    distance (the step's start and end, states of the run, count as stages): d / c for c
    the middle of a gap between stage times, lo or hi (the farthest lies at one of them),
    the smallest of equals.  With room to choose, the point lies in the middle of the widest
    gap, where an error in d matters least.  c: the stage times (:func:`stage_times`)."""
    h = np.concatenate([d / (0.5 * (c[1:] + c[:-1])), [lo, hi]])
    h = np.sort(h[(h >= lo) & (h <= hi)])
    clear = np.abs(np.outer(h, c) - d).min(axis=1)
    i = int(np.argmax(clear))  # (the first of equals: the smallest step)
    return float(h[i]), float(clear[i])
