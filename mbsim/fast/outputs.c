/* The equations of motion at every output of a run in one call (plain C99).
 *
 * mbsim.analyses.trajectory.build_result needs, at each of the nt output states (t, q, qd)
 * of a kept run, the accelerations and multipliers (the channels' qdd and lam) and the
 * constraint residuals Phi and Phi_q qd - nu on all rows (the drift check and the
 * monitors).  Per output that is one mb_accelerations: its mb_constraints leaves phi, the
 * compact Jacobian Jc and nu of all rows at (q, qd, tv), from which the residuals follow
 * without a second constraint evaluation (mbsim.fast.dynamics.System.accelerations and
 * .residuals make the same calls one output at a time).
 *
 * What is not compiled is evaluated by the caller for all outputs before the call: the time
 * targets of the driven rows TV (nt, nf, 3) and the loads of the Python force elements
 * LOADS (nt, 2, nb, 3) (ForceElement.loads_many).  Either may be NULL (none in the model).
 */
#include <string.h>

#include "mb_model.h" /* the one definition of mb_model, shared with kernels.c */

/* kernels.c */
int mb_accelerations(const mb_model *M, int kkt, int have_jac);
void mb_jac_times(const mb_model *M, const double *x, double *out);

/* Outputs 0..nt-1: Q, QD (nt, nq) the states, TV (nt, nf, 3) or NULL, LOADS (nt, 2*nb*3)
 * or NULL; out QDD (nt, nq), LAM (nt, ma) the active rows' multipliers, PHI, V (nt, m) Phi
 * and Phi_q qd - nu on all rows.  Returns the number of outputs done: nt, or the index of
 * the first whose factorisation failed (its STATUS_* in *status; the caller evaluates that
 * one again to report it). */
int64_t mb_outputs(const mb_model *M, int kkt, idx nt, idx nf, const double *Q,
                   const double *QD, const double *TV, const double *LOADS, double *QDD,
                   double *LAM, double *PHI, double *V, int64_t *status)
{
    idx nq = M->nq, m = M->m, ma = M->ma, nl = 6 * M->nb;
    *status = 0;
    M->par[2] = 0.0; /* no Baumgarte terms */
    for (idx k = 0; k < nt; k++) {
        const double *q = Q + k * nq, *qd = QD + k * nq;
        memcpy(M->q, q, (size_t)nq * sizeof(double));
        memcpy(M->qd, qd, (size_t)nq * sizeof(double));
        if (TV && nf)
            memcpy(M->tv, TV + k * 3 * nf, (size_t)(3 * nf) * sizeof(double));
        if (LOADS)
            memcpy(M->loads, LOADS + k * nl, (size_t)nl * sizeof(double));
        int code = mb_accelerations(M, kkt, 0);
        if (code) {
            *status = code;
            return k;
        }
        memcpy(QDD + k * nq, M->qdd, (size_t)nq * sizeof(double));
        memcpy(LAM + k * ma, M->lam, (size_t)ma * sizeof(double));
        memcpy(PHI + k * m, M->phi, (size_t)m * sizeof(double));
        double *v = V + k * m;
        mb_jac_times(M, M->qd, v);
        for (idx r = 0; r < m; r++)
            v[r] -= M->nu[r];
    }
    return nt;
}
