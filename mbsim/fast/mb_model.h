/* mb_model: the caller's view of one model, shared by kernels.c and step.c (plain C99).
 *
 * One definition for both files of the library; mbsim.fast._lib.Struct mirrors it field for
 * field (SIZES, then POINTERS) and checks sizeof(mb_model) (mb_struct_size) at load time.
 * The tables' shapes are documented in kernels.c's header.
 */
#ifndef MB_MODEL_H
#define MB_MODEL_H

#include <stdint.h>

typedef int64_t idx;

/* Sizes, static tables, per-call inputs, outputs, work. */
typedef struct {
    idx nb, nq, m, ma, nc, ninc, npairs, nenv, ne;
    const idx *ci;
    const double *cf;
    const idx *rb;    /* (m, 2) bodies of each row */
    const idx *rows;  /* (ma,) the rows returned by mb_terms */
    const idx *dpos;  /* (ma, 14) CSR position of each compact entry (-1: none) */
    const idx *sidx, *inc, *pairs;
    const double *bt;
    const idx *nrm;   /* (nb,) active position of each body's normalisation row, -1 */
    const idx *ei;
    const double *ef;
    /* inputs, written by the caller before a call */
    double *q, *qd, *tv, *loads, *par, *Jg, *rhs;
    /* outputs on all rows */
    double *phi, *Jc, *gamma, *nu;
    /* outputs on the rows `rows` */
    double *phi_a, *gamma_a, *nu_a, *J, *data;
    /* dynamics outputs: Q (nq), qdd (nq), lam (ma), dq (nq), out[0] = power, out[1] = the
     * smallest pivot ratio of the last Schur factorisation (schur_factor) */
    double *Q, *qdd, *lam, *dq, *out;
    /* work: Qt (nq), g (ma), Mi (nb*16), XG, JG (ninc*8), env (nenv), srhs, z (ma),
     * K ((nq+ma)^2), kr (nq+ma), Mb (nb*49), A (nb*9), F, n, w (nb*3) */
    double *Qt, *g, *Mi, *XG, *JG, *env, *srhs, *z, *K, *kr, *Mb, *A, *F, *n, *w;
    idx *kp; /* work: the pivots of the dense KKT factorisation (nq+ma) */
} mb_model;

#endif
