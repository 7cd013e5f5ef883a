/* The step of the explicit Runge-Kutta integrators of the index-1 family, in C (plain C99).
 *
 * Compiled into the same shared library as kernels.c (mbsim.fast._lib builds both; the
 * source hash covers both) and called through ctypes by mbsim/fast/stepper.py.  One call
 * takes one whole trial step of an explicit RK tableau on y = (q, qd, w), y' = (qd, qdd,
 * power) (Haug Sec. 11.3; mbsim/integrators/index1.py): the stages, each through
 * mb_accelerations, the embedded error norm in the scale of mbsim/integrators/rk.py, and,
 * when the step is accepted, the mass-weighted projection of q and qd onto the constraints
 * and the derivative there (FSAL) (mb_rk_trial).  A second call evaluates the step's dense
 * output at all output times inside it at once, each projected as the step's end is
 * (mb_rk_dense).  A third takes accepted steps up to the last of a window of output times
 * with the step-size controller of mbsim/integrators/base.py and the change-point
 * approach's bookkeeping (mb_rk_steps), writing the outputs of each step as it goes (the
 * per-sample work of mb_rk_dense, dense_sample) and, for the error estimate's coarse
 * companion, following a mesh of step ends without error control.  The change-point
 * policy and every fallback stay in Python: a call returns as soon as something needs them
 * (a status below).
 *
 * The tableau is data (mbsim/integrators/rk.py's class data, passed in as arrays); nothing
 * here allocates.
 */
#include <math.h>
#include <stdint.h>
#include <string.h>

#include "mb_model.h" /* the one definition of mb_model, shared with kernels.c */

/* kernels.c */
int mb_accelerations(const mb_model *M, int kkt, int have_jac);
enum { JAC_HERE = 0, JAC_FACTORED = 2 }; /* mb_accelerations' have_jac (kernels.c) */
void mb_constraints(const mb_model *M, int jac, int gam);
int mb_project(const mb_model *M, int unit);
void mb_project_factored(const mb_model *M);
void mb_jac_times(const mb_model *M, const double *x, double *out);

/* What a call returns. */
enum {
    ST_ACCEPTED = 0,  /* err <= 1: y_acc, f_acc hold the projected end and its derivative */
    ST_REJECTED = 1,  /* err > 1 */
    ST_SOLVE = 2,     /* a factorisation failed (code of mb_accelerations / mb_project in
                         out[O_CODE]) */
    ST_ALARM = 3,     /* a change-point measure below the policy's switch: Python decides */
    ST_PROJECTION = 4, /* the projection did not reach its tolerance (out[O_RES]) */
    ST_NONFINITE = 5, /* the error norm is NaN or inf */
    ST_CALLBACK = 6   /* the Python loads raised: Python takes the step again */
};
enum { O_ERR, O_SMIN, O_SLAST, O_RES, O_CODE, N_OUT };
/* C_KEPT: output samples whose velocities were projected on the factor their positions'
 * projection made (project_sample); C_FRESH: those projected on a fresh one */
enum { C_FE, C_CE, C_FACT, C_NEWTON, C_KEPT, C_FRESH, N_COUNT };
enum { ERR_NONE, ERR_EMBEDDED, ERR_DOP853 };
enum { DENSE_POLY, DENSE_DOP853, DENSE_HERMITE };

/* Python's part of a stage: fills tv (time targets) and, when forces, the loads of the
 * Python force elements at the q, qd loaded into the model; nonzero: it raised. */
typedef int (*load_fn)(double t, int forces);

/* One integrator's view: sizes and options, the tableau, buffers (the caller's). */
typedef struct {
    idx ns;       /* stages (the last stage's derivative at the step's end is K[ns]) */
    idx nq;
    idx err_kind; /* ERR_*: none (fixed step), E (ns+1) weights, DOP853's E5/E3 */
    idx dense_kind; /* DENSE_*: y0 + h K^T P [x, x^2, ..], DOP853's, cubic Hermite */
    idx np;       /* columns of P (DENSE_POLY) */
    idx project;  /* 1: project q, qd after an accepted step and at every output */
    idx kkt;      /* the model's KKT path (identity metric in the projections) */
    idx stab;     /* Baumgarte terms in gamma (alpha, beta) */
    idx reuse;    /* 1: an output sample's velocities on its positions' factor (project_sample) */
    double rtol, atol;
    double tangent;   /* the change-point policy's switch (0: off) */
    double proj_tol;  /* projection tolerance on max |Phi| */
    double proj_fail; /* an unconverged projection above this residual fails the step */
    double alpha, beta;
    load_fn load;     /* NULL: nothing time-dependent or in Python */
    const double *A;  /* (ns, ns) row-major */
    const double *B, *C; /* (ns,) */
    const double *E, *E3; /* (ns + 1,): E (or E5) and E3 of DOP853 */
    const double *P;  /* (ns + 1, np) (DENSE_POLY) */
    const double *AX; /* (3, 16) DOP853's extra stages, row-major */
    const double *CX; /* (3,) */
    const double *D;  /* (4, 16) DOP853's dense-output weights */
    double *y, *f;    /* (ny,) the state at the step's start and its derivative */
    double *K;        /* (16, ny): the stages; K[ns] = f(t + h, y_new) */
    double *y_new, *y_acc, *f_acc; /* (ny,) */
    double *ys;       /* (ny,) work: a stage's state */
    double *vm;       /* (m,) work: Phi_q qd on all rows */
    double *qw;       /* (nq,) work: an output's q after one Newton step */
    double *Fd;       /* (7, ny) work: DOP853's interpolation coefficients */
    double *out;      /* (N_OUT,) O_* */
    int64_t *count;   /* (N_COUNT,) C_*: added to, never reset here */
} mb_rk;

int64_t mb_rk_size(void) { return (int64_t)sizeof(mb_rk); }

/* q, qd into the model's inputs and Python's part at t. */
static int load_state(const mb_model *M, const mb_rk *R, double t, const double *q,
                      const double *qd, int forces)
{
    idx n = R->nq;
    memcpy(M->q, q, (size_t)n * sizeof(double));
    if (qd)
        memcpy(M->qd, qd, (size_t)n * sizeof(double));
    return R->load && R->load(t, forces) ? ST_CALLBACK : ST_ACCEPTED;
}

/* f = y'(t, y) = (qd, qdd, power) (index1.Index1._rhs); the change-point measure
 * s = sqrt(smallest Schur pivot ratio) (changepoints.measure_from_schur) into out.
 * factored: the model's Phi_q and Schur factor are those of y's q at t (right after
 * project_state at the same t and q: mb_accelerations' JAC_FACTORED). */
static int rhs_at(const mb_model *M, mb_rk *R, double t, const double *y, double *f,
                  int factored)
{
    idx n = R->nq;
    if (load_state(M, R, t, y, y + n, 1))
        return ST_CALLBACK;
    M->par[0] = R->alpha;
    M->par[1] = R->beta;
    M->par[2] = R->stab ? 1.0 : 0.0;
    R->count[C_FE]++;
    R->count[C_CE]++;
    if (!factored || R->kkt)
        R->count[C_FACT]++;
    int code = mb_accelerations(M, (int)R->kkt, factored ? JAC_FACTORED : JAC_HERE);
    if (code) {
        R->out[O_CODE] = code;
        return ST_SOLVE;
    }
    double s = sqrt(M->out[1] > 0.0 ? M->out[1] : 0.0);
    R->out[O_SLAST] = s;
    if (s < R->out[O_SMIN])
        R->out[O_SMIN] = s;
    if (s < R->tangent)
        return ST_ALARM;
    memcpy(f, y + n, (size_t)n * sizeof(double));
    memcpy(f + n, M->qdd, (size_t)n * sizeof(double));
    f[2 * n] = M->out[0];
    return ST_ACCEPTED;
}

static int rhs(const mb_model *M, mb_rk *R, double t, const double *y, double *f)
{
    return rhs_at(M, R, t, y, f, 0);
}

/* max |Phi| on the active rows at M->q (after mb_constraints). */
static double phi_max(const mb_model *M)
{
    double r = 0.0;
    for (idx k = 0; k < M->ma; k++) {
        double a = fabs(M->phi[M->rows[k]]);
        if (a > r || a != a)
            r = a;
    }
    return r;
}

/* The projection's correction dq for the right-hand side in M->rhs: on the Schur factor
 * already computed at this q when factored (and not kkt), else factored here.  Returns 0,
 * or the kernels' failure code (also left in R->out[O_CODE]). */
static int projection_solve(const mb_model *M, mb_rk *R, int factored)
{
    if (factored && !R->kkt) {
        mb_project_factored(M);
        return 0;
    }
    R->count[C_FACT]++;
    int code = mb_project(M, (int)R->kkt);
    if (code)
        R->out[O_CODE] = code;
    return code;
}

/* Mass-weighted Newton projection of q onto Phi(q, t) = 0 (System.project_positions):
 * q updated in place; *res the last max |Phi|; returns 1 converged, 0 not, or -ST_* on
 * a failure.  *factored (in and out): 1 when the model's Phi, Phi_q and, unless kkt, its
 * Schur factor are already those of q at t (a derivative just evaluated there), so the
 * first iteration evaluates and factors nothing; on return, whether the factor is still
 * that of the (final) q.  *steps (when not NULL): the Newton steps taken (after one, the
 * model holds the factor of q one correction before the final q). */
static int project_positions(const mb_model *M, mb_rk *R, double t, double *q, int max_iter,
                             double *res, int *factored, int *steps)
{
    idx n = R->nq;
    if (steps)
        *steps = 0;
    for (int it = 0; it <= max_iter; it++) {
        if (!*factored) {
            R->count[C_CE]++;
            if (load_state(M, R, t, q, NULL, 0))
                return -ST_CALLBACK;
            mb_constraints(M, 1, 0);
        }
        *res = phi_max(M);
        if (*res <= R->proj_tol)
            return 1;
        if (it == max_iter)
            break;
        R->count[C_NEWTON]++;
        for (idx k = 0; k < M->ma; k++)
            M->rhs[k] = M->phi[M->rows[k]];
        if (projection_solve(M, R, *factored))
            return -ST_SOLVE;
        *factored = 0; /* q moves: its Phi, Phi_q and factor are evaluated next */
        if (steps)
            (*steps)++;
        for (idx i = 0; i < n; i++)
            q[i] -= M->dq[i];
    }
    return 0;
}

/* qd projected onto Phi_q qd = nu at q (System.project_velocities), in place.  Phi_q and
 * nu are already those of q at t (project_positions' last evaluation); factored: so is the
 * Schur factor (unless kkt).  Afterwards the factor is that of q (unless kkt). */
static int project_velocities(const mb_model *M, mb_rk *R, double t, const double *q,
                              double *qd, int factored)
{
    if (load_state(M, R, t, q, qd, 0))
        return ST_CALLBACK;
    mb_jac_times(M, M->qd, R->vm);
    for (idx k = 0; k < M->ma; k++) {
        idx r = M->rows[k];
        M->rhs[k] = R->vm[r] - M->nu[r];
    }
    if (projection_solve(M, R, factored))
        return ST_SOLVE;
    for (idx i = 0; i < R->nq; i++)
        qd[i] = M->qd[i] - M->dq[i];
    return ST_ACCEPTED;
}

/* (q, qd) put on Phi = 0, Phi_q qd = nu, in place (Index1._project): ST_PROJECTION when
 * the positions' Newton iteration stops above proj_fail.  factored: the model's terms and
 * Schur factor are those of q at t already (project_positions). */
static int project_state(const mb_model *M, mb_rk *R, double t, double *q, double *qd,
                         int factored)
{
    double res = 0.0;
    int ok = project_positions(M, R, t, q, 10, &res, &factored, NULL);
    R->out[O_RES] = res;
    if (ok < 0)
        return -ok;
    if (!ok && res > R->proj_fail)
        return ST_PROJECTION;
    return project_velocities(M, R, t, q, qd, factored);
}

/* The RMS norm of a - b in the scale of q over the step (atol + rtol max(|y0|, |y_acc|),
 * Index1._dense_output_impl's ``scale``). */
static double rms_diff(const mb_rk *R, const double *a, const double *b, idx n)
{
    double s = 0.0;
    for (idx i = 0; i < n; i++) {
        double z = (a[i] - b[i]) / (R->atol + R->rtol * fmax(fabs(R->y[i]), fabs(R->y_acc[i])));
        s += z * z;
    }
    return sqrt(s / (double)(n > 1 ? n : 1));
}

/* The embedded error norm of a trial (rk.Tableau.error_norm, rk.Dop853.error_norm) of kind
 * ERR_EMBEDDED or ERR_DOP853 on the first n components of the stages K ((ns + 1) rows of ld
 * values), in the scale atol + rtol max(|y0|, |y1|) (rk.RungeKuttaIntegrator._scale).
 * Shared with partition.c (coordinate partitioning's (v, vd) and its full q). */
double mb_rk_error_norm(idx kind, idx ns, idx n, idx ld, const double *K, const double *E,
                        const double *E3, double h, const double *y0, const double *y1,
                        double rtol, double atol)
{
    if (kind == ERR_EMBEDDED) {
        double s = 0.0;
        for (idx i = 0; i < n; i++) {
            double e = 0.0;
            for (idx j = 0; j <= ns; j++)
                e += K[j * ld + i] * E[j];
            double z = h * e / (atol + rtol * fmax(fabs(y0[i]), fabs(y1[i])));
            s += z * z;
        }
        return sqrt(s / (double)(n > 1 ? n : 1));
    }
    double e5 = 0.0, e3 = 0.0;
    for (idx i = 0; i < n; i++) {
        double a = 0.0, b = 0.0;
        for (idx j = 0; j <= ns; j++) {
            a += K[j * ld + i] * E[j];
            b += K[j * ld + i] * E3[j];
        }
        double sc = atol + rtol * fmax(fabs(y0[i]), fabs(y1[i]));
        a /= sc;
        b /= sc;
        e5 += a * a;
        e3 += b * b;
    }
    if (e5 == 0.0 && e3 == 0.0)
        return 0.0;
    return fabs(h) * e5 / sqrt((e5 + 0.01 * e3) * (double)n);
}

/* The error norm of the trial on the 2 nq components of q and qd. */
static double error_norm(const mb_rk *R, double h)
{
    return mb_rk_error_norm(R->err_kind, R->ns, 2 * R->nq, 2 * R->nq + 1, R->K, R->E, R->E3,
                            h, R->y, R->y_new, R->rtol, R->atol);
}

/* ys = y + h sum_{j < s} a[j] K[j] (a stage's state; K: rows of ny values; shared with
 * partition.c).  Each component summed in the order j = 0, 1, .. as a scalar loop over j would, from +0, the tableau's zeros (a quarter of
 * DOP853's) skipped: adding their +-0 products to a sum that starts at +0 changes no bit.
 * Four components at a time, their sums kept in registers over the stages (one load of K
 * per product instead of a load and a store of ys as well): the same operations in the
 * same order, so the same bits. */
void mb_rk_combine(const double *K, idx ny, const double *y, const double *a, idx s, double h,
                   double *ys)
{
    idx nz = 0;
    const double *Ks[16];
    double as[16];
    for (idx j = 0; j < s; j++) /* s <= 15: K has 16 rows */
        if (a[j] != 0.0) {
            Ks[nz] = K + j * ny;
            as[nz++] = a[j];
        }
    idx i = 0;
    for (; i + 4 <= ny; i += 4) {
        double s0 = 0.0, s1 = 0.0, s2 = 0.0, s3 = 0.0;
        for (idx k = 0; k < nz; k++) {
            const double *Kj = Ks[k] + i, aj = as[k];
            s0 += Kj[0] * aj;
            s1 += Kj[1] * aj;
            s2 += Kj[2] * aj;
            s3 += Kj[3] * aj;
        }
        ys[i] = y[i] + h * s0;
        ys[i + 1] = y[i + 1] + h * s1;
        ys[i + 2] = y[i + 2] + h * s2;
        ys[i + 3] = y[i + 3] + h * s3;
    }
    for (; i < ny; i++) {
        double s0 = 0.0;
        for (idx k = 0; k < nz; k++)
            s0 += Ks[k][i] * as[k];
        ys[i] = y[i] + h * s0;
    }
}

/* ys = y + h sum_{j < s} a[j] K[j] on the trial's stages (y = (q, qd, w)). */
static void combine(const mb_rk *R, const double *y, const double *a, idx s, double h,
                    double *ys)
{
    mb_rk_combine(R->K, 2 * R->nq + 1, y, a, s, h, ys);
}

/* One trial step of size h from (t, y) with y' = f (rk.RungeKuttaIntegrator._trial, then
 * its error test and Index1._accept).  K[0..ns] the stages and f(t + h, y_new); out[O_ERR]
 * the error norm (0 without control); out[O_SMIN] the smallest measure of the trial's
 * stages, out[O_SLAST] that of the last derivative.  ST_ACCEPTED: y_acc, f_acc the
 * (projected) end and its derivative. */
int mb_rk_trial(const mb_model *M, mb_rk *R, double t, double h)
{
    idx n = R->nq, ny = 2 * n + 1, ns = R->ns;
    double *K = R->K;
    int st;
    R->out[O_ERR] = 0.0;
    R->out[O_SMIN] = INFINITY;
    memcpy(K, R->f, (size_t)ny * sizeof(double));
    for (idx s = 1; s < ns; s++) {
        combine(R, R->y, R->A + s * ns, s, h, R->ys);
        if ((st = rhs(M, R, t + R->C[s] * h, R->ys, K + s * ny)))
            return st;
    }
    combine(R, R->y, R->B, ns, h, R->y_new);
    if ((st = rhs(M, R, t + h, R->y_new, K + ns * ny)))
        return st;
    if (R->err_kind != ERR_NONE) {
        double err = error_norm(R, h);
        R->out[O_ERR] = err;
        if (!isfinite(err))
            return ST_NONFINITE;
        if (err > 1.0)
            return ST_REJECTED;
    }
    memcpy(R->y_acc, R->y_new, (size_t)ny * sizeof(double));
    if (!R->project) {
        memcpy(R->f_acc, K + ns * ny, (size_t)ny * sizeof(double));
        return ST_ACCEPTED;
    }
    /* y_acc = y_new, whose derivative (K[ns]) left its Phi, Phi_q and Schur factor in the
     * model: the projection starts from them */
    if ((st = project_state(M, R, t + h, R->y_acc, R->y_acc + n, 1)))
        return st;
    return rhs_at(M, R, t + h, R->y_acc, R->f_acc, 1); /* S factored by the projection */
}

/* -- dense output ------------------------------------------------------------------------ */

/* F (7, ny): DOP853's interpolation coefficients (rk.Dop853.dense) from the 16 stage rows
 * K (ny values each: the step's ns + 1 and the three extra ones), y0 and y1 the step's ends.
 * Shared with partition.c. */
void mb_dop853_coefficients(idx ny, idx ns, const double *K, const double *D,
                            const double *y0, const double *y1, double h, double *F)
{
    for (idx i = 0; i < ny; i++) {
        double dy = y1[i] - y0[i];
        F[i] = dy;
        F[ny + i] = h * K[i] - dy;
        F[2 * ny + i] = 2.0 * dy - h * (K[ns * ny + i] + K[i]);
        for (idx r = 0; r < 4; r++) {
            double acc = 0.0;
            for (idx j = 0; j < 16; j++)
                acc += D[16 * r + j] * K[j * ny + i];
            F[(3 + r) * ny + i] = h * acc;
        }
    }
}

/* DOP853's three extra stages (K[ns + 1 ..], from the step's unprojected stages) and its
 * interpolation coefficients Fd (rk.Dop853.dense); y0 = R->y, y1 = R->y_new, K[0..ns]
 * as the accepted trial left them. */
static int dop853_coefficients(const mb_model *M, mb_rk *R, double t0, double h)
{
    idx n = R->nq, ny = 2 * n + 1, ns = R->ns;
    double *K = R->K;
    int st;
    for (idx e = 0; e < 3; e++) {
        idx s = ns + 1 + e;
        combine(R, R->y, R->AX + 16 * e, s, h, R->ys);
        if ((st = rhs(M, R, t0 + R->CX[e] * h, R->ys, K + s * ny)))
            return st;
    }
    mb_dop853_coefficients(ny, ns, K, R->D, R->y, R->y_new, h, R->Fd);
    return ST_ACCEPTED;
}

/* y (ny,) = the interpolant of kind DENSE_* at t in [t0, t0 + h] (rk.Tableau.dense and its
 * subclasses'), from the ends y0, y1, the stages K (rows of ny values; K[ns] the end's
 * derivative) with P (ns + 1, np) for DENSE_POLY, or F (7, ny) for DENSE_DOP853.  Shared
 * with partition.c. */
void mb_rk_interpolate(idx kind, idx ny, idx ns, idx np, const double *K, const double *P,
                       const double *F, const double *y0, const double *y1, double t0,
                       double h, double t, double *y)
{
    double x = (t - t0) / h;
    if (kind == DENSE_DOP853) {
        for (idx i = 0; i < ny; i++) {
            double v = 0.0;
            for (idx k = 0; k < 7; k++) {
                v += F[(6 - k) * ny + i];
                v *= k % 2 == 0 ? x : 1.0 - x;
            }
            y[i] = v + y0[i];
        }
    } else if (kind == DENSE_POLY) {
        for (idx i = 0; i < ny; i++) {
            double v = 0.0, xp = 1.0;
            for (idx c = 0; c < np; c++) {
                double qc = 0.0;
                for (idx j = 0; j <= ns; j++)
                    qc += K[j * ny + i] * P[j * np + c];
                xp *= x;
                v += qc * xp;
            }
            y[i] = y0[i] + h * v;
        }
    } else { /* cubic Hermite from the end-point slopes K[0], K[ns] (base.hermite) */
        double h00 = (1 + 2 * x) * (1 - x) * (1 - x), h10 = x * (1 - x) * (1 - x);
        double h01 = x * x * (3 - 2 * x), h11 = x * x * (x - 1);
        for (idx i = 0; i < ny; i++)
            y[i] = h00 * y0[i] + h10 * h * K[i] + h01 * y1[i] + h11 * h * K[ns * ny + i];
    }
}

/* y (ny,) = the interpolant of the last step at t, unprojected. */
static void interpolate(const mb_rk *R, double t0, double h, double t, double *y)
{
    mb_rk_interpolate(R->dense_kind, 2 * R->nq + 1, R->ns, R->np, R->K, R->P, R->Fd, R->y,
                      R->y_new, t0, h, t, y);
}

/* Whether the projection's correction at the step's end (y_acc - y_new) is blended into
 * the step's samples: 1 when the end was moved. */
static int dense_blend(const mb_rk *R)
{
    for (idx i = 0; i < 2 * R->nq + 1; i++)
        if (R->y_acc[i] != R->y_new[i])
            return 1;
    return 0;
}

/* An output sample's velocities on the factor its positions' projection made.  The
 * positions' Newton iteration (project_positions, as the step's end is projected) factors
 * S~ = Phi_q Mt^-1 Phi_q^T at the interpolated q~ and corrects it, usually once, by dq, of
 * the size of the interpolant's error; the velocities were then projected on a second,
 * fresh factor at the projected q = q~ - dq.  The simplified iteration on the first,
 *     qd <- qd - D~ S~^-1 (Phi_q(q) qd - nu(q)),   D~ = Mt^-1 Phi_q^T at q~
 * (mb_project_factored on the factor, Mt^-1 and Phi_q the model holds from q~), ends on
 * Phi_q(q) qd = nu to round-off, as the fresh projection does, and contracts by about
 * ||I - Phi_q(q) D~ S~^-1||, which is O(|dq|): medians 1e-7 to 3e-6 per iteration on the
 * samples of tests/integrators/test_output_projection.py, so one iteration and one more
 * evaluation of the residual to see it (a second iteration on a fifth of the
 * slider-crank's).  Its end differs from the Mt-orthogonal projection at q by the change
 * of D over dq times the velocities' correction, both of the size of the interpolant's
 * error: second order (measured <= 3e-5 of the step's error scale).  Refreshing D at q
 * (Mt^-1 and Phi_q's incidence blocks) would make the end that projection to round-off,
 * for 0.4-3 us a sample, 25-50 % of what the iteration saves (governor, slider-crank, four
 * cranks).  (The end's factor, one step away, was measured as the positions' iteration
 * matrix too: it contracts by 0.05-0.5 on the governor's DOP853 steps and expands 100 x
 * where a light body turns far in a step, the slider-crank's crank (J'_yy = 1e-5 kg m^2);
 * its extra iterations cost more than the factorisations saved on the governor, the
 * slider-crank, the four cranks and a 40-link chain: docs/benchmarks.md.)
 * KEPT_RATE: an iteration must shrink the residual by this factor; at a contraction
 * rho <= 1/2 the distance left to the fixed point, <= rho / (1 - rho) times the last
 * correction, is at most that correction.  KEPT_ITER: iterations allowed; a factorisation
 * costs 4-7 solves on the same rows (governor 3.1 / 0.66 us, four cranks 10.0 / 1.5 us), so
 * beyond 4 the fresh factor is the cheaper.  Either exceeded (near a change point S is
 * ill-conditioned and its factor raised: kernels.c, PIVOT_FLOOR), the velocities are
 * projected on a fresh factor, as before.  VEL_ROUNDOFF: a row of Phi_q qd - nu sums at most
 * 14 products and nu, so its computed value carries up to ~15 eps times the sum of their
 * magnitudes (Higham, Accuracy and Stability of Numerical Algorithms, 2002, Sec. 3.1):
 * below 16 eps of a bound of that sum it cannot be told from zero. */
#define KEPT_RATE 0.5
#define KEPT_ITER 4
#define VEL_ROUNDOFF (16.0 * 2.220446049250313e-16)

/* M->rhs (ma,) = Phi_q qd - nu on the active rows (Jc and nu of the model's q); returns the
 * largest |rhs_k| relative to its round-off scale sum_c |Phi_q,kc| max|qd| + |nu_k| (a bound
 * of the products' magnitudes: a row whose own qd components are round-off of the others',
 * as a body at rest, is measured against the velocities' size; 0/0: 0). */
static double velocity_residual(const mb_model *M, const double *qd, idx n)
{
    double worst = 0.0, vmax = 0.0;
    for (idx i = 0; i < n; i++)
        vmax = fmax(vmax, fabs(qd[i]));
    for (idx k = 0; k < M->ma; k++) {
        idx r = M->rows[k], b0 = M->rb[2 * r], b1 = M->rb[2 * r + 1];
        const double *Jr = M->Jc + 14 * r;
        double s = 0.0, a = 0.0;
        for (int c = 0; c < 7; c++) {
            s += Jr[c] * qd[7 * b0 + c];
            a += fabs(Jr[c]);
        }
        if (b1 >= 0)
            for (int c = 0; c < 7; c++) {
                s += Jr[7 + c] * qd[7 * b1 + c];
                a += fabs(Jr[7 + c]);
            }
        s -= M->nu[r];
        a = a * vmax + fabs(M->nu[r]);
        M->rhs[k] = s;
        double e = a > 0.0 ? fabs(s) / a : fabs(s);
        if (e > worst || e != e)
            worst = e;
    }
    return worst;
}

/* qd put on Phi_q qd = nu (to round-off) at the model's q (Phi_q and nu evaluated there) in
 * place, by the simplified iteration on the Schur factor, Mt^-1 and incidence blocks the
 * model holds from a nearby q (above).  Returns 1 done; 0 when an iteration did not
 * contract by KEPT_RATE or took more than KEPT_ITER (qd moved: the caller starts again from
 * the sample). */
static int velocities_on_factor(const mb_model *M, mb_rk *R, double *qd)
{
    double prev = INFINITY;
    for (int it = 0;; it++) {
        double e = velocity_residual(M, qd, R->nq);
        if (e <= VEL_ROUNDOFF)
            return 1;
        if (it == KEPT_ITER || !(e <= KEPT_RATE * prev))
            return 0;
        prev = e;
        mb_project_factored(M);
        for (idx i = 0; i < R->nq; i++)
            qd[i] -= M->dq[i];
    }
}

/* (q, qd) of an output sample at t (y: the sample) put on the constraints as project_state
 * puts them, the velocities on the factor of the positions' last Newton step (above) where
 * there is one and it serves, counted in C_KEPT, else on a fresh one, in C_FRESH.  Returns
 * what project_state returns. */
static int project_sample(const mb_model *M, mb_rk *R, double t, double *q, double *qd,
                          const double *y)
{
    double res = 0.0;
    int factored = 0, steps;
    int ok = project_positions(M, R, t, q, 10, &res, &factored, &steps);
    R->out[O_RES] = res;
    if (ok < 0)
        return -ok;
    if (!ok && res > R->proj_fail)
        return ST_PROJECTION;
    ok = steps > 0 && velocities_on_factor(M, R, qd);
    R->count[ok ? C_KEPT : C_FRESH]++;
    if (ok)
        return ST_ACCEPTED;
    memcpy(qd, y + R->nq, (size_t)R->nq * sizeof(double));
    return project_velocities(M, R, t, q, qd, 0);
}

/* One sample of the last accepted step [t0, t0 + h] at t (the work of mb_rk_dense per
 * output, shared with mb_rk_steps' outputs): q, qd (nq,), *w the interpolant with the
 * end's correction blended in; when project, q and qd put on the constraints and *flag = 1
 * where that cannot be vouched for (mb_rk_dense), else *flag = 0.  Returns ST_ACCEPTED, or
 * what stopped it (ST_CALLBACK, ST_SOLVE: the caller gives up the step's samples). */
static int dense_sample(const mb_model *M, mb_rk *R, double t0, double h, double t, int blend,
                        int project, double *q, double *qd, double *w, int64_t *flag)
{
    idx n = R->nq, ny = 2 * n + 1;
    double *y = R->ys;
    interpolate(R, t0, h, t, y);
    if (blend) {
        double x = (t - t0) / h;
        for (idx i = 0; i < ny; i++)
            y[i] += x * (R->y_acc[i] - R->y_new[i]);
    }
    *flag = 0;
    memcpy(q, y, (size_t)n * sizeof(double));
    memcpy(qd, y + n, (size_t)n * sizeof(double));
    *w = y[2 * n];
    if (!project)
        return ST_ACCEPTED;
    int st = R->reuse && !R->kkt ? project_sample(M, R, t, q, qd, y)
                                 : project_state(M, R, t, q, qd, 0);
    if (st == ST_CALLBACK)
        return st;
    if (st) {
        *flag = 1;
        return ST_ACCEPTED;
    }
    if (rms_diff(R, q, y, n) > 1.0) { /* the projection's nonlinear part: q after all
                                         * Newton steps against q after the first */
        double res;
        memcpy(R->qw, y, (size_t)n * sizeof(double));
        int fresh = 0;
        int ok = project_positions(M, R, t, R->qw, 1, &res, &fresh, NULL);
        if (ok < 0)
            return -ok;
        if (rms_diff(R, q, R->qw, n) > 1.0)
            *flag = 1;
    }
    return ST_ACCEPTED;
}

/* The dense output of the last accepted step [t0, t0 + h] at times[0..k) (inside it), each
 * sample projected as the step's end (Index1._dense_output_impl): the projection's
 * correction at the end (y_acc - y_new) blended in linearly, then q, qd put on the
 * constraints.  Q, QD (k, nq), W (k,).  flags[i] = 1 where the C path cannot give the
 * output: the projection did not converge, or its nonlinear part exceeds the tolerance
 * (Python integrates to that output instead); 0 otherwise.  Returns ST_ACCEPTED or what
 * stopped the extra stages (ST_ALARM, ST_SOLVE, ST_CALLBACK: Python's dense output
 * takes the whole step then). */
int mb_rk_dense(const mb_model *M, mb_rk *R, double t0, double h, idx k, const double *times,
                double *Q, double *QD, double *W, int64_t *flags)
{
    idx n = R->nq;
    int st;
    if (R->dense_kind == DENSE_DOP853 && (st = dop853_coefficients(M, R, t0, h)))
        return st;
    int blend = dense_blend(R);
    for (idx j = 0; j < k; j++)
        if ((st = dense_sample(M, R, t0, h, times[j], blend, (int)R->project, Q + j * n,
                               QD + j * n, W + j, flags + j)))
            return st;
    return ST_ACCEPTED;
}

/* -- the approach to a change point ------------------------------------------------------ */

/* changepoints.Approach's measure: what its near() and accepted() read and write, written
 * once here; the Python class calls these two functions after each of its steps, and the
 * loop of many steps (mb_rk_steps) after each of its own. */
typedef struct {
    double tangent;        /* the policy's switch (Policy.tangent) */
    double rate;           /* -ds/dt between the last two accepted states (> 0: approaching) */
    double last_t, last_s; /* the last accepted state (NaN: none) */
    double entry;          /* s where the approach began (NaN: no approach) */
} mb_approach;

/* Approach.near(h): s below which a state after a step of size h belongs to the approach:
 * where it began, or the switch plus two steps' fall at the last rate. */
double mb_approach_near(const mb_approach *A, double h)
{
    return isnan(A->entry) ? A->tangent + 2.0 * h * fmax(A->rate, 0.0) : A->entry;
}

/* Approach.accepted's measure after an accepted step of size h to t with s there: the rate
 * from the last state (when t is later), (t, s) the last; then 1 where s >= near(h) (clear of
 * any approach: entry reset), 0 where the state belongs to the approach (entry: the first
 * such s). */
int mb_approach_accepted(mb_approach *A, double t, double h, double s)
{
    if (!isnan(A->last_t) && t > A->last_t)
        A->rate = (A->last_s - s) / (t - A->last_t);
    A->last_t = t;
    A->last_s = s;
    if (s >= mb_approach_near(A, h)) {
        A->entry = NAN;
        return 1;
    }
    if (isnan(A->entry))
        A->entry = s;
    return 0;
}

int64_t mb_approach_size(void) { return (int64_t)sizeof(mb_approach); }

/* -- a loop of accepted steps ------------------------------------------------------------ */

/* The step-size controller's settings and state (mbsim/integrators/base.py: the constants,
 * Integrator._clip, _min_step, _step_factor, _check_progress), in and out. */
typedef struct {
    double t;        /* in: the state's time; out: the last accepted step's end */
    double t_bound, t_stop; /* steps end at t_bound; the loop stops once t >= t_stop */
    double h_abs;    /* in/out: the next step to try */
    double h_max, h_min, h_fixed; /* h_fixed > 0: fixed steps, no error control */
    double err_old;  /* in/out: the PI controller's memory */
    double exponent, beta, safety, min_factor, max_factor;
    double stall_floor; /* stop after a step below stall_floor max(1, |t|) */
    idx max_steps, max_rejects;
    /* out */
    idx steps, rejected; /* accepted steps, and the rejected trials of those steps */
    idx why;         /* LOOP_* */
    double t_old, h_last, s; /* the last accepted step: start, size, measure s at its end */
    double *ends;    /* (max_steps,) out: each accepted step's end time (the run's mesh), or
                        NULL */
    /* the outputs (n_out = 0: none): after each accepted step that reaches times[k_out],
     * the outputs up to its end (within 1e-12 max(1, |t|)) are written, as the driver
     * samples a step (trajectory.step_outputs): before the end the dense output, at or past
     * it the step's end */
    const double *times; /* (n_out,) output times, ascending */
    idx n_out;
    idx k_out;       /* in/out: the next output to write */
    idx project_out; /* 1: each output projected and checked (mb_rk_dense); 0: the plain
                        interpolant (the companion's outputs, estimate.interpolant_many) */
    double *Q, *QD;  /* (n_out, nq) out */
    double *W, *H;   /* (n_out,) out: the integrated power; the size of the output's step */
    int64_t *flags;  /* (n_out,) work */
    /* a mesh of step ends (n_mesh = 0: none): each step ends at the next mesh point after
     * t (or t_bound), h_fixed set to it (estimate.CoarseStepper) */
    const double *mesh; /* (n_mesh,) ascending */
    idx n_mesh;
    idx k_mesh;      /* in/out: where the search for the next mesh point starts */
    /* ap: the integrator's changepoints.Approach (NULL: none): after every accepted step
     * mb_approach_accepted, which updates it; a step
     * whose state belongs to the approach ends the loop (LOOP_NEAR, its measure taken).
     * out ap_h_far: the last step whose state was clear of it (NaN: none) */
    mb_approach *ap;
    double ap_h_far;
} mb_loop;

/* LOOP_OUTPUT: the last accepted step's outputs need Python (an output flagged by
 * dense_sample, or DOP853's extra stages or a sample stopped): none of them is written and
 * k_out is its first output. */
enum { LOOP_STOP, LOOP_NEAR, LOOP_TINY, LOOP_PYTHON, LOOP_OUTPUT };

int64_t mb_loop_size(void) { return (int64_t)sizeof(mb_loop); }

/* base.Integrator._step_factor: Hairer's PI controller. */
static double step_factor(mb_loop *L, double err, int rejected)
{
    if (err <= 1.0) {
        double e = err > 1e-10 ? err : 1e-10;
        double f = L->safety * pow(e, L->exponent + 0.75 * L->beta) * pow(L->err_old, L->beta);
        if (f > L->max_factor)
            f = L->max_factor;
        if (rejected && f > 1.0)
            f = 1.0;
        L->err_old = err > 1e-4 ? err : 1e-4;
        return f;
    }
    double f = L->safety * pow(err, L->exponent + 0.75 * L->beta);
    return f > L->min_factor ? f : L->min_factor;
}

/* Accepted steps from (t, y, f) (the buffers y, f) until t >= t_stop (or t_bound, or
 * max_steps), as RungeKuttaIntegrator._step_impl and Integrator.step take them one by one
 * (the steps' outputs written after each, step_outputs; the approach followed, mb_loop),
 * for a family whose step is mb_rk_trial alone (index-1 outside tangent coordinates).  A
 * step that needs Python is not taken: the loop returns LOOP_PYTHON before it, with every
 * earlier step accepted (a trial's status other than accepted or rejected, a step below the
 * smallest step, max_rejects rejections, a non-finite step or state).  It also returns after
 * a step whose state belongs to the change-point approach `ap` (LOOP_NEAR), and after a step
 * below the stall floor (LOOP_TINY), where the integrator's bookkeeping decides (their outputs left
 * to the driver), and after a step whose outputs need Python (LOOP_OUTPUT).  On return y is the
 * last step's start, y_new, y_acc, f_acc and K its trial (the dense output's data), and
 * t_old, h_last, t, h_abs, err_old, steps, rejected say where the loop is; after
 * LOOP_PYTHON, (t, y, f) is the last accepted state and the rest is the abandoned step's. */
/* The outputs of the step [t0, L->t] just accepted (the mb_loop fields): 0, or 1 when
 * they need Python (LOOP_OUTPUT). */
static int step_outputs(const mb_model *M, mb_rk *R, mb_loop *L, double t0, double h)
{
    idx n = R->nq, k = L->k_out, j = k, ny = 2 * n + 1;
    double t = L->t;
    if (k >= L->n_out || t < L->times[k])
        return 0; /* (within the tolerance below: left to the driver, as before) */
    double eps = 1e-12 * fmax(1.0, fabs(t));
    while (j < L->n_out && L->times[j] <= t + eps)
        j++;
    idx inside = k;
    while (inside < j && L->times[inside] < t)
        inside++;
    if (inside > k) {
        if (R->dense_kind == DENSE_DOP853 && dop853_coefficients(M, R, t0, h))
            return 1;
        int blend = dense_blend(R);
        for (idx i = k; i < inside; i++) {
            if (dense_sample(M, R, t0, h, L->times[i], blend, (int)L->project_out,
                             L->Q + i * n, L->QD + i * n, L->W + i, L->flags + i) ||
                L->flags[i])
                return 1;
            for (idx c = 0; c < n; c++) /* (the driver names a non-finite output) */
                if (!isfinite(L->Q[i * n + c]) || !isfinite(L->QD[i * n + c]))
                    return 1;
        }
    }
    for (idx i = k; i < j; i++) {
        if (i >= inside) { /* at (or, by round-off, past) the step's end: the end */
            memcpy(L->Q + i * n, R->y_acc, (size_t)n * sizeof(double));
            memcpy(L->QD + i * n, R->y_acc + n, (size_t)n * sizeof(double));
            L->W[i] = R->y_acc[ny - 1];
        }
        L->H[i] = h;
    }
    L->k_out = j;
    return 0;
}

int mb_rk_steps(const mb_model *M, mb_rk *R, mb_loop *L)
{
    idx ny = 2 * R->nq + 1;
    L->steps = 0;
    L->rejected = 0;
    L->why = LOOP_STOP;
    while (L->t < L->t_stop && L->t < L->t_bound && L->steps < L->max_steps) {
        if (L->steps > 0) { /* the last step's end is the next step's start */
            memcpy(R->y, R->y_acc, (size_t)ny * sizeof(double));
            memcpy(R->f, R->f_acc, (size_t)ny * sizeof(double));
        }
        if (L->n_mesh > 0) { /* CoarseStepper.step: to the next mesh point */
            double eps = 1e-12 * fmax(1.0, fabs(L->t));
            while (L->k_mesh < L->n_mesh && L->mesh[L->k_mesh] <= L->t + eps)
                L->k_mesh++;
            L->h_fixed = L->h_abs =
                (L->k_mesh < L->n_mesh ? L->mesh[L->k_mesh] : L->t_bound) - L->t;
        }
        double t = L->t, h_abs = L->h_abs < L->h_max ? L->h_abs : L->h_max, h;
        double err_old = L->err_old;
        int rejected = 0;
        idx rejects = 0;
        for (;;) {
            h = h_abs; /* Integrator._clip */
            if (L->h_max < h)
                h = L->h_max;
            if (L->t_bound - t < h)
                h = L->t_bound - t;
            if (L->t_bound - (t + h) < 1e-12 * fmax(1.0, fabs(L->t_bound)))
                h = L->t_bound - t;
            double min_step = fmax(L->h_min, 10.0 * fabs(nextafter(t, INFINITY) - t));
            if (!isfinite(h) || (h < min_step && h < L->t_bound - t) ||
                rejects >= L->max_rejects)
                break;
            int st = mb_rk_trial(M, R, t, h);
            if (st != ST_ACCEPTED && st != ST_REJECTED)
                break;
            if (L->h_fixed > 0.0)
                goto accepted;
            double err = R->out[O_ERR];
            h_abs = h * step_factor(L, err, rejected);
            if (st == ST_ACCEPTED)
                goto accepted;
            rejected = 1;
            rejects++;
        }
        /* this step needs Python: nothing of it is kept (y, f: the state before it) */
        L->err_old = err_old;
        L->why = LOOP_PYTHON;
        return L->why;
    accepted:
        for (idx i = 0; i < ny; i++)
            if (!isfinite(R->y_acc[i])) {
                L->err_old = err_old;
                L->why = LOOP_PYTHON;
                return L->why;
            }
        L->rejected += rejects;
        L->steps++;
        L->t_old = t;
        L->h_last = h;
        L->t = t + h;
        if (L->ends)
            L->ends[L->steps - 1] = L->t;
        L->h_abs = L->h_fixed > 0.0 ? L->h_fixed : h_abs;
        L->s = R->out[O_SLAST];
        if (L->ap && !mb_approach_accepted(L->ap, L->t, h, L->s)) {
            L->why = LOOP_NEAR;
            return L->why;
        }
        if (L->ap)
            L->ap_h_far = h;
        if (h < L->stall_floor * fmax(1.0, fabs(L->t)) && L->t < L->t_bound) {
            L->why = LOOP_TINY;
            return L->why;
        }
        if (L->n_out > 0 && step_outputs(M, R, L, t, h)) { /* (after NEAR and TINY, whose
                                                               outputs the driver takes) */
            L->why = LOOP_OUTPUT;
            return L->why;
        }
    }
    return L->why;
}
