/*
 * fm_me.c - the model-exchange master's integration loop (see fm_me.h for the contract).
 *
 * The integrator follows scipy.integrate.Radau (scipy 1.17, radau.py) line by line: the names
 * below are its names (solve_collocation_system, predict_factor, _step_impl).
 */
#include <math.h>
#include <string.h>

#include "fm_me.h"

#ifndef FP_SOURCE_DIGEST
#define FP_SOURCE_DIGEST "unknown"
#endif

FME_API int fme_abi(void) { return FME_ABI; }

FME_API const char *fme_source_digest(void) { return FP_SOURCE_DIGEST; }

FME_API size_t fme_sizeof_unit(void) { return sizeof(fme_unit); }

FME_API size_t fme_sizeof_master(void) { return sizeof(fme_master); }

/* ---------------------------------------------------------------- Radau IIA constants */
#define S6 2.449489742783178098197284074705891391965947480656670128432692567
static const double C_[3] = {(4.0 - S6) / 10.0, (4.0 + S6) / 10.0, 1.0};
static const double E_[3] = {(-13.0 - 7.0 * S6) / 3.0, (-13.0 + 7.0 * S6) / 3.0, -1.0 / 3.0};
static const double T_[3][3] = {
    {0.09443876248897524, -0.14125529502095421, 0.03002919410514742},
    {0.25021312296533332, 0.20412935229379994, -0.38294211275726192},
    {1.0, 1.0, 0.0}};
static const double TI_[3][3] = {
    {4.17871859155190428, 0.32768282076106237, 0.52337644549944951},
    {-4.17871859155190428, -0.32768282076106237, 0.47662355450055044},
    {0.50287263494578682, -2.57192694985560522, 0.59603920482822492}};
static const double P_[3][3] = {
    {13.0 / 3.0 + 7.0 * S6 / 3.0, -23.0 / 3.0 - 22.0 * S6 / 3.0, 10.0 / 3.0 + 5.0 * S6},
    {13.0 / 3.0 - 7.0 * S6 / 3.0, -23.0 / 3.0 + 22.0 * S6 / 3.0, 10.0 / 3.0 - 5.0 * S6},
    {1.0 / 3.0, -8.0 / 3.0, 10.0 / 3.0}};
#define NEWTON_MAXITER 6
#define MIN_FACTOR 0.2
#define MAX_FACTOR 10.0
#define EPS 2.220446049250313e-16

/* The eigenvalues of the Radau IIA matrix's inverse: MU_REAL = 3 + 3^(2/3) - 3^(1/3), and
 * MU_COMPLEX = 3 + (3^(1/3) - 3^(2/3)) / 2 - i (3^(5/6) + 3^(7/6)) / 2 (scipy's values). */
#define MU_REAL 3.637834252744496
#define MU_COMPLEX_RE 2.6810828736277523
#define MU_COMPLEX_IM (-3.050430199247411)

/* ---------------------------------------------------------------- the work arrays */
/* Pointers into m->work and m->iwork (laid out by layout()). */
typedef struct ws {
    double *y, *f, *y_old, *y_new, *f_new, *scale, *err, *ze, *tmp, *dense, *z_event;
    double *Q, *Z, *Z0, *W, *F, *dW;          /* 3 x nx each, row-major */
    double *J, *LUr;                          /* nx x nx */
    double *LUc_re, *LUc_im, *fc_re, *fc_im;  /* the complex matrix (nx x nx), right side (nx) */
    double *inv_re, *inv_im;                  /* (nx) inverses of its LU's diagonal */
    double *yall, *zind, *znew, *zbuf;        /* ny; nz; nz; nz */
    double *A, *B, *Cm, *D, *M, *R, *sens;    /* Jacobian blocks; sens: the largest unit's */
    int *piv_r, *piv_c, *piv_m, *sx, *sy, *su;
    int *unk, *kn;                            /* value references of one unit's partials */
    int *pat_r, *pat_c;                       /* the real and complex LUs' patterns */
    double *pt_z;                             /* (nx) the states the FMUs were last set to */
} ws;

static int max_unknowns(const fme_master *m)
{
    int k = 1;
    for (int i = 0; i < m->n_units; i++) {
        const fme_unit *u = &m->units[i];
        int a = u->nx + u->n_out, b = u->nx + u->n_in;
        if (a > k) k = a;
        if (b > k) k = b;
    }
    return k;
}

/* Lay the arrays out from base pointers (NULL: only count); the counts in doubles and ints. */
static void layout(const fme_master *m, double *dbase, int *ibase, ws *w, size_t *nd, size_t *ni)
{
    size_t n = (size_t)m->nx, ny = (size_t)m->ny, nu = (size_t)m->nu, nz = (size_t)m->nz;
    size_t d = 0, i = 0, mu = (size_t)max_unknowns(m);
#define TAKE(field, count) do { if (w) w->field = dbase + d; d += (count); } while (0)
#define TAKEI(field, count) do { if (w) w->field = ibase + i; i += (count); } while (0)
    TAKE(y, n); TAKE(f, n); TAKE(y_old, n); TAKE(y_new, n); TAKE(f_new, n); TAKE(scale, n);
    TAKE(err, n); TAKE(ze, n); TAKE(tmp, n); TAKE(dense, n); TAKE(z_event, n);
    TAKE(Q, 3 * n); TAKE(Z, 3 * n); TAKE(Z0, 3 * n); TAKE(W, 3 * n); TAKE(F, 3 * n);
    TAKE(dW, 3 * n); TAKE(J, n * n); TAKE(LUr, n * n);
    TAKE(LUc_re, n * n); TAKE(LUc_im, n * n); TAKE(fc_re, n); TAKE(fc_im, n);
    TAKE(inv_re, n); TAKE(inv_im, n);
    TAKE(yall, ny + 1); TAKE(zind, nz + 1); TAKE(znew, nz + 1); TAKE(zbuf, nz + 1);
    TAKE(pt_z, n); TAKE(A, n * n); TAKE(B, n * nu + 1); TAKE(Cm, ny * n + 1); TAKE(D, ny * nu + 1);
    TAKE(M, nu * nu + 1); TAKE(R, nu * n + 1); TAKE(sens, mu);
    TAKEI(piv_r, n); TAKEI(piv_c, n); TAKEI(piv_m, nu + 1);
    TAKEI(sx, (size_t)m->n_units); TAKEI(sy, (size_t)m->n_units); TAKEI(su, (size_t)m->n_units);
    TAKEI(unk, mu); TAKEI(kn, mu);
    TAKEI(pat_r, 2 * (n * n + n + 1)); TAKEI(pat_c, 2 * (n * n + n + 1));
#undef TAKE
#undef TAKEI
    if (nd) *nd = d;
    if (ni) *ni = i;
}

FME_API size_t fme_work_doubles(const fme_master *m)
{
    size_t d;
    layout(m, NULL, NULL, NULL, &d, NULL);
    return d;
}

FME_API size_t fme_work_ints(const fme_master *m)
{
    size_t i;
    layout(m, NULL, NULL, NULL, NULL, &i);
    return i;
}

static void get_ws(fme_master *m, ws *w)
{
    layout(m, m->work, m->iwork, w, NULL, NULL);
    if (!m->laid_out) {
        int sx = 0, sy = 0, su = 0;
        for (int k = 0; k < m->n_units; k++) {
            w->sx[k] = sx; w->sy[k] = sy; w->su[k] = su;
            sx += m->units[k].nx; sy += m->units[k].n_out; su += m->units[k].n_in;
        }
        m->laid_out = 1;
    }
}

/* ---------------------------------------------------------------- the FMI calls */
static int fail(fme_master *m, int unit, int call, int status, double t)
{
    m->fail_unit = unit;
    m->fail_call = call;
    m->fail_status = status;
    m->fail_time = t;
    return FME_FAILED;
}

#define CHECK(unit, call, expr) do { int s_ = (expr); \
    if (s_ > 1) return fail(m, (unit), (call), s_, t); } while (0)

/* Time and states of every unit, then the connected outputs and inputs (_set_point). The
 * FMUs are not set again to the point they were last set to (nothing else sets them between
 * two calls of this loop: fme_run, fme_start and fme_restart forget the point). */
static int set_point(fme_master *m, ws *w, double t, const double *z)
{
    double *y = w->yall;
    if (m->pt_valid && t == m->pt_t && memcmp(z, w->pt_z, sizeof(double) * (size_t)m->nx) == 0)
        return FME_DONE;
    m->pt_valid = 0;
    for (int k = 0; k < m->n_units; k++) {
        fme_unit *u = &m->units[k];
        CHECK(k, FME_CALL_SET_TIME, u->set_time(u->c, t));
        if (u->nx)
            CHECK(k, FME_CALL_SET_X, u->set_x(u->c, z + w->sx[k], (size_t)u->nx));
    }
    for (int j = 0; j < m->n_units; j++) {
        int k = m->order[j];
        fme_unit *u = &m->units[k];
        if (u->n_early) {
            double *v = w->sens;          /* n_early <= n_in: sens is large enough */
            for (int i = 0; i < u->n_early; i++)
                v[i] = y[u->early_pos[i]];
            CHECK(k, FME_CALL_SET_REAL, u->set_real(u->c, u->early_vr, (size_t)u->n_early, v));
        }
        if (u->n_out)
            CHECK(k, FME_CALL_GET_REAL, u->get_real(u->c, u->out_vr, (size_t)u->n_out,
                                                    y + w->sy[k]));
    }
    for (int j = 0; j < m->n_units; j++) {
        int k = m->order[j];
        fme_unit *u = &m->units[k];
        if (u->n_late) {
            double *v = w->sens;
            for (int i = 0; i < u->n_late; i++)
                v[i] = y[u->late_pos[i]];
            CHECK(k, FME_CALL_SET_REAL, u->set_real(u->c, u->late_vr, (size_t)u->n_late, v));
        }
    }
    memcpy(w->pt_z, z, sizeof(double) * (size_t)m->nx);
    m->pt_t = t;
    m->pt_valid = 1;
    return FME_DONE;
}

/* dz = F(t, z) (rhs). */
static int rhs(fme_master *m, ws *w, double t, const double *z, double *dz)
{
    int rc;
    m->evaluations++;
    if ((rc = set_point(m, w, t, z)) != FME_DONE)
        return rc;
    for (int k = 0; k < m->n_units; k++) {
        fme_unit *u = &m->units[k];
        if (u->nx)
            CHECK(k, FME_CALL_GET_DX, u->get_dx(u->c, dz + w->sx[k], (size_t)u->nx));
    }
    return FME_DONE;
}

/* The event indicators at (t, z) into zz (_indicators). */
static int indicators(fme_master *m, ws *w, double t, const double *z, double *zz)
{
    int rc, off = 0;
    if ((rc = set_point(m, w, t, z)) != FME_DONE)
        return rc;
    for (int k = 0; k < m->n_units; k++) {
        fme_unit *u = &m->units[k];
        if (u->nz)
            CHECK(k, FME_CALL_GET_Z, u->get_z(u->c, zz + off, (size_t)u->nz));
        off += u->nz;
    }
    return FME_DONE;
}

/* ---------------------------------------------------------------- dense linear algebra */
/* LU with partial pivoting in place (row-major n x n); 0, or 1 if singular. */
static int lu_real(double *a, int *piv, int n)
{
    int sing = 0;
    for (int k = 0; k < n; k++) {
        int p = k;
        for (int i = k + 1; i < n; i++)
            if (fabs(a[i * n + k]) > fabs(a[p * n + k])) p = i;
        piv[k] = p;
        if (p != k)
            for (int j = 0; j < n; j++) {
                double s = a[k * n + j]; a[k * n + j] = a[p * n + j]; a[p * n + j] = s;
            }
        if (a[k * n + k] == 0.0) { sing = 1; continue; }
        for (int i = k + 1; i < n; i++) {
            double l;
            if (a[i * n + k] == 0.0) continue;   /* a zero multiplier changes nothing */
            l = a[i * n + k] / a[k * n + k];
            a[i * n + k] = l;
            for (int j = k + 1; j < n; j++)
                a[i * n + j] -= l * a[k * n + j];
        }
    }
    return sing;
}

static void solve_real(const double *a, const int *piv, int n, double *b)
{
    for (int k = 0; k < n; k++)
        if (piv[k] != k) { double s = b[k]; b[k] = b[piv[k]]; b[piv[k]] = s; }
    for (int i = 1; i < n; i++)
        for (int j = 0; j < i; j++) b[i] -= a[i * n + j] * b[j];
    for (int i = n - 1; i >= 0; i--) {
        for (int j = i + 1; j < n; j++) b[i] -= a[i * n + j] * b[j];
        b[i] /= a[i * n + i];
    }
}

/* 1 / (re + i im) by Smith's algorithm. */
static void reciprocal(double re, double im, double *out_re, double *out_im)
{
    if (fabs(re) >= fabs(im)) {
        double r = im / re, d = re + im * r;
        *out_re = 1.0 / d;
        *out_im = -r / d;
    } else {
        double r = re / im, d = re * r + im;
        *out_re = r / d;
        *out_im = -1.0 / d;
    }
}

/* Complex LU with partial pivoting (LAPACK's pivot: the largest |re| + |im|) in place, real and
 * imaginary parts in separate row-major arrays; the inverses of the diagonal in inv. */
static void lu_complex(double *ar, double *ai, double *inv_r, double *inv_i, int *piv, int n)
{
    for (int k = 0; k < n; k++) {
        int p = k;
        double best = fabs(ar[k * n + k]) + fabs(ai[k * n + k]);
        for (int i = k + 1; i < n; i++) {
            double v = fabs(ar[i * n + k]) + fabs(ai[i * n + k]);
            if (v > best) { best = v; p = i; }
        }
        piv[k] = p;
        if (p != k)
            for (int j = 0; j < n; j++) {
                double s = ar[k * n + j]; ar[k * n + j] = ar[p * n + j]; ar[p * n + j] = s;
                s = ai[k * n + j]; ai[k * n + j] = ai[p * n + j]; ai[p * n + j] = s;
            }
        if (best == 0.0) { inv_r[k] = inv_i[k] = INFINITY; continue; }
        reciprocal(ar[k * n + k], ai[k * n + k], &inv_r[k], &inv_i[k]);
        for (int i = k + 1; i < n; i++) {
            double lr, li, *rr, *ri;
            const double *kr, *ki;
            if (ar[i * n + k] == 0.0 && ai[i * n + k] == 0.0) continue;
            lr = ar[i * n + k] * inv_r[k] - ai[i * n + k] * inv_i[k];
            li = ar[i * n + k] * inv_i[k] + ai[i * n + k] * inv_r[k];
            rr = ar + i * n; ri = ai + i * n;
            kr = ar + k * n; ki = ai + k * n;
            ar[i * n + k] = lr;
            ai[i * n + k] = li;
            for (int j = k + 1; j < n; j++) {
                rr[j] -= lr * kr[j] - li * ki[j];
                ri[j] -= lr * ki[j] + li * kr[j];
            }
        }
    }
}

/* The nonzeros of an LU factorisation (n x n, row-major; imaginary parts ai or NULL), column by
 * column, for the solves: pat = [L's column starts (n + 1), L's rows (below the diagonal);
 * U's column starts (n + 1), U's rows (above it)], 2 (n n + n + 1) ints. The factors of the
 * Radau systems are sparse (a state no other state drives has a diagonal row), and the
 * solves skip exact zeros only: their results are those of the dense loops summed in
 * column order. */
static void lu_pattern(const double *ar, const double *ai, int n, int *pat)
{
    int *lp = pat, *li = pat + n + 1, *up = pat + n * n + n + 1, *ui = up + n + 1;
    int nl = 0, nu = 0;
    for (int j = 0; j < n; j++) {
        lp[j] = nl;
        up[j] = nu;
        for (int i = 0; i < n; i++) {
            int nz = ar[i * n + j] != 0.0 || (ai && ai[i * n + j] != 0.0);
            if (!nz || i == j) continue;
            if (i > j) li[nl++] = i;
            else ui[nu++] = i;
        }
    }
    lp[n] = nl;
    up[n] = nu;
}

/* Solve with the real LU in place: the row interchanges, then L and U column by column. */
static void solve_real_sparse(const double *a, const int *piv, const int *pat, int n, double *b)
{
    const int *lp = pat, *li = pat + n + 1, *up = pat + n * n + n + 1, *ui = up + n + 1;
    for (int k = 0; k < n; k++)
        if (piv[k] != k) { double s = b[k]; b[k] = b[piv[k]]; b[piv[k]] = s; }
    for (int j = 0; j < n; j++) {
        double bj = b[j];
        if (bj != 0.0)
            for (int q = lp[j]; q < lp[j + 1]; q++) b[li[q]] -= a[li[q] * n + j] * bj;
    }
    for (int j = n - 1; j >= 0; j--) {
        double bj = b[j] /= a[j * n + j];
        if (bj != 0.0)
            for (int q = up[j]; q < up[j + 1]; q++) b[ui[q]] -= a[ui[q] * n + j] * bj;
    }
}

static void solve_complex_sparse(const double *ar, const double *ai, const double *inv_r,
                                 const double *inv_i, const int *piv, const int *pat, int n,
                                 double *br, double *bi)
{
    const int *lp = pat, *li = pat + n + 1, *up = pat + n * n + n + 1, *ui = up + n + 1;
    for (int k = 0; k < n; k++)
        if (piv[k] != k) {
            double s = br[k]; br[k] = br[piv[k]]; br[piv[k]] = s;
            s = bi[k]; bi[k] = bi[piv[k]]; bi[piv[k]] = s;
        }
    for (int j = 0; j < n; j++) {
        double xr = br[j], xi = bi[j];
        if (xr == 0.0 && xi == 0.0) continue;
        for (int q = lp[j]; q < lp[j + 1]; q++) {
            int i = li[q];
            br[i] -= ar[i * n + j] * xr - ai[i * n + j] * xi;
            bi[i] -= ar[i * n + j] * xi + ai[i * n + j] * xr;
        }
    }
    for (int j = n - 1; j >= 0; j--) {
        double xr = br[j] * inv_r[j] - bi[j] * inv_i[j];
        double xi = br[j] * inv_i[j] + bi[j] * inv_r[j];
        br[j] = xr;
        bi[j] = xi;
        if (xr == 0.0 && xi == 0.0) continue;
        for (int q = up[j]; q < up[j + 1]; q++) {
            int i = ui[q];
            br[i] -= ar[i * n + j] * xr - ai[i * n + j] * xi;
            bi[i] -= ar[i * n + j] * xi + ai[i * n + j] * xr;
        }
    }
}

/* RMS norm of x / s (scipy's norm). */
static double rms(const double *x, const double *s, int n)
{
    double sum = 0.0;
    for (int i = 0; i < n; i++) { double v = x[i] / s[i]; sum += v * v; }
    return sqrt(sum / n);
}

/* ---------------------------------------------------------------- the Jacobian */
/* dF/dz = A + B (I - S D)^-1 S C at (t, z) into w->J (the Python master's jacobian). */
static int jacobian(fme_master *m, ws *w, double t, const double *z)
{
    int n = m->nx, nu = m->nu, ny = m->ny, rc;
    double one = 1.0;
    m->jacobians++;
    if ((rc = set_point(m, w, t, z)) != FME_DONE)
        return rc;
    memset(w->A, 0, sizeof(double) * (size_t)n * (size_t)n);
    memset(w->B, 0, sizeof(double) * (size_t)(n * nu + 1));
    memset(w->Cm, 0, sizeof(double) * (size_t)(ny * n + 1));
    memset(w->D, 0, sizeof(double) * (size_t)(ny * nu + 1));
    for (int k = 0; k < m->n_units; k++) {
        fme_unit *u = &m->units[k];
        int nun = u->nx + u->n_out, nkn = u->nx + u->n_in;
        unsigned int *unk = (unsigned int *)(void *)w->unk, *kn = (unsigned int *)(void *)w->kn;
        if (!nun || !nkn) continue;
        for (int i = 0; i < u->nx; i++) { unk[i] = u->der_vr[i]; kn[i] = u->state_vr[i]; }
        for (int i = 0; i < u->n_out; i++) unk[u->nx + i] = u->out_vr[i];
        for (int i = 0; i < u->n_in; i++) kn[u->nx + i] = u->in_vr[i];
        for (int j = 0; j < nkn; j++) {
            CHECK(k, FME_CALL_DD, u->dd(u->c, unk, (size_t)nun, kn + j, 1, &one, w->sens));
            for (int i = 0; i < nun; i++) {
                double v = w->sens[i];
                int row_x = i < u->nx, col_x = j < u->nx;
                int r = row_x ? w->sx[k] + i : w->sy[k] + i - u->nx;
                int c = col_x ? w->sx[k] + j : w->su[k] + j - u->nx;
                if (row_x && col_x) w->A[r * n + c] = v;
                else if (row_x) w->B[r * nu + c] = v;
                else if (col_x) w->Cm[r * n + c] = v;
                else w->D[r * nu + c] = v;
            }
        }
    }
    memcpy(w->J, w->A, sizeof(double) * (size_t)n * (size_t)n);
    if (nu == 0)
        return FME_DONE;
    /* M = I - S D, R = S C (row i of S D is row src_pos[i] of D); R <- M^-1 R */
    for (int i = 0; i < nu; i++) {
        int s = m->src_pos[i];
        for (int j = 0; j < nu; j++)
            w->M[i * nu + j] = (i == j ? 1.0 : 0.0) - w->D[s * nu + j];
    }
    lu_real(w->M, w->piv_m, nu);
    for (int c = 0; c < n; c++) {
        /* column c of S C, stored contiguously at R + c nu, solved in place */
        double *col = w->R + (size_t)c * (size_t)nu;
        for (int i = 0; i < nu; i++)
            col[i] = w->Cm[m->src_pos[i] * n + c];
        solve_real(w->M, w->piv_m, nu, col);
    }
    for (int r = 0; r < n; r++)
        for (int c = 0; c < n; c++) {
            double s = 0.0;
            for (int i = 0; i < nu; i++)
                s += w->B[r * nu + i] * w->R[(size_t)c * (size_t)nu + i];
            w->J[r * n + c] += s;
        }
    return FME_DONE;
}

/* ---------------------------------------------------------------- the integrator */
/* The dense output of the last step at t into out. */
static void dense_at(const fme_master *m, const ws *w, double t, double *out)
{
    int n = m->nx;
    double h = m->t - m->t_old, x = (t - m->t_old) / h;
    double p0 = x, p1 = p0 * x, p2 = p1 * x;
    for (int i = 0; i < n; i++)
        out[i] = w->Q[i * 3] * p0 + w->Q[i * 3 + 1] * p1 + w->Q[i * 3 + 2] * p2 + w->y_old[i];
}

/* select_initial_step (order 3) from (t, y) with f = F(t, y). */
static int initial_step(fme_master *m, ws *w, double t, double *h_out)
{
    int n = m->nx, rc;
    double interval = fabs(m->t_bound - t), d0, d1, d2, h0, h1;
    if (interval == 0.0) { *h_out = 0.0; return FME_DONE; }
    for (int i = 0; i < n; i++) w->scale[i] = m->atol[i] + fabs(w->y[i]) * m->rtol;
    d0 = rms(w->y, w->scale, n);
    d1 = rms(w->f, w->scale, n);
    h0 = (d0 < 1e-5 || d1 < 1e-5) ? 1e-6 : 0.01 * d0 / d1;
    if (h0 > interval) h0 = interval;
    for (int i = 0; i < n; i++) w->y_new[i] = w->y[i] + h0 * w->f[i];
    if ((rc = rhs(m, w, t + h0, w->y_new, w->f_new)) != FME_DONE) return rc;
    for (int i = 0; i < n; i++) w->tmp[i] = w->f_new[i] - w->f[i];
    d2 = rms(w->tmp, w->scale, n) / h0;
    if (d1 <= 1e-15 && d2 <= 1e-15)
        h1 = fmax(1e-6, h0 * 1e-3);
    else
        h1 = pow(0.01 / fmax(d1, d2), 1.0 / 4.0);
    *h_out = fmin(fmin(100 * h0, h1), fmin(interval, m->max_step));
    return FME_DONE;
}

/* A new integrator at (t, z): Radau.__init__. */
static int init_solver(fme_master *m, ws *w, double t, const double *z)
{
    int rc;
    m->t = t;
    memcpy(w->y, z, sizeof(double) * (size_t)m->nx);
    if ((rc = rhs(m, w, t, w->y, w->f)) != FME_DONE) return rc;
    if ((rc = initial_step(m, w, t, &m->h_abs)) != FME_DONE) return rc;
    m->has_h_old = m->has_err_old = 0;
    m->newton_tol = fmax(10 * EPS / m->rtol, fmin(0.03, sqrt(m->rtol)));
    m->has_sol = 0;
    m->lu_valid = 0;
    m->current_jac = 1;
    return jacobian(m, w, t, w->y);
}

static void factor_lu(fme_master *m, ws *w, double h)
{
    int n = m->nx;
    double mr = MU_REAL / h, mcr = MU_COMPLEX_RE / h, mci = MU_COMPLEX_IM / h;
    for (int i = 0; i < n; i++)
        for (int j = 0; j < n; j++) {
            w->LUr[i * n + j] = (i == j ? mr : 0.0) - w->J[i * n + j];
            w->LUc_re[i * n + j] = (i == j ? mcr : 0.0) - w->J[i * n + j];
            w->LUc_im[i * n + j] = i == j ? mci : 0.0;
        }
    lu_real(w->LUr, w->piv_r, n);
    lu_complex(w->LUc_re, w->LUc_im, w->inv_re, w->inv_im, w->piv_c, n);
    lu_pattern(w->LUr, NULL, n, w->pat_r);
    lu_pattern(w->LUc_re, w->LUc_im, n, w->pat_c);
    m->lu_valid = 1;
}

/* solve_collocation_system: Z (3 x n) from the guess Z0; *converged, *n_iter, *rate. */
static int collocation(fme_master *m, ws *w, double t, double h, int *converged, int *n_iter,
                       double *rate)
{
    int n = m->nx, rc, k;
    double mr = MU_REAL / h, mcr = MU_COMPLEX_RE / h, mci = MU_COMPLEX_IM / h, dw_old = -1.0;
    *converged = 0;
    *rate = -1.0;                         /* None */
    for (int i = 0; i < n; i++)
        for (int r = 0; r < 3; r++)
            w->W[r * n + i] = TI_[r][0] * w->Z0[i] + TI_[r][1] * w->Z0[n + i]
                              + TI_[r][2] * w->Z0[2 * n + i];
    memcpy(w->Z, w->Z0, sizeof(double) * 3 * (size_t)n);
    for (k = 0; k < NEWTON_MAXITER; k++) {
        int finite = 1;
        double dw_norm;
        for (int r = 0; r < 3; r++) {
            for (int i = 0; i < n; i++) w->tmp[i] = w->y[i] + w->Z[r * n + i];
            if ((rc = rhs(m, w, t + h * C_[r], w->tmp, w->F + r * n)) != FME_DONE) return rc;
        }
        for (int i = 0; i < 3 * n; i++) if (!isfinite(w->F[i])) finite = 0;
        if (!finite) break;
        for (int i = 0; i < n; i++) {
            double f0 = w->F[i], f1 = w->F[n + i], f2 = w->F[2 * n + i];
            w->err[i] = f0 * TI_[0][0] + f1 * TI_[0][1] + f2 * TI_[0][2] - mr * w->W[i];
            double wr = w->W[n + i], wi = w->W[2 * n + i];
            w->fc_re[i] = f0 * TI_[1][0] + f1 * TI_[1][1] + f2 * TI_[1][2]
                          - (mcr * wr - mci * wi);
            w->fc_im[i] = f0 * TI_[2][0] + f1 * TI_[2][1] + f2 * TI_[2][2]
                          - (mcr * wi + mci * wr);
        }
        solve_real_sparse(w->LUr, w->piv_r, w->pat_r, n, w->err);
        solve_complex_sparse(w->LUc_re, w->LUc_im, w->inv_re, w->inv_im, w->piv_c, w->pat_c,
                             n, w->fc_re, w->fc_im);
        for (int i = 0; i < n; i++) {
            w->dW[i] = w->err[i];
            w->dW[n + i] = w->fc_re[i];
            w->dW[2 * n + i] = w->fc_im[i];
        }
        {
            double sum = 0.0;
            for (int r = 0; r < 3; r++)
                for (int i = 0; i < n; i++) {
                    double v = w->dW[r * n + i] / w->scale[i];
                    sum += v * v;
                }
            dw_norm = sqrt(sum / (3 * n));
        }
        if (dw_old >= 0.0)
            *rate = dw_norm / dw_old;
        if (*rate >= 0.0 && (*rate >= 1.0 ||
                pow(*rate, NEWTON_MAXITER - k) / (1.0 - *rate) * dw_norm > m->newton_tol))
            break;
        for (int i = 0; i < 3 * n; i++) w->W[i] += w->dW[i];
        for (int r = 0; r < 3; r++)
            for (int i = 0; i < n; i++)
                w->Z[r * n + i] = T_[r][0] * w->W[i] + T_[r][1] * w->W[n + i]
                                  + T_[r][2] * w->W[2 * n + i];
        if (dw_norm == 0.0 || (*rate >= 0.0 && *rate / (1.0 - *rate) * dw_norm < m->newton_tol)) {
            *converged = 1;
            break;
        }
        dw_old = dw_norm;
    }
    *n_iter = (k < NEWTON_MAXITER ? k : NEWTON_MAXITER - 1) + 1;
    return FME_DONE;
}

static double predict_factor(double h_abs, int has_old, double h_abs_old, double error_norm,
                             int has_err_old, double error_norm_old)
{
    double multiplier;
    if (!has_err_old || !has_old || error_norm == 0.0)
        multiplier = 1.0;
    else
        multiplier = h_abs / h_abs_old * pow(error_norm_old / error_norm, 0.25);
    return fmin(1.0, multiplier) * pow(error_norm, -0.25);
}

/* One accepted step (Radau._step_impl and OdeSolver.step's bookkeeping). */
static int step(fme_master *m, ws *w)
{
    int n = m->nx, rc, rejected = 0, accepted = 0, n_iter = 0, has_old, has_err_old;
    int current_jac = m->current_jac, converged;
    double t = m->t, min_step = 10 * fabs(nextafter(t, INFINITY) - t);
    double h_abs, h_abs_old, error_norm_old, h, t_new, error_norm = 0.0, safety = 1.0;
    double rate = -1.0, factor;
    if (m->h_abs > m->max_step) {
        h_abs = m->max_step; has_old = has_err_old = 0; h_abs_old = error_norm_old = 0.0;
    } else if (m->h_abs < min_step) {
        h_abs = min_step; has_old = has_err_old = 0; h_abs_old = error_norm_old = 0.0;
    } else {
        h_abs = m->h_abs; has_old = m->has_h_old; has_err_old = m->has_err_old;
        h_abs_old = m->h_abs_old; error_norm_old = m->error_norm_old;
    }
    t_new = t;
    while (!accepted) {
        if (h_abs < min_step)
            return FME_TOO_SMALL;
        h = h_abs;
        t_new = t + h;
        if (t_new - m->t_bound > 0) t_new = m->t_bound;
        h = t_new - t;
        h_abs = fabs(h);
        if (!m->has_sol) {
            memset(w->Z0, 0, sizeof(double) * 3 * (size_t)n);
        } else {
            for (int r = 0; r < 3; r++) {
                dense_at(m, w, t + h * C_[r], w->dense);
                for (int i = 0; i < n; i++) w->Z0[r * n + i] = w->dense[i] - w->y[i];
            }
        }
        for (int i = 0; i < n; i++) w->scale[i] = m->atol[i] + fabs(w->y[i]) * m->rtol;
        converged = 0;
        while (!converged) {
            if (!m->lu_valid) factor_lu(m, w, h);
            if ((rc = collocation(m, w, t, h, &converged, &n_iter, &rate)) != FME_DONE)
                return rc;
            if (!converged) {
                if (current_jac) break;
                if ((rc = jacobian(m, w, t, w->y)) != FME_DONE) return rc;
                current_jac = 1;
                m->lu_valid = 0;
            }
        }
        if (!converged) {
            h_abs *= 0.5;
            m->lu_valid = 0;
            continue;
        }
        for (int i = 0; i < n; i++) {
            w->y_new[i] = w->y[i] + w->Z[2 * n + i];
            w->ze[i] = (w->Z[i] * E_[0] + w->Z[n + i] * E_[1] + w->Z[2 * n + i] * E_[2]) / h;
            w->err[i] = w->f[i] + w->ze[i];
        }
        solve_real_sparse(w->LUr, w->piv_r, w->pat_r, n, w->err);
        for (int i = 0; i < n; i++)
            w->scale[i] = m->atol[i] + fmax(fabs(w->y[i]), fabs(w->y_new[i])) * m->rtol;
        error_norm = rms(w->err, w->scale, n);
        safety = 0.9 * (2 * NEWTON_MAXITER + 1) / (2 * NEWTON_MAXITER + n_iter);
        if (rejected && error_norm > 1) {
            for (int i = 0; i < n; i++) w->tmp[i] = w->y[i] + w->err[i];
            if ((rc = rhs(m, w, t, w->tmp, w->f_new)) != FME_DONE) return rc;
            for (int i = 0; i < n; i++) w->err[i] = w->f_new[i] + w->ze[i];
            solve_real_sparse(w->LUr, w->piv_r, w->pat_r, n, w->err);
            error_norm = rms(w->err, w->scale, n);
        }
        if (error_norm > 1) {
            factor = predict_factor(h_abs, has_old, h_abs_old, error_norm, has_err_old,
                                    error_norm_old);
            h_abs *= fmax(MIN_FACTOR, safety * factor);
            m->lu_valid = 0;
            rejected = 1;
        } else {
            accepted = 1;
        }
    }
    {
        int recompute_jac = n_iter > 2 && rate > 1e-3;
        factor = predict_factor(h_abs, has_old, h_abs_old, error_norm, has_err_old,
                                error_norm_old);
        factor = fmin(MAX_FACTOR, safety * factor);
        if (!recompute_jac && factor < 1.2)
            factor = 1;
        else
            m->lu_valid = 0;
        if ((rc = rhs(m, w, t_new, w->y_new, w->f_new)) != FME_DONE) return rc;
        if (recompute_jac) {
            if ((rc = jacobian(m, w, t_new, w->y_new)) != FME_DONE) return rc;
            current_jac = 1;
        } else {
            current_jac = 0;
        }
        m->h_abs_old = m->h_abs;
        m->has_h_old = 1;
        m->error_norm_old = error_norm;
        m->has_err_old = 1;
        m->h_abs = h_abs * factor;
        memcpy(w->y_old, w->y, sizeof(double) * (size_t)n);
        memcpy(w->y, w->y_new, sizeof(double) * (size_t)n);
        memcpy(w->f, w->f_new, sizeof(double) * (size_t)n);
        m->current_jac = current_jac;
        m->t_old = t;
        m->t = t_new;
        /* Q = Z^T P (n x 3) */
        for (int i = 0; i < n; i++)
            for (int c = 0; c < 3; c++)
                w->Q[i * 3 + c] = w->Z[i] * P_[0][c] + w->Z[n + i] * P_[1][c]
                                  + w->Z[2 * n + i] * P_[2][c];
        m->has_sol = 1;
    }
    return FME_DONE;
}

/* ---------------------------------------------------------------- events and outputs */
/* Indicator i at s on the dense output. */
static int g_at(fme_master *m, ws *w, int i, double s, double *g)
{
    int rc;
    dense_at(m, w, s, w->dense);
    if ((rc = indicators(m, w, s, w->dense, w->zbuf)) != FME_DONE) return rc;
    *g = w->zbuf[i];
    return FME_DONE;
}

/* scipy's brentq (scipy/optimize/Zeros/brentq.c) on indicator i over [xa, xb]. */
static int brentq(fme_master *m, ws *w, int i, double xa, double xb, double xtol, double rtol,
                  double *root)
{
    double xpre = xa, xcur = xb, xblk = 0.0, fpre, fcur, fblk = 0.0, spre = 0.0, scur = 0.0;
    double sbis, delta, stry, dpre, dblk;
    int rc;
    if ((rc = g_at(m, w, i, xpre, &fpre)) != FME_DONE) return rc;
    if ((rc = g_at(m, w, i, xcur, &fcur)) != FME_DONE) return rc;
    *root = xcur;
    if (fpre == 0) { *root = xpre; return FME_DONE; }
    if (fcur == 0) return FME_DONE;
    for (int it = 0; it < 100; it++) {
        if (fpre != 0 && fcur != 0 && (signbit(fpre) != signbit(fcur))) {
            xblk = xpre; fblk = fpre; spre = scur = xcur - xpre;
        }
        if (fabs(fblk) < fabs(fcur)) {
            xpre = xcur; xcur = xblk; xblk = xpre;
            fpre = fcur; fcur = fblk; fblk = fpre;
        }
        delta = (xtol + rtol * fabs(xcur)) / 2;
        sbis = (xblk - xcur) / 2;
        if (fcur == 0 || fabs(sbis) < delta) break;
        if (fabs(spre) > delta && fabs(fcur) < fabs(fpre)) {
            if (xpre == xblk) {
                stry = -fcur * (xcur - xpre) / (fcur - fpre);
            } else {
                dpre = (fpre - fcur) / (xpre - xcur);
                dblk = (fblk - fcur) / (xblk - xcur);
                stry = -fcur * (fblk * dblk - fpre * dpre) / (dblk * dpre * (fblk - fpre));
            }
            if (2 * fabs(stry) < fmin(fabs(spre), 3 * fabs(sbis) - delta)) {
                spre = scur; scur = stry;
            } else {
                spre = sbis; scur = sbis;
            }
        } else {
            spre = sbis; scur = sbis;
        }
        xpre = xcur; fpre = fcur;
        if (fabs(scur) > delta) xcur += scur;
        else xcur += (sbis > 0 ? delta : -delta);
        if ((rc = g_at(m, w, i, xcur, &fcur)) != FME_DONE) return rc;
    }
    *root = xcur;
    return FME_DONE;
}

/* Row m->rows: time t, the recorded variables at (t, z) (_store). */
static int store(fme_master *m, ws *w, double t, const double *z)
{
    int rc;
    double *row = m->out + (size_t)m->rows * (size_t)(1 + m->n_cols);
    if ((rc = set_point(m, w, t, z)) != FME_DONE) return rc;
    for (int k = 0; k < m->n_units; k++) {
        fme_unit *u = &m->units[k];
        if (u->n_rec)
            CHECK(k, FME_CALL_GET_REAL, u->get_real(u->c, u->rec_vr, (size_t)u->n_rec,
                                                    u->rec_val));
    }
    row[0] = t;
    for (int c = 0; c < m->n_cols; c++)
        row[1 + c] = m->units[m->col_unit[c]].rec_val[m->col_index[c]];
    m->rows++;
    return FME_DONE;
}

static int bad(const fme_master *m)
{
    return m->n_units <= 0 || m->nx <= 0 || !m->units || !m->order || !m->work || !m->iwork ||
           !m->atol || !m->out || m->rtol <= 0 || !(m->interval > 0);
}

FME_API int fme_start(fme_master *m, double t, const double *z)
{
    ws w;
    int rc;
    if (bad(m)) return FME_BADARG;
    m->pt_valid = 0;                      /* the caller may have called the FMUs */
    m->laid_out = 0;
    get_ws(m, &w);
    m->y = w.y;
    m->z_event = w.z_event;
    m->min_step_used = INFINITY;
    m->max_step_used = 0.0;
    if ((rc = indicators(m, &w, t, z, w.zind)) != FME_DONE) return rc;
    return init_solver(m, &w, t, z);
}

FME_API int fme_restart(fme_master *m, double t, const double *z)
{
    ws w;
    int rc;
    if (bad(m) || !m->laid_out) return FME_BADARG;
    m->pt_valid = 0;                      /* the caller may have called the FMUs */
    get_ws(m, &w);
    if ((rc = init_solver(m, &w, t, z)) != FME_DONE) return rc;
    return indicators(m, &w, t, z, w.zind);
}

FME_API int fme_run(fme_master *m, long long max_steps)
{
    ws w;
    int rc;
    if (bad(m) || !m->laid_out) return FME_BADARG;
    m->pt_valid = 0;                      /* the caller may have called the FMUs */
    get_ws(m, &w);
    for (long long s = 0; m->rows <= m->n_out; s++) {
        double t, t_old, t_end, t_event = 0.0;
        int event = 0;
        if (s >= max_steps) return FME_CHUNK;
        if (m->t == m->t_bound)
            return FME_FINISHED;
        if ((rc = step(m, &w)) != FME_DONE) return rc;
        m->steps++;
        t = m->t;
        t_old = m->t_old;
        m->min_step_used = fmin(m->min_step_used, t - t_old);
        m->max_step_used = fmax(m->max_step_used, t - t_old);
        if ((rc = indicators(m, &w, t, w.y, w.znew)) != FME_DONE) return rc;
        for (int i = 0; i < m->nz; i++) {
            if ((w.zind[i] > 0) != (w.znew[i] > 0)) {
                double root;
                if ((rc = brentq(m, &w, i, t_old, t, 1e-14 * fmax(1.0, fabs(t)), 4 * EPS,
                                 &root)) != FME_DONE)
                    return rc;
                if (!event || root < t_event) t_event = root;
                event = 1;
            }
        }
        if (event && t_event > t) t_event = t;
        t_end = event ? t_event : t;
        while (m->rows <= m->n_out &&
               m->t0 + m->rows * m->interval <= t_end + 1e-12 * m->interval) {
            double ti = m->t0 + m->rows * m->interval;
            dense_at(m, &w, fmin(ti, t), w.dense);
            if ((rc = store(m, &w, ti, w.dense)) != FME_DONE) return rc;
        }
        if (event) {
            m->t_event = t_event;
            dense_at(m, &w, t_event, w.z_event);
            return FME_EVENT;
        }
        if ((rc = set_point(m, &w, t, w.y)) != FME_DONE) return rc;
        {
            int step_event = -1;
            for (int k = 0; k < m->n_units; k++) {
                fme_unit *u = &m->units[k];
                int enter = 0, terminate = 0;
                CHECK(k, FME_CALL_COMPLETED, u->completed(u->c, 1, &enter, &terminate));
                if (terminate) {
                    m->fail_unit = k;
                    m->fail_time = t;
                    return FME_TERMINATE;
                }
                if (enter && step_event < 0) step_event = k;
            }
            memcpy(w.zind, w.znew, sizeof(double) * (size_t)m->nz);
            if (step_event >= 0) {
                m->fail_unit = step_event;
                m->fail_time = t;
                return FME_STEP_EVENT;
            }
        }
        if (m->t == m->t_bound && m->rows <= m->n_out)
            return FME_FINISHED;
    }
    return FME_DONE;
}
