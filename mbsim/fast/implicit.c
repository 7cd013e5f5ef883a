/* The Newton iteration of the implicit index-3 integrators (generalized-alpha and HHT) in C
 * (plain C99).
 *
 * Compiled into the same shared library as kernels.c (mbsim.fast._lib) and called through
 * ctypes by mbsim/fast/implicit.py for mbsim/integrators/genalpha.py, whose module doc gives
 * the method (Arnold & Bruls 2007).  One call takes the whole Newton iteration of one trial
 * step (mb_ga_newton): the predictor, the residual r = M(q) qdd + Phi_q(q)^T lam - Q(q, qd, t)
 * with Phi(q, t) through the kernels, the iteration matrix
 *
 *     [ M + gam'/beta' C + K/beta'   Phi_q^T  ]
 *     [ Phi_q                        -eps I   ]
 *
 * factored at every iterate, and the stopping tests.  A second call (mb_ga_tangent) gives
 * K = dr/dq and C = dr/dqd by forward differences; a third solves on the last factor
 * (mb_ga_solve: the integrator's round-off probe).  The step-size control, the local error
 * estimate and every fallback stay in Python, which is visited once per trial step.
 *
 * The dense iteration matrix is factored by LAPACK's dgetrf / dgetrs, whose addresses the
 * caller passes in (scipy.linalg.cython_lapack's, the same routines as scipy.linalg's
 * lu_factor / lu_solve): this file links against nothing.  On the sparse path (large
 * models) the caller factors and solves through two callbacks (factor, solve) with its
 * sparse LU; everything else stays here.  Nothing here allocates.
 */
#include <math.h>
#include <stdint.h>
#include <string.h>

#include "mb_model.h" /* the one definition of mb_model, shared with kernels.c */

/* kernels.c */
void mb_terms(const mb_model *M, int jac, int gam, int mode);
void mb_applied_forces(const mb_model *M);
void mb_mass_blocks(const mb_model *M);

/* Python's part of a residual: fills tv (time targets) and the loads of the Python force
 * elements at the q, qd loaded into the model; nonzero: it raised. */
typedef int (*load_fn)(double t, int forces);
/* Sparse path: factor the iteration matrix from the model's buffers (Mb, the CSR Jacobian
 * of mb_terms' mode 2) with these coefficients; nonzero: it failed. */
typedef int (*factor_fn)(double bp, double gp, double eps);
/* Sparse path: x (nrhs, nq + ma) row-major solved in place on the last factor; nonzero:
 * it failed. */
typedef int (*solve_fn)(double *x, int64_t nrhs);
typedef void (*getrf_fn)(int *m, int *n, double *a, int *lda, int *ipiv, int *info);
typedef void (*getrs_fn)(char *trans, int *n, int *nrhs, double *a, int *lda, int *ipiv,
                         double *b, int *ldb, int *info);

/* What a call returns. */
enum {
    GA_OK = 0,      /* converged (mb_ga_newton) or done */
    GA_NEWTON = 1,  /* the iteration does not converge, or its matrix is singular */
    GA_CALLBACK = 2 /* the Python loads raised at time out[O_T]: Python raises it again */
};
enum { GC_FE, GC_CE, GC_FACT, GC_NEWTON, GC_JAC, GC_N };
enum { O_POWER, O_T, GO_N };

typedef struct {
    idx nq, ma;
    idx sparse;      /* 1: factor and solve through the callbacks */
    idx rheonomic;   /* power = Q.qd - lam.nu (driven rows) */
    idx use_kc;      /* K and C (the pointers below) enter the iteration matrix */
    idx contraction; /* also stop on the remaining-error bound (GeneralizedAlpha._newton) */
    idx max_newton;
    double am, af, gam, beta;
    double rtol, atol, newton_tol;
    double kkt_reg;  /* genalpha.KKT_REG */
    double roundoff; /* ROUNDOFF_ULPS x eps: the round-off of q per unit of max(1, |q|) */
    load_fn load;    /* NULL: nothing time-dependent or in Python */
    factor_fn factor;
    solve_fn solve;
    getrf_fn getrf;
    getrs_fn getrs;
    const double *mscale; /* (nq,) the size of M per coordinate (GeneralizedAlpha._mass_scale) */
    const int64_t *free;  /* (nq,) 1 where a coordinate gets a difference column (not ground) */
    const double *K, *C;  /* (nq, nq) row-major dr/dq, dr/dqd (use_kc) */
    double *S;            /* (N, N) column-major, N = nq + ma: the LU of the last matrix */
    int *piv;             /* (N,) LAPACK's pivots (int, as cython_lapack declares them) */
    double *r, *r0, *x, *w; /* work: r, r0 (nq), x (N), w (nq) */
    double *out;          /* (GO_N,) O_* */
    int64_t *count;       /* (GC_N,) GC_*: added to, never reset here */
} mb_ga;

int64_t mb_ga_size(void) { return (int64_t)sizeof(mb_ga); }

/* r (nq,) = M(q) qdd + Phi_q(q)^T lam - Q(q, qd, t) on the active rows; the model keeps
 * Phi, Phi_q (compact Jc, and the CSR values on the sparse path), nu, Q and Mb of (q, qd, t)
 * (GeneralizedAlpha's residual). */
static int residual(const mb_model *M, mb_ga *G, double t, const double *q, const double *qd,
                    const double *qdd, const double *lam, double *r)
{
    idx n = G->nq, nb = M->nb;
    memcpy(M->q, q, (size_t)n * sizeof(double));
    memcpy(M->qd, qd, (size_t)n * sizeof(double));
    /* the iterate's multipliers where the loads read them (joint friction's normal load:
     * stepper.load_callback), so that the residual's friction is the iterate's own */
    memcpy(M->lam, lam, (size_t)G->ma * sizeof(double));
    if (G->load && G->load(t, 1)) {
        G->out[O_T] = t;
        return GA_CALLBACK;
    }
    G->count[GC_FE]++;
    G->count[GC_CE]++;
    mb_terms(M, 1, 0, G->sparse ? 2 : 0);
    mb_applied_forces(M);
    mb_mass_blocks(M);
    double *v = G->w; /* Phi_q^T lam */
    memset(v, 0, (size_t)n * sizeof(double));
    for (idx k = 0; k < G->ma; k++) {
        idx row = M->rows[k], b0 = M->rb[2 * row], b1 = M->rb[2 * row + 1];
        const double *Jr = M->Jc + 14 * row;
        for (int c = 0; c < 7; c++)
            v[7 * b0 + c] += Jr[c] * lam[k];
        if (b1 >= 0)
            for (int c = 0; c < 7; c++)
                v[7 * b1 + c] += Jr[7 + c] * lam[k];
    }
    for (idx b = 0; b < nb; b++) {
        const double *Mb = M->Mb + 49 * b, *a = qdd + 7 * b;
        for (int i = 0; i < 7; i++) {
            double s = 0.0;
            for (int j = 0; j < 7; j++)
                s += Mb[7 * i + j] * a[j];
            r[7 * b + i] = (s + v[7 * b + i]) - M->Q[7 * b + i];
        }
    }
    return GA_OK;
}

/* The iteration matrix at the model's last residual, factored (dense: LAPACK into S, piv;
 * sparse: the factor callback).  eps = kkt_reg |Phi_q|^2 / |A| regularises the zero block
 * (GeneralizedAlpha's module doc: near a change point the plain matrix is numerically
 * singular); |Phi_q|^2 the largest squared row norm, |A| the largest |M| entry.  Returns
 * GA_OK or GA_NEWTON. */
static int factor(const mb_model *M, mb_ga *G, double bp, double gp)
{
    idx n = G->nq, m = G->ma, N = n + m, nb = M->nb;
    G->count[GC_FACT]++;
    double jn = 0.0, mmax = 0.0;
    for (idx k = 0; k < m; k++) {
        idx row = M->rows[k], b0 = M->rb[2 * row], b1 = M->rb[2 * row + 1];
        const double *Jr = M->Jc + 14 * row;
        double s = 0.0;
        for (int c = 0; c < 7; c++) {
            double a = Jr[c] + (b1 == b0 ? Jr[7 + c] : 0.0); /* both ends on one body */
            s += a * a;
            if (b1 >= 0 && b1 != b0)
                s += Jr[7 + c] * Jr[7 + c];
        }
        if (s > jn)
            jn = s;
    }
    for (idx i = 0; i < 49 * nb; i++)
        if (fabs(M->Mb[i]) > mmax)
            mmax = fabs(M->Mb[i]);
    double eps = G->kkt_reg * jn / (mmax > 1e-300 ? mmax : 1e-300);
    if (G->sparse)
        return G->factor(bp, gp, eps) ? GA_NEWTON : GA_OK;
    double *S = G->S;
    memset(S, 0, (size_t)(N * N) * sizeof(double));
    for (idx b = 0; b < nb; b++)
        for (int i = 0; i < 7; i++)
            for (int j = 0; j < 7; j++)
                S[(7 * b + i) + N * (7 * b + j)] = M->Mb[49 * b + 7 * i + j];
    if (G->use_kc) {
        double g = gp / bp;
        for (idx i = 0; i < n; i++)
            for (idx j = 0; j < n; j++)
                S[i + N * j] += g * G->C[n * i + j] + G->K[n * i + j] / bp;
    }
    for (idx k = 0; k < m; k++) {
        idx row = M->rows[k], b0 = M->rb[2 * row], b1 = M->rb[2 * row + 1];
        const double *Jr = M->Jc + 14 * row;
        for (int c = 0; c < 7; c++) {
            idx col = 7 * b0 + c;
            S[col + N * (n + k)] += Jr[c];
            S[(n + k) + N * col] += Jr[c];
        }
        if (b1 >= 0)
            for (int c = 0; c < 7; c++) {
                idx col = 7 * b1 + c;
                S[col + N * (n + k)] += Jr[7 + c];
                S[(n + k) + N * col] += Jr[7 + c];
            }
        S[(n + k) + N * (n + k)] = -eps;
    }
    int Ni = (int)N, info = 0;
    G->getrf(&Ni, &Ni, S, &Ni, G->piv, &info);
    return info == 0 ? GA_OK : GA_NEWTON;
}

/* x (nrhs, nq + ma) row-major (each right-hand side contiguous) solved in place on the last
 * factor.  Returns GA_OK or GA_NEWTON. */
int mb_ga_solve(mb_ga *G, double *x, int64_t nrhs)
{
    if (G->sparse)
        return G->solve(x, nrhs) ? GA_NEWTON : GA_OK;
    int N = (int)(G->nq + G->ma), k = (int)nrhs, info = 0;
    char trans = 'N';
    G->getrs(&trans, &N, &k, G->S, &N, G->piv, x, &N, &info);
    return info == 0 ? GA_OK : GA_NEWTON;
}

static double max_abs(const double *x, idx n)
{
    double r = 0.0;
    for (idx i = 0; i < n; i++)
        if (fabs(x[i]) > r)
            r = fabs(x[i]);
    return r;
}

/* The step h from (q0, qd0, qdd0, a, lam) at t1 = t0 + h: q, qd, qdd, lam (lam: in, the
 * start's; out, the step's) and a1 (nq,), power in out[O_POWER] (GeneralizedAlpha._newton,
 * whose docstring gives the stopping tests).  Returns GA_OK, GA_NEWTON or GA_CALLBACK. */
int mb_ga_newton(const mb_model *M, mb_ga *G, double t1, double h, const double *q0,
                 const double *qd0, const double *qdd0, const double *a, double *q, double *qd,
                 double *qdd, double *lam, double *a1)
{
    idx n = G->nq, m = G->ma;
    double am = G->am, af = G->af, gam = G->gam, beta = G->beta;
    for (idx i = 0; i < n; i++) {
        qdd[i] = qdd0[i];
        a1[i] = (af * qdd0[i] - am * a[i] + (1 - af) * qdd[i]) / (1 - am);
        q[i] = q0[i] + h * qd0[i] + h * h * ((0.5 - beta) * a[i] + beta * a1[i]);
        qd[i] = qd0[i] + h * ((1 - gam) * a[i] + gam * a1[i]);
    }
    double bp = (1 - am) / (beta * h * h * (1 - af)), gp = gam / (beta * h);
    double qmax = max_abs(q, n);
    /* the round-off of q (and Phi): |q| changes little within a step */
    double qs = G->roundoff * (qmax > 1.0 ? qmax : 1.0), rf = qs * bp;
    double prev = INFINITY, *r = G->r, *x = G->x;
    int it, st;
    for (it = 0; it < G->max_newton; it++) {
        if ((st = residual(M, G, t1, q, qd, qdd, lam, r)))
            return st;
        if (it > 0) {
            /* both residuals at round-off of q: |Phi| and the coordinate change r / (bp M)
             * that the dynamic residual implies; near a singular position the corrections
             * dq ~ eps / sigma_min(Phi_q) are noise and never meet the test on dq below */
            int at_roundoff = 1;
            for (idx k = 0; k < m && at_roundoff; k++)
                if (!(fabs(M->phi[M->rows[k]]) <= qs))
                    at_roundoff = 0;
            for (idx i = 0; i < n && at_roundoff; i++)
                if (!(fabs(r[i]) <= rf * G->mscale[i]))
                    at_roundoff = 0;
            if (at_roundoff)
                break;
        }
        if (factor(M, G, bp, gp))
            return GA_NEWTON;
        for (idx i = 0; i < n; i++)
            x[i] = -r[i] / bp;
        for (idx k = 0; k < m; k++)
            x[n + k] = -M->phi[M->rows[k]];
        if (mb_ga_solve(G, x, 1))
            return GA_NEWTON;
        for (idx i = 0; i < n + m; i++)
            if (!isfinite(x[i]))
                return GA_NEWTON;
        double s = 0.0;
        for (idx i = 0; i < n; i++) {
            double dq = x[i];
            q[i] += dq;
            qd[i] += gp * dq;
            qdd[i] += bp * dq;
        }
        for (idx k = 0; k < m; k++)
            lam[k] += bp * x[n + k];
        G->count[GC_NEWTON]++;
        for (idx i = 0; i < n; i++) {
            double z = x[i] / (G->atol + G->rtol * fabs(q[i]));
            s += z * z;
        }
        double err = sqrt(s / (double)(n > 1 ? n : 1));
        if (err <= G->newton_tol)
            break;
        if (G->contraction && prev < INFINITY && err < prev
            && err * err / (prev - err) <= G->newton_tol)
            break; /* the remaining error theta / (1 - theta) err is below newton_tol */
        /* corrections at round-off of q (tight tolerances near a singular position):
         * converged as far as double precision allows */
        double qm = max_abs(q, n);
        if (max_abs(x, n) <= 64 * 2.220446049250313e-16 * (qm > 1.0 ? qm : 1.0))
            break;
        if (it >= 2 && err > 0.9 * prev)
            return GA_NEWTON; /* not contracting */
        prev = err;
    }
    if (it == G->max_newton)
        return GA_NEWTON;
    /* the rate of work of applied and driving forces, with Q and nu of the last residual */
    double power = 0.0;
    for (idx i = 0; i < n; i++)
        power += M->Q[i] * qd[i];
    if (G->rheonomic) {
        double d = 0.0;
        for (idx k = 0; k < m; k++)
            d += lam[k] * M->nu[M->rows[k]];
        power -= d;
    }
    G->out[O_POWER] = power;
    for (idx i = 0; i < n; i++)
        a1[i] = (af * qdd0[i] - am * a[i] + (1 - af) * qdd[i]) / (1 - am);
    return GA_OK;
}

/* K = dr/dq, C = dr/dqd (nq, nq) row-major at (q, qd, qdd, lam, t) by forward differences
 * with steps 1.5e-8 max(1, |x_j|) (about sqrt(eps): the truncation and the round-off of a
 * forward difference balance there), columns of ground coordinates zero
 * (GeneralizedAlpha._tangent).  Returns GA_OK or GA_CALLBACK. */
int mb_ga_tangent(const mb_model *M, mb_ga *G, double t, const double *q, const double *qd,
                  const double *qdd, const double *lam, double *K, double *C)
{
    idx n = G->nq;
    double *r0 = G->r0, *r = G->r, *xq = G->x, *xv = G->x + n;
    int st;
    G->count[GC_JAC]++;
    memset(K, 0, (size_t)(n * n) * sizeof(double));
    memset(C, 0, (size_t)(n * n) * sizeof(double));
    if ((st = residual(M, G, t, q, qd, qdd, lam, r0)))
        return st;
    memcpy(xq, q, (size_t)n * sizeof(double));
    memcpy(xv, qd, (size_t)n * sizeof(double));
    for (idx j = 0; j < n; j++) {
        if (!G->free[j])
            continue;
        for (int v = 0; v < 2; v++) { /* column j of K (v = 0: q moved), then of C (qd) */
            double *x = v ? xv : xq, *D = v ? C : K;
            double x0 = x[j], d = 1.5e-8 * (fabs(x0) > 1.0 ? fabs(x0) : 1.0);
            x[j] += d;
            st = residual(M, G, t, v ? q : xq, v ? xv : qd, qdd, lam, r);
            x[j] = x0;
            if (st)
                return st;
            for (idx i = 0; i < n; i++)
                D[n * i + j] = (r[i] - r0[i]) / d;
        }
    }
    return GA_OK;
}
