/* The compiled physics of mbsim: constraint kernels and equations of motion (plain C99).
 *
 * No dependencies, no Python.h: mbsim.fast._lib compiles it with step.c (the integrators' step)
 * into one shared library (at install time through setup.py, else at first use into
 * ~/.cache/mbsim) and calls it through ctypes.  Every table and buffer belongs to the caller
 * (numpy arrays kept alive by mbsim.fast); the pointers arrive once, in an mb_model struct
 * (mb_model.h, shared with step.c) built at construction, so a call passes only that struct
 * and a few flags.  Nothing here allocates.
 *
 * Tables (one line per basic constraint k = 0 .. nc-1, all row-major):
 *   ci (nc, NI) int64: kernel code, body i, body j (-1: one body), first global row, flag
 *                      (dot2: 1 when a is on body j; absolute: axis 0/1/2), time-target index
 *                      (-1: none), the body of each of the three vector slots (-1: unused);
 *   cf (nc, NF) double: the three body-fixed vectors (0-8) and up to six constant targets.
 *   Jc (m, 14): compact Phi_q, columns 0-6 d Phi_r / d[r_i, p_i], 7-13 d Phi_r / d[r_j, p_j].
 *   tv (nf, 3): time targets c(t) (squared where the driver says so), c'(t), c''(t).
 *   bt (nb, NB) per body: mass (0), J' (1-9), J'^-1 (10-18, zero when J' is singular),
 *                      c = 4 tr(J') / 3 (19), weight m g (20-22), 1 / m (23);
 *   ei (ne, 3) / ef (ne, NEF): compiled force elements (EL_*), bodies b1, b2 and data
 *                      (layout by kind above el_tsda, el_tire and in mb_applied_forces);
 *   sidx (4, ma): active rows, Schur order (RCM), envelope first column fc, offset off;
 *   inc (ninc, 3): incidences (active row u, column offset 0/7, body), grouped by body
 *                  (offset + CROSS: left out of S, a body held by its own rows);
 *   pairs (np, 4): envelope index of S[u, v], incidence g_u, incidence g_v, and the bit
 *                      columns where XG[g_u] * JG[g_v] can be nonzero for the kernels' Phi_q
 *                      (pair_dot's code; mbsim/fast/dynamics.py: pair_codes).
 * (mbsim/fast/constraints.py and dynamics.py build them; their module docs say more.)
 *
 * Equations: Haug, Computer-Aided Kinematics and Dynamics of Mechanical Systems (1989),
 * Ch. 6 (Euler parameters), Ch. 9 (basic constraints), Ch. 11 (equations of motion).  Every
 * analysis calls them through mbsim/core.py.  The plain numpy reference of the same
 * equations lives under tests/reference/ (basic.py, equations.py) and serves only the tests
 * (tests/test_kernels.py, tests/test_core.py), which check that both agree to round-off.
 */
#include <math.h>
#include <stdint.h>
#include <string.h>

#include "mb_model.h"

enum { DOT1, DOT2, SPHERICAL, DISTANCE, ANGLE, ABSOLUTE, GROUND, NORMALIZATION };
enum { I_KERNEL, I_BI, I_BJ, I_ROW, I_FLAG, I_FUNC, I_SLOT, NI = 9 };
enum { F_CONST = 9, NF = 15, NB = 24 };
enum { EL_TSDA, EL_FORCE, EL_FORCE_LOCAL, EL_TORQUE, EL_TORQUE_LOCAL, EL_TIRE };
/* Columns of ef (mbsim/fast/dynamics.py: NEF): the widest element's data, the tire's 13
 * (tire_law).  One table for every kind keeps one loop over the elements in the model's
 * order (the loads add up in that order) and one pointer in mb_model; the narrower kinds
 * leave their last columns zero. */
enum { NEF = 13 };
/* The tire law's outputs per tire and state (tire_law, mb_tire_states): F (0-2), n_local
 * (3-5), sc (6-8), v (9-11), u (12-14), F_ver, F_lat, F_roll, alpha, saturated,
 * deflection, speed (15-21) (mbsim/forces/tire.py: TIRE_OUTPUTS). */
enum { TIRE_OUT = 22 };
enum { STATUS_OK = 0, STATUS_NOT_PD = 1, STATUS_SINGULAR = 2 };
enum { JAC_HERE = 0, JAC_CALLER = 1, JAC_FACTORED = 2 }; /* mb_accelerations' have_jac */

#ifndef MB_SOURCE_HASH
#define MB_SOURCE_HASH "unknown"
#endif

/* SHA-256 (16 hex digits) of the kernels.c this library was built from (mbsim.fast._lib
 * compares it with the source beside it, so an edit never runs a stale build). */
const char *mb_source_hash(void) { return MB_SOURCE_HASH; }

static const int NE[8] = {1, 1, 3, 1, 1, 1, 6, 1}; /* equations per constraint, by code */


/* sizeof(mb_model): mbsim.fast._lib checks it against its ctypes mirror at load time. */
int64_t mb_struct_size(void) { return (int64_t)sizeof(mb_model); }

/* -- body-fixed vectors ------------------------------------------------------------------- */

/* One body-fixed vector a' on body b at (q, qd): B = B(p, a') = d(A(p) a')/dp (3, 4)
 * (Haug eq. 9.3.14, homogeneous form of mbsim.rotations.B); val = A a' = B p / 2; when gam,
 * vel = B pd (its rate) and bdot = B(pd, a') pd (the gamma term; B is linear in p). */
typedef struct {
    double B[3][4];
    double val[3], vel[3], bdot[3];
} vec_t;

static void bmat(double e0, double e1, double e2, double e3, const double *a, double B[3][4])
{
    double ea = 2.0 * (e1 * a[0] + e2 * a[1] + e3 * a[2]);
    B[0][0] = 2.0 * (e0 * a[0] + e2 * a[2] - e3 * a[1]);
    B[1][0] = 2.0 * (e0 * a[1] + e3 * a[0] - e1 * a[2]);
    B[2][0] = 2.0 * (e0 * a[2] + e1 * a[1] - e2 * a[0]);
    B[0][1] = ea;
    B[0][2] = 2.0 * (e1 * a[1] - a[0] * e2 + e0 * a[2]);
    B[0][3] = 2.0 * (e1 * a[2] - a[0] * e3 - e0 * a[1]);
    B[1][1] = 2.0 * (e2 * a[0] - a[1] * e1 - e0 * a[2]);
    B[1][2] = ea;
    B[1][3] = 2.0 * (e2 * a[2] - a[1] * e3 + e0 * a[0]);
    B[2][1] = 2.0 * (e3 * a[0] - a[2] * e1 + e0 * a[1]);
    B[2][2] = 2.0 * (e3 * a[1] - a[2] * e2 - e0 * a[0]);
    B[2][3] = ea;
}

static void body_vector(const double *q, const double *qd, idx b, const double *a, int gam,
                        vec_t *v)
{
    const double *p = q + 7 * b + 3;
    bmat(p[0], p[1], p[2], p[3], a, v->B);
    for (int i = 0; i < 3; i++)
        v->val[i] = 0.5 * (v->B[i][0] * p[0] + v->B[i][1] * p[1] + v->B[i][2] * p[2] +
                           v->B[i][3] * p[3]);
    if (gam) {
        const double *d = qd + 7 * b + 3;
        double Bd[3][4];
        bmat(d[0], d[1], d[2], d[3], a, Bd);
        for (int i = 0; i < 3; i++) {
            v->vel[i] = v->B[i][0] * d[0] + v->B[i][1] * d[1] + v->B[i][2] * d[2] +
                        v->B[i][3] * d[3];
            v->bdot[i] = Bd[i][0] * d[0] + Bd[i][1] * d[1] + Bd[i][2] * d[2] + Bd[i][3] * d[3];
        }
    }
}

static double dot3(const double *x, const double *y)
{
    return x[0] * y[0] + x[1] * y[1] + x[2] * y[2];
}

/* x^T B (4,): the derivative of x . (A a') with respect to p. */
static void xB(const double *x, const double B[3][4], double *out)
{
    for (int m = 0; m < 4; m++)
        out[m] = x[0] * B[0][m] + x[1] * B[1][m] + x[2] * B[2][m];
}

/* -- the basic kernels: Phi (without targets), Jc rows, gamma (without c'') ---------------
 * Each writes phi[0..ne), J[14 * e + c] (the kernel's rows of Jc, zeroed by the caller) and
 * gamma[0..ne).  v: the kernel's vector slots (see VECTORS in mbsim/fast/constraints.py). */

/* dot-1: Phi = a_i . a_j (Haug eq. 9.2.3); slots a_i, a_j.
 * Phi_p_i = a_j^T B(p_i, a_i'), Phi_p_j = a_i^T B(p_j, a_j');
 * gamma = -(a_i . bdot_j + a_j . bdot_i + 2 adot_i . adot_j). */
static void k_dot1(const vec_t *v, double *phi, double *J, double *gamma, int jac, int gam)
{
    phi[0] = dot3(v[0].val, v[1].val);
    if (jac) {
        xB(v[1].val, v[0].B, J + 3);
        xB(v[0].val, v[1].B, J + 10);
    }
    if (gam)
        gamma[0] = -(dot3(v[0].val, v[1].bdot) + dot3(v[1].val, v[0].bdot) +
                     2.0 * dot3(v[0].vel, v[1].vel));
}

/* d = r_j + A_j s_j - r_i - A_i s_i and its rate (Haug Ch. 9). */
static void point_diff(const double *q, const double *qd, idx bi, idx bj, const vec_t *v,
                       int gam, double *d, double *dd)
{
    for (int i = 0; i < 3; i++) {
        d[i] = q[7 * bj + i] + v[2].val[i] - q[7 * bi + i] - v[1].val[i];
        if (gam)
            dd[i] = qd[7 * bj + i] + v[2].vel[i] - qd[7 * bi + i] - v[1].vel[i];
    }
}

/* dot-2: Phi = a . d_ij, a on body i (flag 0) or j (flag 1) (Haug eq. 9.2.6); slots a, s_i,
 * s_j.  Phi_r_i = -a^T, Phi_r_j = a^T, Phi_p_i = -a^T B(p_i, s_i'), Phi_p_j = a^T B(p_j, s_j'),
 * plus d^T B(p, a') on a's body; gamma = -(a . (bdot_j - bdot_i) + d . bdot_a + 2 adot . ddot).
 */
static void k_dot2(const double *q, const double *qd, idx bi, idx bj, idx flag, const vec_t *v,
                   double *phi, double *J, double *gamma, int jac, int gam)
{
    double d[3], dd[3], t[4];
    point_diff(q, qd, bi, bj, v, gam, d, dd);
    const double *a = v[0].val;
    phi[0] = dot3(a, d);
    if (jac) {
        for (int i = 0; i < 3; i++) {
            J[i] = -a[i];
            J[7 + i] = a[i];
        }
        xB(a, v[1].B, t);
        for (int m = 0; m < 4; m++)
            J[3 + m] = -t[m];
        xB(a, v[2].B, t);
        for (int m = 0; m < 4; m++)
            J[10 + m] = t[m];
        xB(d, v[0].B, t);
        int ca = flag ? 10 : 3;
        for (int m = 0; m < 4; m++)
            J[ca + m] += t[m];
    }
    if (gam) {
        double s = 0.0;
        for (int i = 0; i < 3; i++)
            s += a[i] * (v[2].bdot[i] - v[1].bdot[i]) + d[i] * v[0].bdot[i] +
                 2.0 * v[0].vel[i] * dd[i];
        gamma[0] = -s;
    }
}

/* spherical: Phi = d_ij (3 equations, Haug eq. 9.4.1); slots -, s_i, s_j.
 * Phi_q = [-I, -B(p_i, s_i'), I, B(p_j, s_j')]; gamma = bdot_i - bdot_j. */
static void k_spherical(const double *q, const double *qd, idx bi, idx bj, const vec_t *v,
                        double *phi, double *J, double *gamma, int jac, int gam)
{
    double d[3], dd[3];
    point_diff(q, qd, bi, bj, v, 0, d, dd);
    for (int i = 0; i < 3; i++) {
        phi[i] = d[i];
        if (jac) {
            double *Jr = J + 14 * i;
            Jr[i] = -1.0;
            Jr[7 + i] = 1.0;
            for (int m = 0; m < 4; m++) {
                Jr[3 + m] = -v[1].B[i][m];
                Jr[10 + m] = v[2].B[i][m];
            }
        }
        if (gam)
            gamma[i] = v[1].bdot[i] - v[2].bdot[i];
    }
}

/* distance: Phi = d . d, target C^2 (Haug eq. 9.2.9); slots -, s_i, s_j.
 * Phi_q = 2 d^T [-I, -B_i, I, B_j]; gamma = -2 (d . (bdot_j - bdot_i) + ddot . ddot). */
static void k_distance(const double *q, const double *qd, idx bi, idx bj, const vec_t *v,
                       double *phi, double *J, double *gamma, int jac, int gam)
{
    double d[3], dd[3], t[4];
    point_diff(q, qd, bi, bj, v, gam, d, dd);
    phi[0] = dot3(d, d);
    if (jac) {
        for (int i = 0; i < 3; i++) {
            J[i] = -2.0 * d[i];
            J[7 + i] = 2.0 * d[i];
        }
        xB(d, v[1].B, t);
        for (int m = 0; m < 4; m++)
            J[3 + m] = -2.0 * t[m];
        xB(d, v[2].B, t);
        for (int m = 0; m < 4; m++)
            J[10 + m] = 2.0 * t[m];
    }
    if (gam) {
        double s = 0.0;
        for (int i = 0; i < 3; i++)
            s += d[i] * (v[2].bdot[i] - v[1].bdot[i]) + dd[i] * dd[i];
        gamma[0] = -2.0 * s;
    }
}

/* angle (rotational driver): theta from g_i to g_j about f_i minus f(t), wrapped to
 * (-pi, pi] (Haug Sec. 9.5); slots g_i, h_i, g_j.  c = g_i . g_j and s = h_i . g_j are dot-1
 * terms, theta = atan2(s, c): theta_q = (c s_q - s c_q) / rho, rho = c^2 + s^2, and
 * gamma = (c gs - s gc) / rho + thetadot rhodot / rho with gc, gs the dot-1 gammas.
 * f: the target angle (the driver's f(t), or the constant target). */
static void k_angle(const vec_t *v, double f, double *phi, double *J, double *gamma, int jac,
                    int gam)
{
    double c = dot3(v[0].val, v[2].val), s = dot3(v[1].val, v[2].val);
    double cf = cos(f), sf = sin(f);
    phi[0] = atan2(s * cf - c * sf, c * cf + s * sf);
    double rho = c * c + s * s;
    if (jac) {
        double dci[4], dsi[4], dcj[4], dsj[4];
        xB(v[2].val, v[0].B, dci);
        xB(v[2].val, v[1].B, dsi);
        xB(v[0].val, v[2].B, dcj);
        xB(v[1].val, v[2].B, dsj);
        for (int m = 0; m < 4; m++) {
            J[3 + m] = (c * dsi[m] - s * dci[m]) / rho;
            J[10 + m] = (c * dsj[m] - s * dcj[m]) / rho;
        }
    }
    if (gam) {
        double gc = -(dot3(v[0].val, v[2].bdot) + dot3(v[2].val, v[0].bdot) +
                      2.0 * dot3(v[0].vel, v[2].vel));
        double gs = -(dot3(v[1].val, v[2].bdot) + dot3(v[2].val, v[1].bdot) +
                      2.0 * dot3(v[1].vel, v[2].vel));
        double cd = dot3(v[0].vel, v[2].val) + dot3(v[0].val, v[2].vel);
        double sd = dot3(v[1].vel, v[2].val) + dot3(v[1].val, v[2].vel);
        double thd = (c * sd - s * cd) / rho;
        double rhod = 2.0 * (c * cd + s * sd);
        gamma[0] = (c * gs - s * gc) / rho + thd * rhod / rho;
    }
}

/* absolute: Phi = (r + A s')[axis] (Haug Sec. 9.5, absolute constraints); slot s.
 * Phi_r = e_axis^T, Phi_p = B(p, s')[axis]; gamma = -bdot[axis]. */
static void k_absolute(const double *q, idx bi, idx axis, const vec_t *v, double *phi,
                       double *J, double *gamma, int jac, int gam)
{
    phi[0] = q[7 * bi + axis] + v[0].val[axis];
    if (jac) {
        J[axis] = 1.0;
        for (int m = 0; m < 4; m++)
            J[3 + m] = v[0].B[axis][m];
    }
    if (gam)
        gamma[0] = -v[0].bdot[axis];
}

/* ground: r = r0, (e1, e2, e3) = e0' (6 equations; the targets are the constants). */
static void k_ground(const double *q, idx bi, double *phi, double *J, double *gamma, int jac,
                     int gam)
{
    for (int i = 0; i < 3; i++) {
        phi[i] = q[7 * bi + i];
        phi[3 + i] = q[7 * bi + 4 + i];
        if (jac) {
            J[14 * i + i] = 1.0;
            J[14 * (3 + i) + 4 + i] = 1.0;
        }
    }
    if (gam)
        for (int i = 0; i < 6; i++)
            gamma[i] = 0.0;
}

/* normalization: Phi = p^T p (target 1; Haug eq. 6.3.2); Phi_p = 2 p^T;
 * gamma = -2 pd^T pd (its second time derivative). */
static void k_normalization(const double *q, const double *qd, idx bi, double *phi, double *J,
                            double *gamma, int jac, int gam)
{
    const double *p = q + 7 * bi + 3, *pd = qd + 7 * bi + 3;
    double s = 0.0;
    for (int m = 0; m < 4; m++) {
        s += p[m] * p[m];
        if (jac)
            J[3 + m] = 2.0 * p[m];
    }
    phi[0] = s;
    if (gam) {
        s = 0.0;
        for (int m = 0; m < 4; m++)
            s += pd[m] * pd[m];
        gamma[0] = -2.0 * s;
    }
}

/* Phi (with targets), compact Phi_q, gamma (with c'') and nu = c' of all m rows at the
 * model's q, qd, tv; jac, gam: what to compute besides phi and nu (gam reads qd). */
void mb_constraints(const mb_model *M, int jac, int gam)
{
    const double *q = M->q, *qd = M->qd, *tv = M->tv;
    vec_t v[3];
    memset(M->nu, 0, (size_t)M->m * sizeof(double));
    if (jac)
        memset(M->Jc, 0, (size_t)M->m * 14 * sizeof(double));
    for (idx k = 0; k < M->nc; k++) {
        const idx *c = M->ci + NI * k;
        const double *f = M->cf + NF * k;
        idx kind = c[I_KERNEL], bi = c[I_BI], bj = c[I_BJ], r = c[I_ROW], flag = c[I_FLAG];
        idx fn = c[I_FUNC];
        for (int s = 0; s < 3; s++)
            if (c[I_SLOT + s] >= 0)
                body_vector(q, qd, c[I_SLOT + s], f + 3 * s, gam, &v[s]);
        double *phi = M->phi + r, *J = M->Jc + 14 * r, *gamma = M->gamma + r;
        switch (kind) {
        case DOT1: k_dot1(v, phi, J, gamma, jac, gam); break;
        case DOT2: k_dot2(q, qd, bi, bj, flag, v, phi, J, gamma, jac, gam); break;
        case SPHERICAL: k_spherical(q, qd, bi, bj, v, phi, J, gamma, jac, gam); break;
        case DISTANCE: k_distance(q, qd, bi, bj, v, phi, J, gamma, jac, gam); break;
        case ANGLE:
            k_angle(v, fn >= 0 ? tv[3 * fn] : f[F_CONST], phi, J, gamma, jac, gam);
            break;
        case ABSOLUTE: k_absolute(q, bi, flag, v, phi, J, gamma, jac, gam); break;
        case GROUND: k_ground(q, bi, phi, J, gamma, jac, gam); break;
        default: k_normalization(q, qd, bi, phi, J, gamma, jac, gam); break;
        }
        if (kind != ANGLE) { /* Phi = phi(q) - c: the constant targets, then the time target */
            for (int e = 0; e < NE[kind]; e++)
                phi[e] -= f[F_CONST + e];
            if (fn >= 0)
                phi[0] -= tv[3 * fn];
        }
        if (fn >= 0) { /* nu = c', gamma += c'' */
            M->nu[r] = tv[3 * fn + 1];
            if (gam)
                gamma[0] += tv[3 * fn + 2];
        }
    }
}

/* The results on the rows `rows`: phi_a, nu_a (gamma_a when gam); the Jacobian dense into J
 * (mode 1; (ma, nq), pattern-only writes: J stays zero elsewhere) or as CSR values into data
 * (mode 2, positions dpos); mode 0: no Jacobian. */
static void gather(const mb_model *M, int gam, int mode)
{
    const idx *rb = M->rb;
    for (idx k = 0; k < M->ma; k++) {
        idx r = M->rows[k];
        M->phi_a[k] = M->phi[r];
        M->nu_a[k] = M->nu[r];
        if (gam)
            M->gamma_a[k] = M->gamma[r];
        const double *Jr = M->Jc + 14 * r;
        if (mode == 1) {
            double *Jk = M->J + M->nq * k;
            idx c0 = 7 * rb[2 * r], c1 = 7 * rb[2 * r + 1];
            for (int c = 0; c < 7; c++)
                Jk[c0 + c] = Jr[c];
            if (c1 >= 0) {
                if (c1 == c0) /* both ends on one body: the derivative is the sum */
                    for (int c = 0; c < 7; c++)
                        Jk[c1 + c] += Jr[7 + c];
                else
                    for (int c = 0; c < 7; c++)
                        Jk[c1 + c] = Jr[7 + c];
            }
        } else if (mode == 2) {
            const idx *dp = M->dpos + 14 * k;
            for (int c = 0; c < 14; c++)
                if (dp[c] >= 0)
                    M->data[dp[c]] = 0.0;
            for (int c = 0; c < 14; c++)
                if (dp[c] >= 0)
                    M->data[dp[c]] += Jr[c];
        }
    }
}

/* mb_constraints, then the results on `rows` (gather). */
void mb_terms(const mb_model *M, int jac, int gam, int mode)
{
    mb_constraints(M, jac, gam);
    gather(M, gam, jac ? mode : 0);
}

/* Compact rows Jc (all rows of `rows`) from a dense (ma, nq) Jacobian J: the inverse of the
 * dense gather (a row whose two bodies coincide keeps the sum in the body-i slot). */
void mb_gather_dense(const mb_model *M, const double *J, double *Jc)
{
    for (idx k = 0; k < M->ma; k++) {
        idx r = M->rows[k], c0 = 7 * M->rb[2 * r], c1 = 7 * M->rb[2 * r + 1];
        const double *Jk = J + M->nq * k;
        for (int c = 0; c < 7; c++)
            Jc[14 * r + c] = Jk[c0 + c];
        if (c1 >= 0)
            for (int c = 0; c < 7; c++)
                Jc[14 * r + 7 + c] = c1 == c0 ? 0.0 : Jk[c1 + c];
    }
}

/* out (m,) = Phi_q x from the compact Jacobian Jc (all rows). */
void mb_jac_times(const mb_model *M, const double *x, double *out)
{
    for (idx r = 0; r < M->m; r++) {
        const double *Jr = M->Jc + 14 * r;
        idx b0 = M->rb[2 * r], b1 = M->rb[2 * r + 1];
        double s = 0.0;
        for (int c = 0; c < 7; c++)
            s += Jr[c] * x[7 * b0 + c];
        if (b1 >= 0)
            for (int c = 0; c < 7; c++)
                s += Jr[7 + c] * x[7 * b1 + c];
        out[r] = s;
    }
}

/* -- equations of motion ------------------------------------------------------------------ */

/* A = A(p) (Haug eq. 6.3.20, homogeneous form of mbsim.rotations.A), row-major 3 x 3. */
static void rotation(const double *p, double *A)
{
    double e0 = p[0], e1 = p[1], e2 = p[2], e3 = p[3];
    double d = e0 * e0 - e1 * e1 - e2 * e2 - e3 * e3;
    A[0] = d + 2 * e1 * e1;
    A[4] = d + 2 * e2 * e2;
    A[8] = d + 2 * e3 * e3;
    A[1] = 2 * (e1 * e2 - e0 * e3);
    A[3] = 2 * (e1 * e2 + e0 * e3);
    A[2] = 2 * (e1 * e3 + e0 * e2);
    A[6] = 2 * (e1 * e3 - e0 * e2);
    A[5] = 2 * (e2 * e3 - e0 * e1);
    A[7] = 2 * (e2 * e3 + e0 * e1);
}

/* G = G(p) = [-e, -e~ + e0 I] (3, 4) (Haug eq. 6.3.18): omega' = 2 G pd. */
static void gmat(const double *p, double G[3][4])
{
    double e0 = p[0], e1 = p[1], e2 = p[2], e3 = p[3];
    G[0][0] = -e1; G[0][1] = e0;  G[0][2] = e3;  G[0][3] = -e2;
    G[1][0] = -e2; G[1][1] = -e3; G[1][2] = e0;  G[1][3] = e1;
    G[2][0] = -e3; G[2][1] = e2;  G[2][2] = -e1; G[2][3] = e0;
}

/* out = A x (trans: A^T x). */
static void rot(const double *A, const double *x, double *out, int trans)
{
    for (int i = 0; i < 3; i++)
        out[i] = trans ? A[i] * x[0] + A[3 + i] * x[1] + A[6 + i] * x[2]
                       : A[3 * i] * x[0] + A[3 * i + 1] * x[1] + A[3 * i + 2] * x[2];
}

/* out += sign (x cross y). */
static void cross_add(const double *x, const double *y, double *out, double sign)
{
    out[0] += sign * (x[1] * y[2] - x[2] * y[1]);
    out[1] += sign * (x[2] * y[0] - x[0] * y[2]);
    out[2] += sign * (x[0] * y[1] - x[1] * y[0]);
}

/* TSDA (Haug Sec. 11.3): f = k (l - L0) + c ldot, tension along u = d / l, d = r_j + A_j s_j'
 * - r_i - A_i s_i'; f u acts on P_i towards P_j and the opposite on P_j.  ef: s_i', s_j', k,
 * c, L0.  Coincident points: no direction, no force. */
static void el_tsda(const double *q, const double *qd, const double *A, const double *w,
                    idx b1, idx b2, const double *e, double *F, double *n)
{
    double si[3], sj[3], u[3], vi[3] = {0, 0, 0}, vj[3] = {0, 0, 0}, x[3], y[3], l = 0.0;
    rot(A + 9 * b2, e + 3, sj, 0);
    rot(A + 9 * b1, e, si, 0);
    for (int i = 0; i < 3; i++) {
        u[i] = q[7 * b2 + i] + sj[i] - q[7 * b1 + i] - si[i];
        l += u[i] * u[i];
    }
    l = sqrt(l);
    for (int i = 0; i < 3; i++)
        u[i] = l > 0 ? u[i] / l : 0.0;
    /* ldot = u . ((rd_j + A_j (w_j' x s_j')) - (rd_i + A_i (w_i' x s_i'))) */
    cross_add(e + 3, w + 3 * b2, vj, -1.0);
    cross_add(e, w + 3 * b1, vi, -1.0);
    rot(A + 9 * b2, vj, x, 0);
    rot(A + 9 * b1, vi, y, 0);
    double ldot = 0.0;
    for (int i = 0; i < 3; i++)
        ldot += u[i] * (qd[7 * b2 + i] + x[i] - qd[7 * b1 + i] - y[i]);
    double f = e[6] * (l - e[8]) + e[7] * ldot;
    for (int i = 0; i < 3; i++) {
        u[i] *= f;
        F[3 * b1 + i] += u[i];
        F[3 * b2 + i] -= u[i];
    }
    rot(A + 9 * b1, u, x, 1); /* n_i' += s_i' x A_i^T f u, n_j' -= s_j' x A_j^T f u */
    cross_add(e, x, n + 3 * b1, 1.0);
    rot(A + 9 * b2, u, x, 1);
    cross_add(e + 3, x, n + 3 * b2, -1.0);
}

/* w' = 2 G(p) pd (Haug eq. 6.3.18): the body-frame angular velocity. */
static void omega_local(const double *p, const double *pd, double *w)
{
    double G[3][4];
    gmat(p, G);
    for (int i = 0; i < 3; i++)
        w[i] = 2.0 * (G[i][0] * pd[0] + G[i][1] * pd[1] + G[i][2] * pd[2] + G[i][3] * pd[3]);
}

/* clip(x, lo, hi) that keeps a NaN x (as numpy's minimum(maximum(x, lo), hi)). */
static double clip(double x, double lo, double hi)
{
    x = x < lo ? lo : x;
    return x > hi ? hi : x;
}

/* The tire on the road z = 0 (mbsim/forces/tire.py's module doc: Haug Sec. 12.5.1, Eqs.
 * 12.5.1-12.5.3 written for any heading), one tire at one state: the only implementation of
 * the law, for the equations of motion (mb_applied_forces) and for its quantities at the
 * outputs (mb_tire_states).
 * r, rd: origin of the tire's body and its velocity (global); A: its rotation matrix; w: its
 * angular velocity (body frame); e: the tire's ef row, s' (0-2, spindle, body frame), forward
 * axis (3-5, unit, body frame), kt, radius, c, c_alpha, mu, rolling, v_min (6-12).
 * o (TIRE_OUT,): see TIRE_OUT.
 * Spindle P = r + A s', height h = P_z; contact point C = P - h z, sc = A^T (C - r); v the
 * velocity of the body point at C, rd + A (w' x sc); heading u = the forward axis on the road,
 * normalised (y when it stands vertical, |u_h| <= 1e-12); l = u x z; v_fwd = u . v, v_lat =
 * l . v; alpha = atan2(v_lat, |v_fwd|) (12.5.1 in the heading frame); deflection d = radius -
 * h; F_ver = max(0, kt d - c v_z) on the ground (d > 0), else 0; F_lat = w(|v_h|) clip(C_alpha
 * alpha, +-mu F_ver), w the smoothstep 3 x^2 - 2 x^3 of x = min(|v_h| / v_min, 1); saturated:
 * on the ground, C_alpha alpha != 0 and |C_alpha alpha| >= mu F_ver; F_roll = rolling F_ver
 * clip(v_fwd / v_min, +-1); F = F_ver z - F_lat l - F_roll u at C, n' = sc x A^T F. */
static void tire_law(const double *r, const double *rd, const double *A, const double *w,
                     const double *e, double *o)
{
    double *F = o, *nl = o + 3, *sc = o + 6, *v = o + 9, *u = o + 12, x[3] = {0, 0, 0}, y[3];
    double kt = e[6], radius = e[7], c = e[8], c_alpha = e[9], mu = e[10], rolling = e[11],
           v_min = e[12];
    rot(A, e, y, 0); /* P - r = A s' */
    double P0 = r[0] + y[0], P1 = r[1] + y[1], h = r[2] + y[2];
    double d[3] = {P0 - r[0], P1 - r[1], -r[2]}; /* C - r */
    rot(A, d, sc, 1);
    cross_add(sc, w, x, -1.0); /* w' x sc */
    rot(A, x, y, 0);
    for (int i = 0; i < 3; i++)
        v[i] = rd[i] + y[i];
    double uh0 = A[0] * e[3] + A[1] * e[4] + A[2] * e[5];
    double uh1 = A[3] * e[3] + A[4] * e[4] + A[5] * e[5];
    double un = hypot(uh0, uh1);
    if (un > 1e-12) {
        u[0] = uh0 / un;
        u[1] = uh1 / un;
    } else { /* the forward axis stands vertical: the heading of y */
        u[0] = 0.0;
        u[1] = 1.0;
    }
    u[2] = 0.0;
    double l0 = u[1], l1 = -u[0]; /* l = u x z */
    double v_fwd = u[0] * v[0] + u[1] * v[1], v_lat = l0 * v[0] + l1 * v[1];
    double alpha = atan2(v_lat, fabs(v_fwd));
    double defl = radius - h;
    int ground = defl > 0;
    double f_ver = 0.0;
    if (ground) {
        f_ver = kt * defl - c * v[2];
        f_ver = f_ver < 0.0 ? 0.0 : f_ver; /* no tension (a NaN stays) */
    }
    double limit = mu * f_ver, f_lin = c_alpha * alpha;
    double speed = hypot(v_fwd, v_lat);
    double xs = speed / v_min;
    xs = xs > 1.0 ? 1.0 : xs;
    double f_lat = xs * xs * (3.0 - 2.0 * xs) * clip(f_lin, -limit, limit);
    double f_roll = rolling * f_ver * clip(v_fwd / v_min, -1.0, 1.0);
    F[0] = -f_lat * l0 - f_roll * u[0];
    F[1] = -f_lat * l1 - f_roll * u[1];
    F[2] = -f_lat * 0.0 - f_roll * 0.0 + f_ver; /* the zeros keep a non-finite F_lat's NaN */
    rot(A, F, y, 1);
    nl[0] = nl[1] = nl[2] = 0.0;
    cross_add(sc, y, nl, 1.0);
    o[15] = f_ver;
    o[16] = f_lat;
    o[17] = f_roll;
    o[18] = alpha;
    o[19] = (ground && f_lin != 0.0 && fabs(f_lin) >= limit) ? 1.0 : 0.0;
    o[20] = defl;
    o[21] = speed;
}

/* The tire law (tire_law) of ntire tires at nt states: q, qd (nt, nb, 7) the states; tb
 * (ntire,) each tire's body, te (ntire, NEF) its ef row; out (nt, ntire, TIRE_OUT).  A and w'
 * as mb_applied_forces computes them, so a tire's loads here equal its loads in the equations
 * of motion to the bit. */
void mb_tire_states(int64_t nt, int64_t nb, int64_t ntire, const idx *tb, const double *te,
                    const double *q, const double *qd, double *out)
{
    double A[9], w[3];
    for (idx k = 0; k < nt; k++)
        for (idx j = 0; j < ntire; j++) {
            const double *qb = q + 7 * (nb * k + tb[j]), *qdb = qd + 7 * (nb * k + tb[j]);
            rotation(qb + 3, A);
            omega_local(qb + 3, qdb + 3, w);
            tire_law(qb, qdb, A, w, te + NEF * j, out + TIRE_OUT * (ntire * k + j));
        }
}

/* Q (nq,) = [F, 2 G^T (n' - w' x J' w')] per body (Haug Ch. 11, Euler-parameter form):
 * gravity, the compiled elements (EL_*), the Python elements' loads (2, nb, 3: F and n') and
 * the gyroscopic term. */
void mb_applied_forces(const mb_model *M)
{
    const double *q = M->q, *qd = M->qd, *bt = M->bt;
    double *A = M->A, *F = M->F, *n = M->n, *w = M->w, *Q = M->Q;
    double G[3][4], x[3];
    idx nb = M->nb;
    for (idx b = 0; b < nb; b++) {
        const double *p = q + 7 * b + 3, *pd = qd + 7 * b + 3;
        if (M->ne > 0) /* A: the compiled elements' alone */
            rotation(p, A + 9 * b);
        omega_local(p, pd, w + 3 * b);
        for (int i = 0; i < 3; i++) {
            F[3 * b + i] = bt[NB * b + 20 + i] + M->loads[3 * b + i];
            n[3 * b + i] = M->loads[3 * nb + 3 * b + i];
        }
    }
    for (idx k = 0; k < M->ne; k++) {
        idx kind = M->ei[3 * k], b1 = M->ei[3 * k + 1], b2 = M->ei[3 * k + 2];
        const double *e = M->ef + NEF * k;
        if (kind == EL_TSDA) {
            el_tsda(q, qd, A, w, b1, b2, e, F, n);
        } else if (kind == EL_TIRE) { /* on b1 (tire_law) */
            double o[TIRE_OUT];
            tire_law(q + 7 * b1, qd + 7 * b1, A + 9 * b1, w + 3 * b1, e, o);
            for (int i = 0; i < 3; i++) {
                F[3 * b1 + i] += o[i];
                n[3 * b1 + i] += o[3 + i];
            }
        } else if (kind == EL_FORCE_LOCAL) { /* follower force: body-fixed direction, at s' */
            rot(A + 9 * b1, e, x, 0);
            for (int i = 0; i < 3; i++)
                F[3 * b1 + i] += x[i];
            cross_add(e + 3, e, n + 3 * b1, 1.0);
        } else if (kind == EL_FORCE) { /* global vector at s': n' += s' x A^T f */
            for (int i = 0; i < 3; i++)
                F[3 * b1 + i] += e[i];
            rot(A + 9 * b1, e, x, 1);
            cross_add(e + 3, x, n + 3 * b1, 1.0);
        } else { /* torque on b1, the opposite on b2 (-1: none); local: frame of b2 (else b1) */
            double tg[3], tl[3];
            if (kind == EL_TORQUE_LOCAL)
                rot(A + 9 * (b2 >= 0 ? b2 : b1), e, tg, 0);
            else
                for (int i = 0; i < 3; i++)
                    tg[i] = e[i];
            rot(A + 9 * b1, tg, tl, 1);
            for (int i = 0; i < 3; i++)
                n[3 * b1 + i] += tl[i];
            if (b2 >= 0) {
                rot(A + 9 * b2, tg, tl, 1);
                for (int i = 0; i < 3; i++)
                    n[3 * b2 + i] -= tl[i];
            }
        }
    }
    for (idx b = 0; b < nb; b++) { /* gyroscopic term and Q_p = 2 G^T (n' - w' x J' w') */
        const double *Jl = bt + NB * b + 1;
        double *wb = w + 3 * b, *nbv = n + 3 * b, Jw[3];
        gmat(q + 7 * b + 3, G);
        for (int i = 0; i < 3; i++)
            Jw[i] = Jl[3 * i] * wb[0] + Jl[3 * i + 1] * wb[1] + Jl[3 * i + 2] * wb[2];
        cross_add(wb, Jw, nbv, -1.0);
        for (int i = 0; i < 3; i++)
            Q[7 * b + i] = F[3 * b + i];
        for (int m = 0; m < 4; m++)
            Q[7 * b + 3 + m] = 2.0 * (G[0][m] * nbv[0] + G[1][m] * nbv[1] + G[2][m] * nbv[2]);
    }
}

/* Mb (nb, 7, 7) = diag(m I, 4 G^T J' G) (Haug Ch. 11), into M->Mb. */
void mb_mass_blocks(const mb_model *M)
{
    double G[3][4];
    for (idx b = 0; b < M->nb; b++) {
        const double *bt = M->bt + NB * b;
        double *Mb = M->Mb + 49 * b;
        gmat(M->q + 7 * b + 3, G);
        memset(Mb, 0, 49 * sizeof(double));
        for (int i = 0; i < 3; i++)
            Mb[8 * i] = bt[0];
        for (int a = 0; a < 4; a++)
            for (int c = 0; c < 4; c++) {
                double s = 0.0;
                for (int i = 0; i < 3; i++)
                    for (int j = 0; j < 3; j++)
                        s += G[i][a] * bt[1 + 3 * i + j] * G[j][c];
                Mb[7 * (3 + a) + 3 + c] = 4.0 * s;
            }
    }
}

/* Mi (nb, 4, 4): Euler-parameter block of Mt^-1 = (G^T J'^-1 G / 4 + p p^T / c) / s^2,
 * s = p^T p (module doc of mbsim/fast/dynamics.py: the modified mass matrix); the
 * translational block is I / m.  unit: the identity metric instead (min-norm projections
 * of models with a singular J'). */
static void minv_blocks(const mb_model *M, int unit)
{
    double G[3][4], H[3][4];
    for (idx b = 0; b < M->nb; b++) {
        const double *p = M->q + 7 * b + 3, *bt = M->bt + NB * b;
        double *Mi = M->Mi + 16 * b;
        if (unit) {
            memset(Mi, 0, 16 * sizeof(double));
            for (int a = 0; a < 4; a++)
                Mi[5 * a] = 1.0;
            continue;
        }
        gmat(p, G);
        for (int i = 0; i < 3; i++) /* H = J'^-1 G */
            for (int e = 0; e < 4; e++)
                H[i][e] = bt[10 + 3 * i] * G[0][e] + bt[11 + 3 * i] * G[1][e] +
                          bt[12 + 3 * i] * G[2][e];
        double s = p[0] * p[0] + p[1] * p[1] + p[2] * p[2] + p[3] * p[3];
        double s2 = 1.0 / (s * s), c = 1.0 / bt[19];
        for (int a = 0; a < 4; a++)
            for (int e = 0; e < 4; e++) {
                double t = G[0][a] * H[0][e] + G[1][a] * H[1][e] + G[2][a] * H[2][e];
                Mi[4 * a + e] = (0.25 * t + p[a] * p[e] * c) * s2;
            }
    }
}

/* y[0..7) = (Mt^-1 block of body b) x[0..7). */
static inline void apply_minv(const mb_model *M, int unit, idx b, const double *x,
                              double *y)
{
    double im = unit ? 1.0 : M->bt[NB * b + 23];
    const double *Mi = M->Mi + 16 * b;
    for (int i = 0; i < 3; i++)
        y[i] = x[i] * im;
    for (int a = 0; a < 4; a++)
        y[3 + a] = Mi[4 * a] * x[3] + Mi[4 * a + 1] * x[4] + Mi[4 * a + 2] * x[5] +
                   Mi[4 * a + 3] * x[6];
}

/* x . y over one body's 7 columns (x = Mt^-1 times one row of Phi_q, y another row, both
 * padded to 8 with a zero), in the order c = 0, 1, .., 6, with the products that are exact
 * zeros left out (pairs' code, mbsim/fast/dynamics.py: pair_codes): where y is an exact zero
 * of the kernels' Phi_q, or, in the r columns, where Mt^-1 is diagonal, x is.  Adding a +-0
 * product to a sum that starts at +0 changes no bit (the sum never becomes -0), so the
 * result is the full sum's to the bit and the Schur matrix the same.  code >= 0: the r
 * column code (7: none, the padding's 0 x 0) and the four p columns, a chain's every pair
 * (a spherical joint's row has one r column, a normalisation row none): 5 products of 7;
 * code < 0: the columns of the mask -1 - code (ALL_COLUMNS: every one).  (A non-finite x or
 * y stays in the sum through the p columns, which no kernel with a non-constant r column
 * leaves out.) */
enum { ALL_COLUMNS = 0x7F };

static inline double pair_dot(const double *x, const double *y, idx code)
{
    double s = 0.0;
    if (code >= 0) {
        s += x[code] * y[code];
        s += x[3] * y[3];
        s += x[4] * y[4];
        s += x[5] * y[5];
        s += x[6] * y[6];
        return s;
    }
    idx mask = -1 - code;
    for (int c = 0; c < 7; c++)
        if (mask >> c & 1)
            s += x[c] * y[c];
    return s;
}

/* Factor the Schur matrix S = Phi_q Mt^-1 Phi_q^T of the active rows (Jc: compact Phi_q).
 * Per incidence g = (row u, column offset, body b): JG[g] = the row's 7 entries for b and
 * XG[g] = Mt_b^-1 JG[g] (padded to 8); S[u, v] = sum over shared bodies XG[g_u] . JG[g_v]
 * (pairs), assembled in the envelope of its RCM permutation and overwritten by its
 * factor S = L D L^T (L unit lower triangular; George and Liu 1981, Ch. 4: the fill stays
 * in the envelope), the diagonal stored as 1 / D_ii.  Row i by bordering (Golub & Van Loan
 * Sec. 4.1): w_ij = S_ij - sum_k w_ik L_jk (w = L D, k < j), then L_ij = w_ij / D_jj and
 * D_ii = S_ii - sum_k w_ik L_ik: the multiply-adds of Cholesky, without its square roots
 * on the chain from one row to the next.  out[1] = the smallest ratio pivot / diagonal before any
 * raise (1: none below 1; ~ (sigma_min / sigma)^2 of the scaled rows near a change point).
 * Returns 0 when S is not positive definite. */
#define PIVOT_FLOOR 1e-8 /* relative: (sigma_min / sigma)^2 below which a pivot is raised */
/* inc's column offset + CROSS: an incidence of a row on a body held by its own rows alone
 * (the ground), left out of S (mbsim/fast/dynamics.py: schur_structure); its XG is zero, so
 * the sums over incidences below skip it, and fixed_body_multipliers adds its reaction. */
#define CROSS 14

static int schur_factor(const mb_model *M, const double *Jc, int unit)
{
    const idx *sidx = M->sidx, *inc = M->inc, *pairs = M->pairs;
    idx ma = M->ma;
    const idx *rows = sidx, *fc = sidx + 2 * ma, *off = sidx + 3 * ma;
    double *XG = M->XG, *JG = M->JG, *env = M->env;
    for (idx g = 0; g < M->ninc; g++) {
        idx o = inc[3 * g + 1], cross = o >= CROSS;
        const double *Jr = Jc + 14 * rows[inc[3 * g]] + (cross ? o - CROSS : o);
        for (int c = 0; c < 7; c++)
            JG[8 * g + c] = Jr[c];
        JG[8 * g + 7] = 0.0;
        XG[8 * g + 7] = 0.0;
        if (cross) /* a row's entries on a body its own rows hold: no part of S */
            memset(XG + 8 * g, 0, 7 * sizeof(double));
        else
            apply_minv(M, unit, inc[3 * g + 2], JG + 8 * g, XG + 8 * g);
    }
    memset(env, 0, (size_t)M->nenv * sizeof(double));
    int own = Jc == M->Jc; /* the kernels' Phi_q: the pairs' column masks hold (else Jg) */
    for (idx k = 0; k < M->npairs; k++) {
        const idx *pk = pairs + 4 * k;
        env[pk[0]] += pair_dot(XG + 8 * pk[1], JG + 8 * pk[2], own ? pk[3] : -1 - ALL_COLUMNS);
    }
    double rmin = 1.0, *dinv = M->z; /* 1 / D_kk by position (z: free until the solve) */
    for (idx i = 0; i < ma; i++) { /* envelope L D L^T, row by row (bordering) */
        idx fi = fc[i], oi = off[i] - fi;
        for (idx j = fi; j < i; j++) { /* w_ij: row i's k < j hold w, row j's L */
            idx fj = fc[j], oj = off[j] - fj;
            double s = env[oi + j];
            for (idx k = fi > fj ? fi : fj; k < j; k++)
                s -= env[oi + k] * env[oj + k];
            env[oi + j] = s;
        }
        double d0 = env[oi + i], s = d0;
        for (idx k = fi; k < i; k++) { /* L_ik = w_ik / D_kk, D_ii -= w_ik L_ik */
            double l = env[oi + k] * dinv[k];
            s -= env[oi + k] * l;
            env[oi + k] = l;
        }
        if (d0 > 0.0 && s < rmin * d0)
            rmin = s / d0;
        if (!(s > PIVOT_FLOOR * d0)) {
            /* A pivot below PIVOT_FLOOR of its diagonal: the kept rows are (nearly) dependent
             * here, as at a change point of a mechanism (the flat position of a parallelogram
             * linkage), where the multiplier of the vanishing direction is 0/0.  Raising the
             * pivot to the floor (a modified Cholesky, Gill & Murray 1974) leaves every other
             * direction exact and bounds that one, which the projection then corrects; without
             * it the step size collapsed there (issue 11). */
            if (!(d0 > 0.0) || !(s > -1e-6 * d0)) /* not a near-zero pivot: indefinite */
                return 0;
            s = PIVOT_FLOOR * d0;
        }
        env[oi + i] = dinv[i] = 1.0 / s;
    }
    M->out[1] = rmin;
    return 1;
}

/* x = S^-1 rhs (both in the active rows' order) with the factor L D L^T of schur_factor. */
static void schur_solve(const mb_model *M, const double *rhs, double *x)
{
    idx n = M->ma;
    const idx *order = M->sidx + n, *fc = M->sidx + 2 * n, *off = M->sidx + 3 * n;
    const double *env = M->env;
    double *z = M->z;
    for (idx i = 0; i < n; i++) { /* L z = P rhs (unit diagonal) */
        idx oi = off[i] - fc[i];
        double s = rhs[order[i]];
        for (idx k = fc[i]; k < i; k++)
            s -= env[oi + k] * z[k];
        z[i] = s;
    }
    for (idx i = 0; i < n; i++) /* D y = z */
        z[i] *= env[off[i] + i - fc[i]];
    for (idx i = n - 1; i >= 0; i--) { /* L^T x = y, column by column */
        idx oi = off[i] - fc[i];
        for (idx k = fc[i]; k < i; k++)
            z[k] -= env[oi + k] * z[i];
    }
    for (idx i = 0; i < n; i++)
        x[order[i]] = z[i];
}

/* g = gamma on the active rows (Baumgarte-stabilised when par[2] != 0: gamma - 2 alpha
 * (Phi_q qd - nu) - beta^2 Phi, Baumgarte 1972), Q, and Qt = Q + c p gamma_norm / 2 on each
 * body with an active normalisation row (the modified mass matrix). */
static void rhs_terms(const mb_model *M, const double *Jc)
{
    const double *par = M->par, *qd = M->qd;
    int stab = par[2] != 0.0;
    for (idx u = 0; u < M->ma; u++) {
        idx r = M->sidx[u];
        M->g[u] = M->gamma[r];
        if (stab) {
            const double *Jr = Jc + 14 * r;
            idx b0 = M->rb[2 * r], b1 = M->rb[2 * r + 1];
            double jv = 0.0;
            for (int c = 0; c < 7; c++)
                jv += Jr[c] * qd[7 * b0 + c];
            if (b1 >= 0)
                for (int c = 0; c < 7; c++)
                    jv += Jr[7 + c] * qd[7 * b1 + c];
            M->g[u] -= 2.0 * par[0] * (jv - M->nu[r]) + par[1] * par[1] * M->phi[r];
        }
    }
    mb_applied_forces(M);
    memcpy(M->Qt, M->Q, (size_t)M->nq * sizeof(double));
    for (idx b = 0; b < M->nb; b++)
        if (M->nrm[b] >= 0) {
            double h = 0.5 * M->bt[NB * b + 19] * M->g[M->nrm[b]];
            for (int m = 0; m < 4; m++)
                M->Qt[7 * b + 3 + m] += h * M->q[7 * b + 3 + m];
        }
}

/* y (nq,) += sign (Phi_q Mt^-1)^T lam (sign +-1): incidence by incidence in the order of
 * `inc`, y[c] += x[c] h or y[c] -= x[c] h (x = XG[g], h = lam of its row), each component's
 * sum in that order.  `inc` is grouped by body, so a body's 7 components stay in registers
 * over its run of incidences instead of a store and a load between two incidences (the same
 * operations in the same order: the same bits). */
static void add_incidences(const mb_model *M, const double *lam, double sign, double *y)
{
    const idx *inc = M->inc;
    for (idx k = 0; k < M->ninc;) {
        idx b = inc[3 * k + 2];
        double *yb = y + 7 * b, a[7];
        for (int c = 0; c < 7; c++)
            a[c] = yb[c];
        for (; k < M->ninc && inc[3 * k + 2] == b; k++) {
            const double *x = M->XG + 8 * k;
            double h = lam[inc[3 * k]];
            if (sign < 0.0)
                for (int c = 0; c < 7; c++)
                    a[c] -= x[c] * h;
            else
                for (int c = 0; c < 7; c++)
                    a[c] += x[c] * h;
        }
        for (int c = 0; c < 7; c++)
            yb[c] = a[c];
    }
}

/* A held body's own rows alone fix its part of x (qdd: Phi_bb qdd_b = gamma_b; dq: Phi_bb dq_b
 * = Phi_b), which the solve on S (own rows decoupled) gives; the other rows u then ask
 * Phi_um x_m = ... - Phi_ub x_b.  With d = S^-1 (sum over CROSS incidences Phi_ub x_b):
 * x_m -= Mt^-1 Phi_q^T d and lam += sign d (accelerations: +1, lam = S^-1 (Phi_q Mt^-1 Qt -
 * gamma); projections: -1, lam = S^-1 rhs).  Nothing to do when x_b = 0 (a held body at
 * rest: the ground), the usual case. */
static void held_coupling(const mb_model *M, double *x, double sign)
{
    const idx *inc = M->inc;
    double *d = M->srhs;
    int any = 0;
    memset(d, 0, (size_t)M->ma * sizeof(double));
    for (idx k = 0; k < M->ninc; k++)
        if (inc[3 * k + 1] >= CROSS) {
            const double *xb = x + 7 * inc[3 * k + 2], *J = M->JG + 8 * k;
            double s = 0.0;
            for (int c = 0; c < 7; c++)
                s += J[c] * xb[c];
            if (s != 0.0) {
                d[inc[3 * k]] += s;
                any = 1;
            }
        }
    if (!any)
        return;
    schur_solve(M, d, d);
    for (idx u = 0; u < M->ma; u++)
        M->lam[u] += sign * d[u];
    for (idx k = 0; k < M->ninc; k++) { /* own incidences of held bodies: d = 0 there */
        const double *xg = M->XG + 8 * k;
        double *y = x + 7 * inc[3 * k + 2], h = d[inc[3 * k]];
        for (int c = 0; c < 7; c++)
            y[c] -= xg[c] * h;
    }
}

/* The multipliers of the rows that hold a body alone (CROSS): S left the other rows' entries
 * in its columns out, so its own rows' lam_b balance Qt_b alone; the body's block of the
 * equations of motion (qdd_b = 0) adds Phi_bb^-T f, f = -sum over the other rows u of
 * Phi_ub^T lam_u.  Phi_bb^-T = S_bb^-1 Phi_bb Mt_b^-1 (S_bb = Phi_bb Mt_b^-1 Phi_bb^T, its
 * own block of S, which nothing couples to the rest), so one more solve with the right-hand
 * side XG_g . f on the own incidences g (zero elsewhere, and so is the solution there). */
static void fixed_body_multipliers(const mb_model *M)
{
    const idx *inc = M->inc;
    double *rhs = M->srhs;
    int any = 0;
    memset(rhs, 0, (size_t)M->ma * sizeof(double));
    for (idx g0 = 0, g1; g0 < M->ninc; g0 = g1) { /* incidences grouped by body */
        idx b = inc[3 * g0 + 2];
        double f[7] = {0.0};
        int cross = 0;
        for (g1 = g0; g1 < M->ninc && inc[3 * g1 + 2] == b; g1++)
            if (inc[3 * g1 + 1] >= CROSS) {
                double h = M->lam[inc[3 * g1]];
                cross = any = 1;
                for (int c = 0; c < 7; c++)
                    f[c] += M->JG[8 * g1 + c] * h;
            }
        if (!cross)
            continue;
        for (idx g = g0; g < g1; g++)
            if (inc[3 * g + 1] < CROSS) {
                double s = 0.0;
                for (int c = 0; c < 7; c++)
                    s += M->XG[8 * g + c] * f[c];
                rhs[inc[3 * g]] -= s;
            }
    }
    if (!any)
        return;
    schur_solve(M, rhs, rhs);
    for (idx u = 0; u < M->ma; u++)
        M->lam[u] += rhs[u];
}

/* lam = S^-1 (Phi_q Mt^-1 Qt - g), qdd = Mt^-1 (Qt - Phi_q^T lam); factored: Mi, XG and
 * the factor of S are already those of Jc at M->q (the last mb_project, unit 0). */
static int solve_schur(const mb_model *M, const double *Jc, int factored)
{
    const idx *inc = M->inc;
    if (!factored) {
        minv_blocks(M, 0);
        if (!schur_factor(M, Jc, 0))
            return STATUS_NOT_PD;
    }
    double *rhs = M->srhs;
    for (idx u = 0; u < M->ma; u++)
        rhs[u] = -M->g[u];
    for (idx k = 0; k < M->ninc; k++) { /* + Phi_q Mt^-1 Qt */
        const double *x = M->XG + 8 * k, *Qt = M->Qt + 7 * inc[3 * k + 2];
        double s = 0.0;
        for (int c = 0; c < 7; c++)
            s += x[c] * Qt[c];
        rhs[inc[3 * k]] += s;
    }
    schur_solve(M, rhs, M->lam);
    for (idx b = 0; b < M->nb; b++)
        apply_minv(M, 0, b, M->Qt + 7 * b, M->qdd + 7 * b);
    add_incidences(M, M->lam, -1.0, M->qdd); /* - (Phi_q Mt^-1)^T lam */
    held_coupling(M, M->qdd, 1.0);
    fixed_body_multipliers(M);
    return STATUS_OK;
}

/* LU with partial pivoting of the row-major (n, n) A in place (Golub & Van Loan Alg. 3.4.1),
 * piv (n,) the row swapped with each row.  Returns the smallest |pivot| / largest |pivot|
 * (0: an exactly zero pivot, factorisation stopped). */
static double dense_lu(double *A, idx *piv, idx n)
{
    double pmin = INFINITY, pmax = 0.0;
    for (idx k = 0; k < n; k++) {
        idx p = k;
        double big = fabs(A[k * n + k]);
        for (idx i = k + 1; i < n; i++)
            if (fabs(A[i * n + k]) > big) {
                big = fabs(A[i * n + k]);
                p = i;
            }
        piv[k] = p;
        if (big == 0.0)
            return 0.0;
        if (p != k)
            for (idx j = 0; j < n; j++) {
                double t = A[k * n + j];
                A[k * n + j] = A[p * n + j];
                A[p * n + j] = t;
            }
        pmin = big < pmin ? big : pmin;
        pmax = big > pmax ? big : pmax;
        double inv = 1.0 / A[k * n + k];
        for (idx i = k + 1; i < n; i++) {
            double l = A[i * n + k] *= inv;
            if (l != 0.0)
                for (idx j = k + 1; j < n; j++)
                    A[i * n + j] -= l * A[k * n + j];
        }
    }
    return n > 0 ? pmin / pmax : 1.0;
}

/* x (n,) := A^-1 x (trans = 0) or A^-T x (trans = 1) from dense_lu's factors. */
static void dense_lu_solve(const double *LU, const idx *piv, idx n, double *x, int trans)
{
    if (!trans) {
        for (idx k = 0; k < n; k++) { /* P, then L (unit) forward, then U backward */
            double t = x[k];
            x[k] = x[piv[k]];
            x[piv[k]] = t;
        }
        for (idx i = 0; i < n; i++)
            for (idx j = 0; j < i; j++)
                x[i] -= LU[i * n + j] * x[j];
        for (idx i = n - 1; i >= 0; i--) {
            for (idx j = i + 1; j < n; j++)
                x[i] -= LU[i * n + j] * x[j];
            x[i] /= LU[i * n + i];
        }
    } else { /* A^T = U^T L^T P: U^T forward, L^T backward, then P^T */
        for (idx i = 0; i < n; i++) {
            for (idx j = 0; j < i; j++)
                x[i] -= LU[j * n + i] * x[j];
            x[i] /= LU[i * n + i];
        }
        for (idx i = n - 1; i >= 0; i--)
            for (idx j = i + 1; j < n; j++)
                x[i] -= LU[j * n + i] * x[j];
        for (idx k = n - 1; k >= 0; k--) {
            double t = x[k];
            x[k] = x[piv[k]];
            x[piv[k]] = t;
        }
    }
}

/* [M, Phi_q^T; Phi_q, 0] [qdd; lam] = [Q; g] by dense LU with partial pivoting (Haug
 * Ch. 11): for models where some J' is singular (no exact Mt^-1).  Returns STATUS_SINGULAR
 * on an exactly zero pivot (as LAPACK's dgesv). */
static int solve_kkt(const mb_model *M, const double *Jc)
{
    idx nq = M->nq, ma = M->ma, n = nq + ma;
    double *K = M->K, *x = M->kr;
    mb_mass_blocks(M);
    memset(K, 0, (size_t)(n * n) * sizeof(double));
    for (idx b = 0; b < M->nb; b++)
        for (int i = 0; i < 7; i++)
            for (int j = 0; j < 7; j++)
                K[(7 * b + i) * n + 7 * b + j] = M->Mb[49 * b + 7 * i + j];
    for (idx u = 0; u < ma; u++) {
        idx r = M->sidx[u];
        for (int s = 0; s < 2; s++) {
            idx b = M->rb[2 * r + s];
            if (b < 0)
                continue;
            for (int c = 0; c < 7; c++) {
                K[(nq + u) * n + 7 * b + c] += Jc[14 * r + 7 * s + c];
                K[(7 * b + c) * n + nq + u] += Jc[14 * r + 7 * s + c];
            }
        }
    }
    memcpy(x, M->Q, (size_t)nq * sizeof(double));
    memcpy(x + nq, M->g, (size_t)ma * sizeof(double));
    if (dense_lu(K, M->kp, n) == 0.0)
        return STATUS_SINGULAR;
    dense_lu_solve(K, M->kp, n, x, 0);
    memcpy(M->qdd, x, (size_t)nq * sizeof(double));
    memcpy(M->lam, x + nq, (size_t)ma * sizeof(double));
    return STATUS_OK;
}

/* (qdd, lam) of the equations of motion at (q, qd): the constraint terms, the applied forces,
 * then the Schur complement of Mt, or the dense KKT matrix when kkt.  have_jac: JAC_HERE
 * (0) evaluates Phi_q here; JAC_CALLER (1): the compact Phi_q is the caller's Jg (m, 14);
 * JAC_FACTORED (2): Jc is already that of M->q and, unless kkt, so are Mi, XG and the Schur
 * factor (the last call was mb_project at this q: the step's projection, whose S = Phi_q
 * Mt^-1 Phi_q^T is the one needed here), so neither is computed again (the same numbers).
 * out[0] = power Q.qd - lam.nu.  Returns a STATUS_*. */
int mb_accelerations(const mb_model *M, int kkt, int have_jac)
{
    mb_constraints(M, have_jac == JAC_HERE, 1);
    const double *Jc = have_jac == JAC_CALLER ? M->Jg : M->Jc;
    int factored = have_jac == JAC_FACTORED && !kkt;
    rhs_terms(M, Jc);
    if (!factored) /* (else out[1] stays the pivot ratio of that factorisation) */
        M->out[1] = 1.0;
    int status = kkt ? solve_kkt(M, Jc) : solve_schur(M, Jc, factored);
    if (status != STATUS_OK)
        return status;
    double power = 0.0;
    for (idx i = 0; i < M->nq; i++)
        power += M->Q[i] * M->qd[i];
    for (idx u = 0; u < M->ma; u++)
        power -= M->lam[u] * M->nu[M->sidx[u]];
    M->out[0] = power;
    return STATUS_OK;
}

void mb_project_factored(const mb_model *M);

/* dq (nq,) = Mt^-1 Phi_q^T S^-1 rhs: the weighted least-norm correction with Phi_q dq = rhs
 * on the active rows (Phi_q: Jc of the last mb_constraints; unit: identity metric).
 * Returns a STATUS_*. */
int mb_project(const mb_model *M, int unit)
{
    minv_blocks(M, unit);
    if (!schur_factor(M, M->Jc, unit))
        return STATUS_NOT_PD;
    mb_project_factored(M);
    return STATUS_OK;
}

/* mb_project on the Schur factor already in the model (Mi, XG and the factor of S left by
 * the last mb_accelerations or mb_project, unit 0, at this q and Phi_q: step.c's
 * projections right after a derivative at the same q), so nothing is factored again. */
void mb_project_factored(const mb_model *M)
{
    schur_solve(M, M->rhs, M->lam);
    memset(M->dq, 0, (size_t)M->nq * sizeof(double));
    add_incidences(M, M->lam, 1.0, M->dq);
    held_coupling(M, M->dq, -1.0);
}

/* -- kinematic analysis: Phi = 0, Phi_q qd = nu, Phi_q qdd = gamma on one LU --------------- */

enum { KIN_NOT_CONVERGED = 3 };

/* Phi_q on the rows `rows` as a dense row-major (ma, nq) matrix (gather's mode 1). */
static void dense_rows(const mb_model *M, double *J)
{
    memset(J, 0, (size_t)(M->ma * M->nq) * sizeof(double));
    for (idx k = 0; k < M->ma; k++) {
        idx r = M->rows[k], c0 = 7 * M->rb[2 * r], c1 = 7 * M->rb[2 * r + 1];
        const double *Jr = M->Jc + 14 * r;
        double *Jk = J + M->nq * k;
        for (int c = 0; c < 7; c++)
            Jk[c0 + c] += Jr[c];
        if (c1 >= 0)
            for (int c = 0; c < 7; c++)
                Jk[c1 + c] += Jr[7 + c];
    }
}

/* Largest eigenvalue of the symmetric tridiagonal T (diagonal a (k,), off-diagonal b (k-1,))
 * by bisection on the Sturm count (Golub & Van Loan Sec. 8.4.1), to 1e-15 relative. */
static double tridiagonal_max(const double *a, const double *b, idx k)
{
    double lo = a[0], hi = -INFINITY;
    for (idx i = 0; i < k; i++) {
        double r = (i > 0 ? fabs(b[i - 1]) : 0.0) + (i < k - 1 ? fabs(b[i]) : 0.0);
        lo = fmax(lo, a[i]);
        hi = fmax(hi, a[i] + r);
    }
    for (int it = 0; it < 200 && hi - lo > 1e-15 * fabs(hi); it++) {
        double x = 0.5 * (lo + hi), d = 1.0;
        idx below = 0; /* eigenvalues < x: negative pivots of T - x I */
        for (idx i = 0; i < k; i++) {
            d = a[i] - x - (i > 0 ? b[i - 1] * b[i - 1] / d : 0.0);
            if (d == 0.0)
                d = -1e-300;
            below += d < 0.0;
        }
        if (below == k)
            hi = x;
        else
            lo = x;
    }
    return hi;
}

/* Largest eigenvalue of J^T J (inv = 0) or of (J^T J)^-1 = J^-1 J^-T (inv = 1) by Lanczos
 * with full reorthogonalisation (Golub & Van Loan Sec. 10.1), stopped when the largest Ritz
 * value changes by less than 1e-10 relative (extreme eigenvalues converge first) or the
 * Krylov space is invariant.  J (n, n) and its LU; V: work n (n + 1); w, a, b: work (n,). */
static double lanczos_max(const double *J, const double *LU, const idx *piv, idx n, int inv,
                          double *V, double *w, double *a, double *b)
{
    double nrm = 0.0, ritz = 0.0;
    for (idx i = 0; i < n; i++) {
        V[i] = 1.0 + 0.5 * sin(1.0 + 7.0 * (double)i); /* no special direction */
        nrm += V[i] * V[i];
    }
    nrm = sqrt(nrm);
    for (idx i = 0; i < n; i++)
        V[i] /= nrm;
    for (idx k = 0; k < n; k++) {
        double *v = V + n * k;
        if (inv) { /* w = J^-1 J^-T v */
            memcpy(w, v, (size_t)n * sizeof(double));
            dense_lu_solve(LU, piv, n, w, 1);
            dense_lu_solve(LU, piv, n, w, 0);
        } else { /* w = J^T (J v), through the next column of V as scratch */
            double *y = V + n * (k + 1);
            for (idx i = 0; i < n; i++) {
                double s = 0.0;
                for (idx j = 0; j < n; j++)
                    s += J[i * n + j] * v[j];
                y[i] = s;
            }
            memset(w, 0, (size_t)n * sizeof(double));
            for (idx i = 0; i < n; i++)
                for (idx j = 0; j < n; j++)
                    w[j] += J[i * n + j] * y[i];
        }
        double al = 0.0;
        for (idx i = 0; i < n; i++)
            al += w[i] * v[i];
        a[k] = al;
        for (int pass = 0; pass < 2; pass++) /* w -= V_k (V_k^T w), twice */
            for (idx j = 0; j <= k; j++) {
                const double *u = V + n * j;
                double h = 0.0;
                for (idx i = 0; i < n; i++)
                    h += u[i] * w[i];
                for (idx i = 0; i < n; i++)
                    w[i] -= h * u[i];
            }
        double bk = 0.0;
        for (idx i = 0; i < n; i++)
            bk += w[i] * w[i];
        bk = sqrt(bk);
        double prev = ritz;
        ritz = tridiagonal_max(a, b, k + 1);
        if (!isfinite(ritz) || (k > 0 && fabs(ritz - prev) <= 1e-10 * fabs(ritz)) ||
            bk <= 1e-14 * fabs(ritz) || k == n - 1)
            break;
        b[k] = bk;
        for (idx i = 0; i < n; i++)
            V[n * (k + 1) + i] = w[i] / bk;
    }
    return ritz;
}

/* One output of a kinematic analysis (DOF 0: the rows `rows` square, ma == nq), Haug Ch.
 * 10: Newton from the predictor M->q onto Phi(q, t) = 0 on `rows` until max |Phi| <= tol
 * (at most max_iter steps, dense LU of Phi_q each), then qd from Phi_q qd = nu into M->qd
 * and qdd from Phi_q qdd = gamma into M->qdd on the LU of Phi_q at the solution.  The time
 * targets M->tv are the caller's.  work: 3 nq^2 + 4 nq doubles; piv: nq.  info[0] = Newton
 * iterations, info[1] = max |Phi| on `rows`, info[2] = cond_2(Phi_q) when want_cond (power
 * Lanczos on J^T J and on its inverse), info[3] = smallest / largest LU pivot.  Returns
 * STATUS_OK, STATUS_SINGULAR (a zero pivot) or KIN_NOT_CONVERGED. */
int mb_kinematic(const mb_model *M, double tol, int64_t max_iter, int want_cond, double *work,
                 idx *piv, double *info)
{
    idx n = M->nq;
    double *LU = work, *J = work + n * n, *V = J + n * n, *w = V + n * (n + 1), *q = M->q;
    info[2] = NAN;
    for (int64_t it = 0;; it++) {
        mb_constraints(M, 1, 0);
        double res = 0.0;
        for (idx k = 0; k < n; k++)
            res = fmax(res, fabs(M->phi[M->rows[k]]));
        info[0] = (double)it;
        info[1] = res;
        dense_rows(M, LU);
        if (!isfinite(res))
            return KIN_NOT_CONVERGED;
        if (res <= tol) {
            if (want_cond)
                memcpy(J, LU, (size_t)(n * n) * sizeof(double));
            info[3] = dense_lu(LU, piv, n);
            if (info[3] == 0.0)
                return STATUS_SINGULAR;
            break;
        }
        if (it == max_iter)
            return KIN_NOT_CONVERGED;
        info[3] = dense_lu(LU, piv, n);
        if (info[3] == 0.0)
            return STATUS_SINGULAR;
        for (idx k = 0; k < n; k++)
            M->dq[k] = -M->phi[M->rows[k]];
        dense_lu_solve(LU, piv, n, M->dq, 0);
        for (idx k = 0; k < n; k++)
            q[k] += M->dq[k];
    }
    for (idx k = 0; k < n; k++) /* nu of the last evaluation (q, t) */
        M->qd[k] = M->nu[M->rows[k]];
    dense_lu_solve(LU, piv, n, M->qd, 0);
    mb_constraints(M, 0, 1); /* gamma at (q, qd); Jc stays that of q */
    for (idx k = 0; k < n; k++)
        M->qdd[k] = M->gamma[M->rows[k]];
    dense_lu_solve(LU, piv, n, M->qdd, 0);
    if (want_cond) {
        double smax2 = lanczos_max(J, LU, piv, n, 0, V, w, w + n, w + 2 * n);
        double sinv2 = lanczos_max(J, LU, piv, n, 1, V, w, w + n, w + 2 * n);
        info[2] = sqrt(smax2 * sinv2);
    }
    return STATUS_OK;
}

/* -- the modified mass matrix applied to vectors ------------------------------------------- */

/* Y (k, nq) = Mt^-1 X (k, nq) at M->q, row by row: Mt = M + c p p^T on each Euler-parameter
 * block (mbsim/fast/dynamics.py's module doc), identity when unit. */
void mb_apply_minv(const mb_model *M, int unit, int64_t k, const double *X, double *Y)
{
    minv_blocks(M, unit);
    for (int64_t r = 0; r < k; r++)
        for (idx b = 0; b < M->nb; b++)
            apply_minv(M, unit, b, X + r * M->nq + 7 * b, Y + r * M->nq + 7 * b);
}
