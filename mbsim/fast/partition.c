/* The step of the coordinate-partitioning integrators (gcp-*) in C (plain C99).
 *
 * Compiled into the same shared library as kernels.c (mbsim.fast._lib) and called through
 * ctypes by mbsim/fast/partition.py for mbsim/integrators/gcp.py, whose module doc gives
 * the method (Wehage & Haug 1982; Haug Sec. 11.4).  A stage in coordinates (v independent,
 * u = the rest) from the stage's (v, vd) and a predicted q (mb_gcp_stage):
 *
 * 1. u solves Phi(u, v, t) = 0 by Newton on Phi_u du = Phi, Phi_u factored by LAPACK's
 *    dgetrf at every iterate; the stop is changepoints.newton's: max |du| <= newton_tol,
 *    or after max_iter iterations max |Phi| <= newton_tol at the last iterate;
 * 2. ud solves Phi_u ud = nu - Phi_v vd on the last iterate's factor;
 * 3. qdd, lam and the power from the equations of motion (mb_accelerations) with the Phi_q
 *    of that iterate, as the Python stage passes it (System.accelerations' jac);
 *
 * and beside them the change-point measure of the last factor (smallest / largest |U_ii|,
 * changepoints.measure_from_lu).  Near a change point the stage is taken in the tangent
 * coordinates v = C q instead (tangent_stage: changepoints.complete and .accelerations).
 * One call takes a whole trial step of the RK tableau from such stages, its change-point
 * alarm, branch test and error norms (mb_gcp_trial); one call all outputs of the last
 * accepted step (mb_gcp_dense).  The step-size control, re-partitioning and every fallback
 * stay in Python, visited once per trial.  The tableau's arithmetic (stage combinations,
 * error norms, interpolants) is step.c's, shared.
 *
 * The last stage's factor stays in LU, piv (in tangent coordinates At, pivA; column-major,
 * LAPACK's 1-based pivots) until the next call: the caller copies it out where it needs it.
 * Nothing here allocates.
 */
#include <math.h>
#include <stdint.h>
#include <string.h>

#include "mb_model.h" /* the one definition of mb_model, shared with kernels.c */

/* step.c */
double mb_rk_error_norm(idx kind, idx ns, idx n, idx ld, const double *K, const double *E,
                        const double *E3, double h, const double *y0, const double *y1,
                        double rtol, double atol);
void mb_rk_combine(const double *K, idx ny, const double *y, const double *a, idx s, double h,
                   double *ys);
void mb_dop853_coefficients(idx ny, idx ns, const double *K, const double *D,
                            const double *y0, const double *y1, double h, double *F);
void mb_rk_interpolate(idx kind, idx ny, idx ns, idx np, const double *K, const double *P,
                       const double *F, const double *y0, const double *y1, double t0,
                       double h, double t, double *y);
enum { ERR_NONE }; /* step.c's error kinds: none, embedded, DOP853's */
enum { DENSE_POLY, DENSE_DOP853, DENSE_HERMITE }; /* step.c's interpolants */

/* kernels.c */
void mb_terms(const mb_model *M, int jac, int gam, int mode);
void mb_applied_forces(const mb_model *M);
void mb_mass_blocks(const mb_model *M);
void mb_gather_dense(const mb_model *M, const double *J, double *Jc);
int mb_accelerations(const mb_model *M, int kkt, int have_jac);
enum { JAC_CALLER = 1 }; /* mb_accelerations' have_jac (kernels.c): Phi_q from Jg */

/* Python's part: fills tv (time targets) and, when forces, the loads of the Python force
 * elements at the q, qd loaded into the model; nonzero: it raised. */
typedef int (*load_fn)(double t, int forces);
typedef void (*getrf_fn)(int *m, int *n, double *a, int *lda, int *ipiv, int *info);
typedef void (*getrs_fn)(char *trans, int *n, int *nrhs, double *a, int *lda, int *ipiv,
                         double *b, int *ldb, int *info);

/* What a call returns. */
enum {
    GP_OK = 0,
    GP_NEWTON = 1,   /* Newton neither stopped moving nor left max |Phi| <= newton_tol */
    GP_SINGULAR = 2, /* Phi_u exactly singular (dgetrf's info > 0) */
    GP_SOLVE = 3,    /* the equations of motion failed (mb_accelerations' code in out) */
    GP_CALLBACK = 4, /* the Python loads raised: the caller takes the stage in Python */
    GP_ALARM = 5,    /* a stage's measure below the policy's switch (mb_gcp_trial) */
    GP_BRANCH = 6,   /* the step's q left the RK solution of the full q (mb_gcp_trial) */
    GP_REDUCED = 7   /* tangent coordinates: the reduced mass matrix T^T M T is singular */
};
enum { GP_FE, GP_CE, GP_FACT, GP_NEWTON_IT, GP_N };
/* out: the last stage's power and measure, the kernels' failure code; the trial's error
 * norm, the time of the stage that failed, the branch test's deviation, and the
 * sensitivity max |Phi_u^-1 Phi_v| at the step's end (an accepted trial) */
enum { P_POWER, P_RATIO, P_CODE, P_ERR, P_T, P_DEV, P_SENS, P_N };

typedef struct {
    idx nq, ma, k;   /* coordinates, dependent (= active rows), independent */
    idx max_iter;
    idx kkt;         /* the model's KKT path */
    idx rheonomic;   /* nu from the driven rows (else zero) */
    double newton_tol;
    load_fn load;    /* NULL: nothing time-dependent or in Python */
    getrf_fn getrf;
    getrs_fn getrs;
    const int64_t *iv, *iu; /* (k,), (ma,) the partition */
    double *LU;      /* (ma, ma) column-major: the LU of the last iterate's Phi_u */
    int *piv;        /* (ma,) its pivots */
    double *x;       /* (ma,) work */
    double *out;     /* (P_N,) P_* */
    int64_t *count;  /* (GP_N,) GP_*: added to, never reset here */
    /* the trial step (mb_gcp_trial): the tableau as step.c reads it, and its buffers */
    idx ns, err_kind;
    double rtol, atol;
    double tangent;  /* the policy's switch: a stage's measure below it is GP_ALARM */
    double branch_jump; /* the branch test's bound in tolerances (INFINITY: no test) */
    const double *A, *B, *C, *E, *E3; /* A (ns, ns) row-major; B, C (ns,); E, E3 (ns + 1,) */
    double *y, *f;   /* (ny,) the step's start and its derivative, ny = 2 k + 1 */
    double *q0, *qd0; /* (nq,) the accepted state's q and qd */
    double *K;       /* (ns + 1, ny) the stages; K[ns] = f(t + h, y_new) */
    double *QD;      /* (ns + 1, nq) every stage's full qd */
    double *ys, *y_new; /* (ny,) */
    double *pred;    /* (nq,) the Newton start of the last stage (the RK combination) */
    double *pred_end; /* (nq,) that of the step's end (the extension's end point) */
    double *q, *qd, *qdd; /* (nq,) the last stage's */
    /* the dense output (mb_gcp_dense): the interpolant's kind and data as step.c reads
     * them; K and QD hold 16 rows (DOP853's extra stages after the step's) */
    idx dense_kind, np;
    const double *P, *AX, *CX, *D; /* P (ns + 1, np); AX (3, 16), CX (3,), D (4, 16) */
    double *Fy, *Fq; /* (7, ny), (7, nq): DOP853's coefficients of y and of the full q */
    double *Z;       /* (k, ma): Phi_u^-1 Phi_v, column by column (the sensitivity) */
    /* tangent coordinates (tangent_stage): v = Ct q; NULL in coordinates */
    const double *Ct; /* (k, nq) row-major */
    double *At;      /* (nq, nq) column-major: the LU of A = [Phi_q; Ct] at the last iterate */
    int *pivA;       /* (nq,) */
    double *T;       /* (k, nq): the basis A^-1 [0; I], column by column; then M T */
    double *p;       /* (nq,) A^-1 [gamma; 0]; then M p */
    double *R;       /* (k, k) column-major: T^T M T, factored */
    int *pivR;       /* (k,) */
    double *w;       /* (nq,) work */
    double *MT;      /* (k, nq): M T, column by column */
    double *ra;      /* (k,) the reduced equations' right-hand side, then v'' */
} mb_gcp;

int64_t mb_gcp_size(void) { return (int64_t)sizeof(mb_gcp); }

/* max |x_i| (NaN if any x_i is NaN). */
static double max_abs(const double *x, idx n)
{
    double r = 0.0;
    for (idx i = 0; i < n; i++) {
        double a = fabs(x[i]);
        r = a > r || a != a ? a : r;
    }
    return r;
}

/* The completed (q, qd) at t into the model with the Python part (time targets, Python
 * force elements); nonzero: that raised. */
static int load_state(const mb_model *M, mb_gcp *G, double t, const double *q,
                      const double *qd)
{
    memcpy(M->q, q, (size_t)G->nq * sizeof(double));
    memcpy(M->qd, qd, (size_t)G->nq * sizeof(double));
    return G->load && G->load(t, 1);
}

/* Phi, Phi_q (dense rows) and nu of a Newton iterate q at t into the model; nonzero: the
 * Python part (time targets) raised. */
static int newton_terms(const mb_model *M, mb_gcp *G, double t, const double *q)
{
    memcpy(M->q, q, (size_t)G->nq * sizeof(double));
    if (G->load && G->load(t, 0))
        return 1;
    G->count[GP_CE]++;
    mb_terms(M, 1, 0, 1);
    return 0;
}

/* LU of Phi_u = J[:, iu] (the dense rows of the last mb_terms) into G->LU. */
static int factor_u(const mb_model *M, mb_gcp *G)
{
    idx n = G->nq, m = G->ma;
    for (idx c = 0; c < m; c++) {
        const double *col = M->J + G->iu[c];
        double *dst = G->LU + c * m;
        for (idx r = 0; r < m; r++)
            dst[r] = col[r * n];
    }
    int mi = (int)m, info = 0;
    G->count[GP_FACT]++;
    G->getrf(&mi, &mi, G->LU, &mi, G->piv, &info);
    return info == 0 ? GP_OK : GP_SINGULAR;
}

static void solve_u(mb_gcp *G, double *b)
{
    int mi = (int)G->ma, one = 1, info = 0;
    char no = 'N';
    G->getrs(&no, &mi, &one, G->LU, &mi, G->piv, b, &mi, &info);
}

/* smallest / largest |U_ii| of the last factor (1 when empty or zero). */
static double pivot_ratio(const mb_gcp *G)
{
    double lo = INFINITY, hi = 0.0;
    for (idx i = 0; i < G->ma; i++) {
        double d = fabs(G->LU[i * G->ma + i]);
        lo = d < lo ? d : lo;
        hi = d > hi ? d : hi;
    }
    return G->ma && hi > 0.0 ? lo / hi : 1.0;
}

/* out (nq, ncol) column-major = M x (same layout), M block diagonal (the model's Mb). */
static void mass_times(const mb_model *M, idx n, const double *x, idx ncol, double *out)
{
    for (idx c = 0; c < ncol; c++)
        for (idx b = 0; b < M->nb; b++) {
            const double *Mb = M->Mb + 49 * b, *xb = x + c * n + 7 * b;
            for (int i = 0; i < 7; i++) {
                double s = 0.0;
                for (int j = 0; j < 7; j++)
                    s += Mb[7 * i + j] * xb[j];
                out[c * n + 7 * b + i] = s;
            }
        }
}

/* A stage in tangent coordinates v = Ct q (changepoints.complete, then
 * changepoints.accelerations): q by Newton on [Phi(q, t); Ct q - v] = 0 through A = [Phi_q;
 * Ct], qd = A^-1 [nu; vd], and qdd from the reduced equations (T^T M T) v'' = T^T (Q - M p),
 * T = A^-1 [0; I], p = A^-1 [gamma; 0], the constraint forces dropping out (T^T Phi_q^T =
 * 0); power = Q.qd - lam.nu with [lam; mu] = A^-T (Q - M qdd).  out[P_SENS] = max |T| (the
 * tangent partition's sensitivity). */
static int tangent_stage(const mb_model *M, mb_gcp *G, double t, const double *v,
                         const double *vd, double *q, double *qd, double *qdd,
                         int accelerations)
{
    idx n = G->nq, m = G->ma, k = G->k;
    int ni = (int)n, one = 1, info = 0, converged = 0;
    char no = 'N', tr = 'T';
    for (int it = 0; it < G->max_iter && !converged; it++) {
        if (newton_terms(M, G, t, q))
            return GP_CALLBACK;
        for (idx c = 0; c < n; c++) {
            double *col = G->At + c * n;
            for (idx r = 0; r < m; r++)
                col[r] = M->J[r * n + c];
            for (idx i = 0; i < k; i++)
                col[m + i] = G->Ct[i * n + c];
        }
        G->count[GP_FACT]++;
        G->getrf(&ni, &ni, G->At, &ni, G->pivA, &info);
        if (info)
            return GP_SINGULAR;
        memcpy(G->w, M->phi_a, (size_t)m * sizeof(double));
        for (idx i = 0; i < k; i++) {
            double s = 0.0;
            for (idx c = 0; c < n; c++)
                s += G->Ct[i * n + c] * q[c];
            G->w[m + i] = s - v[i];
        }
        G->getrs(&no, &ni, &one, G->At, &ni, G->pivA, G->w, &ni, &info);
        for (idx i = 0; i < n; i++)
            q[i] -= G->w[i];
        G->count[GP_NEWTON_IT]++;
        converged = max_abs(G->w, n) <= G->newton_tol; /* NaN: not */
    }
    if (!converged && !(max_abs(M->phi_a, m) <= G->newton_tol))
        return GP_NEWTON;
    for (idx r = 0; r < m; r++)
        qd[r] = G->rheonomic ? M->nu_a[r] : 0.0;
    memcpy(qd + m, vd, (size_t)k * sizeof(double));
    G->getrs(&no, &ni, &one, G->At, &ni, G->pivA, qd, &ni, &info);
    if (!accelerations)
        return GP_OK;
    if (load_state(M, G, t, q, qd))
        return GP_CALLBACK;
    G->count[GP_CE]++;
    mb_terms(M, 0, 1, 0); /* gamma, nu at (q, qd) */
    mb_applied_forces(M);
    mb_mass_blocks(M);
    /* T = A^-1 [0; I], p = A^-1 [gamma; 0] */
    memset(G->T, 0, (size_t)(n * k) * sizeof(double));
    for (idx i = 0; i < k; i++)
        G->T[i * n + m + i] = 1.0;
    int ki = (int)k;
    G->getrs(&no, &ni, &ki, G->At, &ni, G->pivA, G->T, &ni, &info);
    G->out[P_SENS] = max_abs(G->T, n * k);
    memcpy(G->p, M->gamma_a, (size_t)m * sizeof(double));
    memset(G->p + m, 0, (size_t)k * sizeof(double));
    G->getrs(&no, &ni, &one, G->At, &ni, G->pivA, G->p, &ni, &info);
    /* R = T^T M T, rhs = T^T (Q - M p) */
    mass_times(M, n, G->p, 1, G->w);
    for (idx i = 0; i < n; i++)
        G->w[i] = M->Q[i] - G->w[i];
    double *rhs = G->ra, *MT = G->MT;
    mass_times(M, n, G->T, k, MT);
    for (idx a = 0; a < k; a++) {
        double s = 0.0;
        for (idx i = 0; i < n; i++)
            s += G->T[a * n + i] * G->w[i];
        rhs[a] = s;
        for (idx b = 0; b < k; b++) {
            double r = 0.0;
            for (idx i = 0; i < n; i++)
                r += G->T[a * n + i] * MT[b * n + i];
            G->R[b * k + a] = r;
        }
    }
    G->count[GP_FACT]++;
    G->getrf(&ki, &ki, G->R, &ki, G->pivR, &info);
    if (info)
        return GP_REDUCED;
    G->getrs(&no, &ki, &one, G->R, &ki, G->pivR, rhs, &ki, &info);
    for (idx i = 0; i < n; i++) { /* qdd = T v'' + p */
        double s = G->p[i];
        for (idx a = 0; a < k; a++)
            s += G->T[a * n + i] * rhs[a];
        qdd[i] = s;
    }
    double power = 0.0;
    for (idx i = 0; i < n; i++)
        power += M->Q[i] * qd[i];
    if (G->rheonomic) {
        mass_times(M, n, qdd, 1, G->w);
        for (idx i = 0; i < n; i++)
            G->w[i] = M->Q[i] - G->w[i];
        G->getrs(&tr, &ni, &one, G->At, &ni, G->pivA, G->w, &ni, &info);
        for (idx r = 0; r < m; r++)
            power -= G->w[r] * M->nu_a[r];
    }
    G->out[P_POWER] = power;
    return GP_OK;
}

/* One stage (module doc: 1-3).  q: in, the predicted q (its v part is replaced by v); out, the
 * completed q.  qd out; qdd out when accelerations (else q and qd only: an output sample).
 * The model keeps the last iterate's Phi (phi_a: the caller's failure message) and Phi_q. */
int mb_gcp_stage(const mb_model *M, mb_gcp *G, double t, const double *v, const double *vd,
                 double *q, double *qd, double *qdd, int accelerations)
{
    if (G->Ct)
        return tangent_stage(M, G, t, v, vd, q, qd, qdd, accelerations);
    idx n = G->nq, m = G->ma, k = G->k;
    for (idx c = 0; c < k; c++)
        q[G->iv[c]] = v[c];
    int converged = 0, st;
    for (int it = 0; it < G->max_iter && !converged; it++) {
        if (newton_terms(M, G, t, q))
            return GP_CALLBACK;
        if ((st = factor_u(M, G)))
            return st;
        memcpy(G->x, M->phi_a, (size_t)m * sizeof(double));
        solve_u(G, G->x);
        for (idx c = 0; c < m; c++)
            q[G->iu[c]] -= G->x[c];
        G->count[GP_NEWTON_IT]++;
        converged = max_abs(G->x, m) <= G->newton_tol; /* NaN: not */
    }
    if (!converged && !(max_abs(M->phi_a, m) <= G->newton_tol))
        return GP_NEWTON;
    /* ud = Phi_u^-1 (nu - Phi_v vd) on the last factor */
    for (idx r = 0; r < m; r++) {
        const double *Jr = M->J + r * n;
        double s = 0.0;
        for (idx c = 0; c < k; c++)
            s += Jr[G->iv[c]] * vd[c];
        G->x[r] = (G->rheonomic ? M->nu_a[r] : 0.0) - s;
    }
    solve_u(G, G->x);
    for (idx c = 0; c < k; c++)
        qd[G->iv[c]] = vd[c];
    for (idx c = 0; c < m; c++)
        qd[G->iu[c]] = G->x[c];
    G->out[P_RATIO] = pivot_ratio(G);
    if (!accelerations)
        return GP_OK;
    if (load_state(M, G, t, q, qd))
        return GP_CALLBACK;
    M->par[2] = 0.0; /* no Baumgarte terms */
    mb_gather_dense(M, M->J, M->Jg);
    G->count[GP_FE]++;
    G->count[GP_CE]++;
    G->count[GP_FACT]++;
    if ((st = mb_accelerations(M, (int)G->kkt, JAC_CALLER))) {
        G->out[P_CODE] = st;
        return GP_SOLVE;
    }
    memcpy(qdd, M->qdd, (size_t)n * sizeof(double));
    G->out[P_POWER] = M->out[0];
    return GP_OK;
}

/* The branch test's deviation of the last stage's q from its Newton start pred, the rms
 * of (q - pred) / (atol + rtol |pred|) (gcp._check_branch), also left in out[P_DEV]. */
static double branch_deviation(mb_gcp *G)
{
    idx n = G->nq;
    double dev = 0.0;
    for (idx i = 0; i < n; i++) {
        double z = (G->q[i] - G->pred[i]) / (G->atol + G->rtol * fabs(G->pred[i]));
        dev += z * z;
    }
    dev = sqrt(dev / (double)(n > 1 ? n : 1));
    G->out[P_DEV] = dev;
    return dev;
}

/* max |Phi_u^-1 Phi_v| on the last stage's factor and Phi_q (gcp._sensitivity: how far u
 * moves per unit of v, the re-partitioning test at an accepted step). */
static double sensitivity(const mb_model *M, mb_gcp *G)
{
    idx n = G->nq, m = G->ma, k = G->k;
    if (!m || !k)
        return 0.0;
    for (idx c = 0; c < k; c++)
        for (idx r = 0; r < m; r++)
            G->Z[c * m + r] = M->J[r * n + G->iv[c]];
    int mi = (int)m, ki = (int)k, info = 0;
    char no = 'N';
    G->getrs(&no, &mi, &ki, G->LU, &mi, G->piv, G->Z, &mi, &info);
    return max_abs(G->Z, m * k);
}

/* One stage of the trial at t from the state ys, its Newton start the RK combination of
 * the full q with the weights a (s of them): K row and QD row r filled.  alarm: a measure
 * below the switch is GP_ALARM.  Returns GP_*. */
static int trial_stage(const mb_model *M, mb_gcp *G, double t, double h, const double *a,
                       idx s, idx r, int alarm)
{
    idx n = G->nq, k = G->k, ny = 2 * k + 1;
    mb_rk_combine(G->QD, n, G->q0, a, s, h, G->q);
    memcpy(G->pred, G->q, (size_t)n * sizeof(double));
    int st = mb_gcp_stage(M, G, t, G->ys, G->ys + k, G->q, G->qd, G->qdd, 1);
    if (st == GP_OK && alarm && !G->Ct && G->out[P_RATIO] < G->tangent)
        st = GP_ALARM;
    if (st) {
        G->out[P_T] = t;
        return st;
    }
    double *Kr = G->K + r * ny;
    memcpy(Kr, G->ys + k, (size_t)k * sizeof(double));
    for (idx c = 0; c < k; c++) { /* v'' = qdd[iv], or Ct qdd in tangent coordinates */
        double a = 0.0;
        if (G->Ct)
            for (idx i = 0; i < n; i++)
                a += G->Ct[c * n + i] * G->qdd[i];
        else
            a = G->qdd[G->iv[c]];
        Kr[k + c] = a;
    }
    Kr[2 * k] = G->out[P_POWER];
    memcpy(G->QD + r * n, G->qd, (size_t)n * sizeof(double));
    return GP_OK;
}

/* One trial step of size h from (t, y) in coordinates (gcp.GeneralizedCoordinatePartitioning
 * ._trial, then rk.RungeKuttaIntegrator._attempt's error test): the stages, each started from
 * the RK combination of the stages' full velocities (q' = qd with the stage weights); a stage
 * whose measure is below the switch fails the trial (GP_ALARM: Python retries it in tangent
 * coordinates); the end's q against that combination (GP_BRANCH past branch_jump
 * tolerances); then out[P_ERR] = max(the embedded error norm of (v, vd), that of the full q
 * from the stages' qd) when control.  On GP_OK: K, QD, y_new, pred and the last stage's q,
 * qd, qdd (the step's end) filled; the caller compares out[P_ERR] with 1. */
int mb_gcp_trial(const mb_model *M, mb_gcp *G, double t, double h, int control)
{
    idx n = G->nq, k = G->k, ny = 2 * k + 1, ns = G->ns;
    int st;
    G->out[P_ERR] = 0.0;
    memcpy(G->K, G->f, (size_t)ny * sizeof(double));
    memcpy(G->QD, G->qd0, (size_t)n * sizeof(double));
    for (idx s = 1; s < ns; s++) {
        const double *a = G->A + s * ns;
        mb_rk_combine(G->K, ny, G->y, a, s, h, G->ys);
        if ((st = trial_stage(M, G, t + G->C[s] * h, h, a, s, s, 1)))
            return st;
    }
    mb_rk_combine(G->K, ny, G->y, G->B, ns, h, G->y_new);
    memcpy(G->ys, G->y_new, (size_t)ny * sizeof(double));
    if ((st = trial_stage(M, G, t + h, h, G->B, ns, ns, 1)))
        return st;
    memcpy(G->pred_end, G->pred, (size_t)n * sizeof(double));
    if (branch_deviation(G) > G->branch_jump) {
        G->out[P_T] = t + h;
        return GP_BRANCH;
    }
    if (control && G->err_kind != ERR_NONE) {
        double e1 = mb_rk_error_norm(G->err_kind, ns, 2 * k, ny, G->K, G->E, G->E3, h, G->y,
                                     G->y_new, G->rtol, G->atol);
        double e2 = mb_rk_error_norm(G->err_kind, ns, n, n, G->QD, G->E, G->E3, h, G->q0,
                                     G->pred_end, G->rtol, G->atol);
        G->out[P_ERR] = e1 > e2 || e1 != e1 ? e1 : e2;
    }
    if (G->out[P_ERR] <= 1.0) {
        if (!G->Ct)
            G->out[P_SENS] = sensitivity(M, G);
        else if (factor_u(M, G) == GP_OK) /* the coordinate choice's measure, to go back */
            G->out[P_RATIO] = pivot_ratio(G);
        else
            G->out[P_RATIO] = 0.0;
    }
    return GP_OK;
}

/* The dense output of the last accepted trial [t0, t0 + h] (its buffers as mb_gcp_trial
 * left them, the partition the step's) at times[0..nt) (gcp._dense_output_impl): DOP853's
 * three extra stages, each started from the same RK combination of the full velocities
 * and held to the branch test; then per output the interpolant of y = (v, vd, w) and the
 * continuous extension of the full q from the stages' full velocities, q completed from
 * that extension by Newton, and the branch test again.  Q, QDo (nt, nq), W (nt,);
 * flags[i] = 1 where the output failed (Python takes it, with its fallback), else 0.
 * Returns GP_OK, or the status of an extra stage that failed (the interpolant does not
 * exist: Python takes the whole step's outputs). */
int mb_gcp_dense(const mb_model *M, mb_gcp *G, double t0, double h, idx nt,
                 const double *times, double *Q, double *QDo, double *W, int64_t *flags)
{
    idx n = G->nq, k = G->k, ny = 2 * k + 1, ns = G->ns;
    int st;
    if (G->dense_kind == DENSE_DOP853) {
        for (idx e = 0; e < 3; e++) {
            idx s = ns + 1 + e;
            const double *a = G->AX + 16 * e;
            mb_rk_combine(G->K, ny, G->y, a, s, h, G->ys);
            if ((st = trial_stage(M, G, t0 + G->CX[e] * h, h, a, s, s, 0)))
                return st;
            if (branch_deviation(G) > G->branch_jump)
                return GP_BRANCH;
        }
        mb_dop853_coefficients(ny, ns, G->K, G->D, G->y, G->y_new, h, G->Fy);
        mb_dop853_coefficients(n, ns, G->QD, G->D, G->q0, G->pred_end, h, G->Fq);
    }
    for (idx i = 0; i < nt; i++) {
        double t = times[i];
        mb_rk_interpolate(G->dense_kind, ny, ns, G->np, G->K, G->P, G->Fy, G->y, G->y_new, t0,
                          h, t, G->ys);
        mb_rk_interpolate(G->dense_kind, n, ns, G->np, G->QD, G->P, G->Fq, G->q0,
                          G->pred_end, t0, h, t, G->pred);
        double *q = Q + i * n, *qd = QDo + i * n;
        memcpy(q, G->pred, (size_t)n * sizeof(double));
        st = mb_gcp_stage(M, G, t, G->ys, G->ys + k, q, qd, NULL, 0);
        memcpy(G->q, q, (size_t)n * sizeof(double));
        flags[i] = st != GP_OK || branch_deviation(G) > G->branch_jump;
        W[i] = G->ys[2 * k];
    }
    return GP_OK;
}
