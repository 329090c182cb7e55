/*
 * fm_master.c - the compiled fixed-step loop of the co-simulation master (see fm_master.h).
 *
 * A port of orchestration/cosim/master.py (Master.run with a fixed step, _step, _startup_step,
 * _macro_step, _outputs_after_step, _combination, _store); the names of the Python functions
 * are given where their code is mirrored. Compiled with -ffp-contract=off: no fused
 * multiply-add, every operation rounded as numpy rounds it.
 */
#include "fm_master.h"

#include <math.h>
#include <string.h>

#ifndef FP_SOURCE_DIGEST
#define FP_SOURCE_DIGEST "unknown"
#endif

FM_API int fm_abi(void) { return FM_ABI; }

FM_API const char *fm_source_digest(void) { return FP_SOURCE_DIGEST; }

FM_API size_t fm_sizeof_slave(void) { return sizeof(fm_slave); }

FM_API size_t fm_sizeof_master(void) { return sizeof(fm_master); }

/* Kinds of weight rows (the third index of m->weights). */
#define K_AVERAGE 0
#define K_VALUE 1
#define K_D1 2
#define K_D2 3

static double t_of(const fm_master *m, long long j)
{
    return m->t0 + (double)j * m->h;          /* master.py: t0 + k * self.h */
}

static const double *weight_row(const fm_master *m, int newest_offset, int nodes, int kind)
{
    return m->weights + (((newest_offset + 1) * 3 + (nodes - 1)) * 4 + kind) * 3;
}

static int fail(fm_master *m, int slave, int call, int status, int timed, double t)
{
    m->fail_slave = slave;
    m->fail_call = call;
    m->fail_status = status;
    m->fail_timed = timed;
    m->fail_time = t;
    return FM_FAILED;
}

/* ---------------------------------------------------------------------- history */
/* Values per sample: the outputs, then their derivatives (fm_slave). */
static int width(const fm_slave *s) { return s->n_out * (1 + s->n_oder); }

static int visible(const fm_slave *s) { return s->count < FM_DEPTH ? s->count : FM_DEPTH; }

/* _History.push, as the run loop does it (the oldest sample leaves beyond FM_DEPTH). */
static void push(fm_slave *s, long long j, const double *u)
{
    int n = width(s);
    if (s->count >= FM_DEPTH) {
        memmove(s->hist, s->hist + (s->count - FM_DEPTH + 1) * n,
                (size_t)((FM_DEPTH - 1) * n) * sizeof(double));
        s->count = FM_DEPTH - 1;
    }
    if (n) memcpy(s->hist + s->count * n, u, (size_t)n * sizeof(double));
    s->count++;
    s->newest = j;
}

/* _macro_step's provisional push (Gauss-Seidel): into the spare slot, undone by unpush(). */
static void push_provisional(fm_slave *s, const double *u)
{
    int n = width(s);
    if (n) memcpy(s->hist + s->count * n, u, (size_t)n * sizeof(double));
    s->count++;
    s->newest++;
}

static void unpush(fm_slave *s)
{
    s->count--;
    s->newest--;
}

/* ---------------------------------------------------------------------- extrapolation */
/* _combination, one output: row `w` of weights on the newest `nodes` samples of source `s`,
 * summed left to right (k == 1: one product, as numpy's W * u). */
static double combine(const fm_slave *s, const double *w, int nodes, int idx)
{
    int n = width(s);
    const double *u = s->hist + (s->count - nodes) * n + idx;
    double acc;
    int i;
    if (nodes == 1) return w[0] * u[0];
    acc = w[0] * u[0];
    for (i = 1; i < nodes; i++) acc = acc + w[i] * u[i * n];
    return acc;
}

/* taylor_rows, one row: the weights on [y, y', ..., y''''] of the Taylor polynomial at a sample
 * evaluated from `delta` seconds after it: its average over [delta, delta + scale] (K_AVERAGE)
 * or its value or derivative there (K_VALUE, K_D1, K_D2), with Python's float ** int (libm's
 * pow; the exponents are volatile so that pow(x, 2) stays pow) and its factorials. The first
 * q + 1 weights are those of order q. */
static void taylor_row(double delta, double scale, int kind, double w[5])
{
    static const double fact[6] = {1.0, 1.0, 2.0, 6.0, 24.0, 120.0};
    int j;
    for (j = 0; j <= 4; j++) {
        volatile double e1 = (double)(j + 1), e0;
        if (kind == K_AVERAGE) {
            w[j] = (pow(delta + scale, e1) - pow(delta, e1)) / (fact[j + 1] * scale);
        } else if (j >= kind - K_VALUE) {
            e0 = (double)(j - (kind - K_VALUE));
            w[j] = pow(delta, e0) / fact[j - (kind - K_VALUE)];
        } else {
            w[j] = 0.0;
        }
    }
}

/* _combination of a source with output derivatives: row `w` on its newest sample's output
 * `idx` and its derivatives, summed left to right. */
static double combine_taylor(const fm_slave *s, const double *w, int idx)
{
    const double *y = s->hist + (s->count - 1) * width(s) + idx;
    double acc = w[0] * y[0];
    int j;
    for (j = 1; j <= s->n_oder; j++) acc = acc + w[j] * y[j * s->n_out];
    return acc;
}

/* _hermite_inputs: the held inputs of slave `d` over the step from index `kt`: per source, the
 * rows of hermite_rows on its newest sample (at kt: the Taylor polynomial) or on its samples at
 * kt and kt + 1 (it stepped first in this step), summed left to right. */
static int fill_hermite(const fm_master *m, fm_slave *d, long long kt)
{
    int i, r, rows = d->n_der ? d->n_der + 1 : 1;
    for (i = 0; i < d->n_in; i++) {
        const fm_slave *s = &m->slaves[d->in_src[i]];
        const int q = s->n_oder, n = width(s), e = (int)(s->newest - kt), o = s->n_out;
        const double *y, *w[3] = {NULL, NULL, NULL};
        double a0, a1 = 0.0, a2 = 0.0;
        int j;
        if (q < 1 || q > 4 || e < 0 || e > 1 || s->count < 1 + e) return 0;
        y = s->hist + (s->count - 1 - e) * n + d->in_idx[i];
        for (r = 0; r < rows; r++)
            w[r] = m->hweights + (((q - 1) * 2 + e) * 4 + (d->n_der ? K_VALUE + r : K_AVERAGE))
                   * 10;
        /* each row's sum left to right, the rows side by side in registers (independent
         * chains: the same operations as one row after the other) */
        if (rows == 3) {
            const double *w0 = w[0], *w1 = w[1], *w2 = w[2];
            a0 = w0[0] * y[0];
            a1 = w1[0] * y[0];
            a2 = w2[0] * y[0];
            for (j = 1; j <= q; j++) {
                const double yj = y[j * o];
                a0 = a0 + w0[j] * yj;
                a1 = a1 + w1[j] * yj;
                a2 = a2 + w2[j] * yj;
            }
            if (e)
                for (j = 0; j <= q; j++) {
                    const double yj = y[n + j * o];
                    a0 = a0 + w0[q + 1 + j] * yj;
                    a1 = a1 + w1[q + 1 + j] * yj;
                    a2 = a2 + w2[q + 1 + j] * yj;
                }
            d->in_val[i] = a0;
            d->der_val[i] = a1;
            d->der_val[d->n_in + i] = a2;
            continue;
        }
        for (r = 0; r < rows; r++) {
            const double *wr = w[r];
            double acc = wr[0] * y[0];
            for (j = 1; j <= q; j++) acc = acc + wr[j] * y[j * o];
            if (e)
                for (j = 0; j <= q; j++) acc = acc + wr[q + 1 + j] * y[n + j * o];
            if (r == 0) d->in_val[i] = acc;
            else d->der_val[(r - 1) * d->n_in + i] = acc;
        }
    }
    return 1;
}

/* _fill: the inputs of slave `d` from its sources' polynomials about step index `kt`: the held
 * values (`held`: the step averages, or the values and the derivatives at kt when the slave
 * takes input derivatives), or the values at kt alone. The nodes are the step indices' offsets
 * from kt, integers however long the run. */
static int fill(const fm_master *m, fm_slave *d, long long kt, int held)
{
    const fm_slave *s = NULL;
    const double *w = NULL, *wd[2] = {NULL, NULL};
    int i, r, src = -1, nodes = 0;
    int rows = held && d->n_der ? d->n_der : 0;
    for (i = 0; i < d->n_in; i++) {
        int idx = d->in_idx[i];
        if (d->in_src[i] != src) {   /* a source's rows, once for a run of its inputs */
            int vis, e;
            src = d->in_src[i];
            s = &m->slaves[src];
            vis = visible(s);
            nodes = m->p + 1 < vis ? m->p + 1 : vis;
            e = (int)(s->newest - kt);
            if (e < -1 || e > 1 || nodes < 1) return 0;
            if (s->n_oder) {         /* the Taylor polynomial at the newest sample */
                w = m->taylor[e + 1][held && !d->n_der ? K_AVERAGE : K_VALUE];
                for (r = 0; r < rows; r++) wd[r] = m->taylor[e + 1][K_D1 + r];
            } else {
                w = weight_row(m, e, nodes, held && !d->n_der ? K_AVERAGE : K_VALUE);
                for (r = 0; r < rows; r++) wd[r] = m->dweights[nodes - 1][e + 1][r];
            }
        }
        if (s->n_oder) {
            d->in_val[i] = combine_taylor(s, w, idx);
            for (r = 0; r < rows; r++)
                d->der_val[r * d->n_in + i] = combine_taylor(s, wd[r], idx);
        } else {
            d->in_val[i] = combine(s, w, nodes, idx);
            for (r = 0; r < rows; r++)
                d->der_val[r * d->n_in + i] = combine(s, wd[r], nodes, idx);
        }
    }
    return 1;
}

/* ---------------------------------------------------------------------- one step */
/* Slave.set_inputs: slave n's in_val, then its der_val (when it takes input derivatives), at t. */
static int send_inputs(fm_master *m, int n, double t)
{
    fm_slave *d = &m->slaves[n];
    int st;
    if (d->n_in) {
        st = d->set_real(d->c, d->in_vr, (size_t)d->n_in, d->in_val);
        if (st > 1) return fail(m, n, FM_CALL_SET_REAL, st, 1, t);
    }
    if (d->n_der && d->n_in) {
        st = d->set_der(d->c, d->der_vr, (size_t)(d->n_in * d->n_der), d->der_order,
                        d->der_val);
        if (st > 1) return fail(m, n, FM_CALL_SET_DER, st, 1, t);
    }
    return FM_DONE;
}

/* Slave.set_inputs with the held inputs (values, then derivatives), at ta. */
static int set_held(fm_master *m, int n, long long k, double ta)
{
    fm_slave *d = &m->slaves[n];
    if (!(m->hermite ? fill_hermite(m, d, k) : fill(m, d, k, 1))) return FM_BADARG;
    return send_inputs(m, n, ta);
}

static int do_step(fm_master *m, int n, double ta)
{
    fm_slave *d = &m->slaves[n];
    int st = d->do_step(d->c, ta, m->h, 1);
    if (st > 1) return fail(m, n, FM_CALL_DO_STEP, st, 1, ta);
    return FM_DONE;
}

/* _outputs_after_step: a feedthrough slave first gets its inputs' values at tb; with hermite, a
 * slave whose sources have all stepped gets their values and derivatives at tb
 * (_sample_inputs). */
static int outputs_after_step(fm_master *m, int n, long long k, double tb)
{
    fm_slave *d = &m->slaves[n];
    int st, i, r, all = m->hermite && d->n_in > 0;
    for (i = 0; i < d->n_in && all; i++) all = m->slaves[d->in_src[i]].newest == k + 1;
    if (all) {
        for (i = 0; i < d->n_in; i++) {
            const fm_slave *s = &m->slaves[d->in_src[i]];
            const double *y = s->hist + (s->count - 1) * width(s) + d->in_idx[i];
            d->in_val[i] = y[0];
            for (r = 0; r < d->n_der; r++)
                d->der_val[r * d->n_in + i] = r + 1 <= s->n_oder ? y[(r + 1) * s->n_out] : 0.0;
        }
        if ((st = send_inputs(m, n, tb)) != FM_DONE) return st;
    } else if (d->feedthrough && d->n_in) {
        if (!fill(m, d, k + 1, 0)) return FM_BADARG;
        st = d->set_real(d->c, d->in_vr, (size_t)d->n_in, d->in_val);
        if (st > 1) return fail(m, n, FM_CALL_SET_REAL, st, 1, tb);
    }
    if (d->n_out) {
        st = d->get_real(d->c, d->out_vr, (size_t)d->n_out, d->new_val);
        if (st > 1) return fail(m, n, FM_CALL_GET_REAL, st, 1, tb);
    }
    if (d->n_out && d->n_oder) {
        st = d->get_der(d->c, d->oder_vr, (size_t)(d->n_out * d->n_oder), d->oder_order,
                        d->new_val + d->n_out);
        if (st > 1) return fail(m, n, FM_CALL_GET_DER, st, 1, tb);
    }
    return FM_DONE;
}

/* _macro_step: every slave's new outputs in its new_val; the FMUs step from t0 + k h over h. */
static int macro_step(fm_master *m, long long k)
{
    double ta = t_of(m, k), tb = t_of(m, k + 1);
    int i, rc;
    if (!m->gauss_seidel) {
        for (i = 0; i < m->n_slaves; i++)
            if ((rc = set_held(m, m->order[i], k, ta)) != FM_DONE) return rc;
        for (i = 0; i < m->n_slaves; i++)
            if ((rc = do_step(m, m->order[i], ta)) != FM_DONE) return rc;
        int any = 0;
        for (i = 0; i < m->n_slaves; i++) {
            if (m->slaves[m->order[i]].sampled) {
                any = 1;
                continue;
            }
            if ((rc = outputs_after_step(m, m->order[i], k, tb)) != FM_DONE) return rc;
        }
        if (!any) return FM_DONE;
        /* a sampled controller's force at a tick is a feedthrough of the sensors there: its
         * inputs at the others' new outputs (pushed for the while, as _macro_step does) */
        for (i = 0; i < m->n_slaves; i++)
            if (!m->slaves[i].sampled) push_provisional(&m->slaves[i], m->slaves[i].new_val);
        rc = FM_DONE;
        for (i = 0; i < m->n_slaves && rc == FM_DONE; i++)
            if (m->slaves[m->order[i]].sampled) rc = outputs_after_step(m, m->order[i], k, tb);
        for (i = 0; i < m->n_slaves; i++)
            if (!m->slaves[i].sampled) unpush(&m->slaves[i]);
        return rc;
    }
    /* Gauss-Seidel: later slaves interpolate the earlier ones' outputs between ta and tb. A
     * slave whose newest sample is already at tb (the predicted one of the first step) has it
     * replaced meanwhile. */
    for (i = 0; i < m->n_slaves; i++) {
        int n = m->order[i];
        fm_slave *s = &m->slaves[n];
        if ((rc = set_held(m, n, k, ta)) != FM_DONE) return rc;
        if ((rc = do_step(m, n, ta)) != FM_DONE) return rc;
        if ((rc = outputs_after_step(m, n, k, tb)) != FM_DONE) return rc;
        if (s->count > 0 && s->newest == k + 1) {
            double *u = s->hist + (s->count - 1) * width(s);
            if (s->n_out) {
                memcpy(s->saved, u, (size_t)width(s) * sizeof(double));
                memcpy(u, s->new_val, (size_t)width(s) * sizeof(double));
            }
            s->mark = 2;                          /* replaced */
        } else {
            push_provisional(s, s->new_val);
            s->mark = 1;                          /* pushed */
        }
    }
    for (i = 0; i < m->n_slaves; i++) {
        fm_slave *s = &m->slaves[i];
        if (s->mark == 1) {
            unpush(s);
        } else if (s->mark == 2 && s->n_out) {
            memcpy(s->hist + (s->count - 1) * width(s), s->saved,
                   (size_t)width(s) * sizeof(double));
        }
        s->mark = 0;
    }
    return FM_DONE;
}

/* _startup_step: predict the first step on held inputs, restore the FMU states, take it again
 * with the inputs interpolated between t0 and the predicted outputs; free the states however it
 * ends (a failed free replaces the failure, as an exception in Python's finally does). */
static int startup_step(fm_master *m, long long k)
{
    int i, rc, got = 0;
    for (i = 0; i < m->n_slaves; i++) {
        fm_slave *s = &m->slaves[i];
        int st;
        s->state = NULL;
        st = s->get_state(s->c, &s->state);
        if (st > 1) return fail(m, i, FM_CALL_GET_STATE, st, 0, 0.0);
        got++;
    }
    rc = macro_step(m, k);
    if (rc == FM_DONE) {
        for (i = 0; i < m->n_slaves; i++) push(&m->slaves[i], k + 1, m->slaves[i].new_val);
        for (i = 0; i < m->n_slaves && rc == FM_DONE; i++) {
            fm_slave *s = &m->slaves[i];
            int st = s->set_state(s->c, s->state);
            if (st > 1) rc = fail(m, i, FM_CALL_SET_STATE, st, 0, 0.0);
        }
        if (rc == FM_DONE) rc = macro_step(m, k);
        if (rc == FM_DONE)
            for (i = 0; i < m->n_slaves; i++) unpush(&m->slaves[i]);
    }
    for (i = 0; i < got; i++) {
        fm_slave *s = &m->slaves[i];
        int st = s->free_state(s->c, &s->state);
        if (st > 1) return fail(m, i, FM_CALL_FREE_STATE, st, 0, 0.0);
    }
    return rc;
}

/* _store: row `row` at time t (recorded-only variables read now, in the slaves' order). */
static int store(fm_master *m, long long row, double t)
{
    double *out = m->out + row * (1 + m->n_cols);
    int i;
    for (i = 0; i < m->n_slaves; i++) {
        fm_slave *s = &m->slaves[i];
        if (s->n_rec) {
            int st = s->get_real(s->c, s->rec_vr, (size_t)s->n_rec, s->rec_val);
            if (st > 1) return fail(m, i, FM_CALL_GET_REAL, st, 1, t);
        }
    }
    out[0] = t;
    for (i = 0; i < m->n_cols; i++) {
        const fm_slave *s = &m->slaves[m->col_slave[i]];
        out[1 + i] = m->col_rec[i] ? s->rec_val[m->col_index[i]]
                                   : s->hist[(s->count - 1) * width(s) + m->col_index[i]];
    }
    if (row + 1 > m->rows) m->rows = row + 1;
    return FM_DONE;
}

/* The weights that depend on h alone, once per fm_run: the derivative rows divided by h ** kd
 * (numpy: w / h ** kd, Python's ** being libm's pow; the exponents are volatile so that the
 * compiler does not turn pow(x, 2) into x * x), and the Taylor rows from (kt - newest) h = -e h
 * seconds after the newest sample, over a step of h (master.py: scale * unit = 1 * h); a row's
 * first q + 1 weights are those of order q. */
static void prepare(fm_master *m)
{
    volatile double one = 1.0, two = 2.0;
    double pw[2];
    int e, nodes, r, j, kind;
    pw[0] = pow(m->h, one);
    pw[1] = pow(m->h, two);
    for (nodes = 1; nodes <= 3; nodes++)
        for (e = -1; e <= 1; e++)
            for (r = 0; r < 2; r++) {
                const double *wu = weight_row(m, e, nodes, K_D1 + r);
                for (j = 0; j < 3; j++)
                    m->dweights[nodes - 1][e + 1][r][j] = j < nodes ? wu[j] / pw[r] : 0.0;
            }
    for (e = -1; e <= 1; e++)
        for (kind = K_AVERAGE; kind <= K_D2; kind++)
            taylor_row((double)(-e) * m->h, m->h, kind, m->taylor[e + 1][kind]);
}

static int check(const fm_master *m)
{
    int i, j;
    if (!m || !m->slaves || !m->order || !m->weights || m->n_slaves < 1 || m->p < 0 ||
        (m->hermite && (!m->hweights || !m->gauss_seidel || m->correct_startup)) ||
        m->p > 2 || m->m < 1 || m->total < 0 || m->k < 0 || (m->n_cols && !m->out) ||
        !(m->h > 0.0))
        return 0;
    for (i = 0; i < m->n_slaves; i++) {
        const fm_slave *s = &m->slaves[i];
        if (m->order[i] < 0 || m->order[i] >= m->n_slaves) return 0;
        if (!s->set_real || !s->get_real || !s->do_step || s->n_in < 0 || s->n_out < 0 ||
            s->n_rec < 0 || s->n_der < 0 || s->n_der > 2 || s->n_oder < 0 ||
            s->n_oder > (m->hermite ? 4 : 2) ||
            s->count < 1 || s->count > FM_DEPTH)
            return 0;
        if (s->n_der && !s->set_der) return 0;
        if (s->n_oder && !s->get_der) return 0;
        if (m->correct_startup && (!s->get_state || !s->set_state || !s->free_state)) return 0;
        for (j = 0; j < s->n_in; j++)
            if (s->in_src[j] < 0 || s->in_src[j] >= m->n_slaves ||
                s->in_idx[j] < 0 || s->in_idx[j] >= m->slaves[s->in_src[j]].n_out)
                return 0;
    }
    for (i = 0; i < m->n_cols; i++) {
        const fm_slave *s;
        if (m->col_slave[i] < 0 || m->col_slave[i] >= m->n_slaves) return 0;
        s = &m->slaves[m->col_slave[i]];
        if (m->col_index[i] < 0 || m->col_index[i] >= (m->col_rec[i] ? s->n_rec : s->n_out))
            return 0;
    }
    return 1;
}

FM_API int fm_run(fm_master *m, long long k_end)
{
    int i, rc;
    if (!check(m)) return FM_BADARG;
    prepare(m);
    if (k_end > m->total) k_end = m->total;
    while (m->k < k_end) {
        long long k = m->k;
        double tb = t_of(m, k + 1);
        if (m->correct_startup && m->slaves[m->order[0]].count == 1)
            rc = startup_step(m, k);
        else
            rc = macro_step(m, k);
        if (rc != FM_DONE) return rc;
        for (i = 0; i < m->n_slaves; i++) push(&m->slaves[i], k + 1, m->slaves[i].new_val);
        m->k = k + 1;
        if ((k + 1) % m->m == 0 && (rc = store(m, (k + 1) / m->m, tb)) != FM_DONE) return rc;
        if (m->go_on && !m->go_on()) return FM_STOPPED;
    }
    return FM_DONE;
}
