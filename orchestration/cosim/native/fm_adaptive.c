/*
 * fm_adaptive.c - the compiled adaptive loop of the co-simulation master (see fm_adaptive.h).
 *
 * A port of orchestration/cosim/master.py (Master._run_adaptive, _step, _startup_step,
 * _macro_step, _outputs_after_step, _combination, _coupling_error, _energy_error, _store) with
 * the history stamped in seconds; the names of the Python functions are given where their code
 * is mirrored. Compiled with -ffp-contract=off: no fused multiply-add.
 */
#include "fm_adaptive.h"

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#ifndef FP_SOURCE_DIGEST
#define FP_SOURCE_DIGEST "unknown"
#endif

FA_API int fa_abi(void) { return FA_ABI; }

FA_API const char *fa_source_digest(void) { return FP_SOURCE_DIGEST; }

FA_API size_t fa_sizeof_slave(void) { return sizeof(fa_slave); }

FA_API size_t fa_sizeof_master(void) { return sizeof(fa_master); }

#define KIND_AVERAGE (-1)

/* Python's min(a, b) and max(a, b): the first argument unless the second compares smaller
 * (larger); NaN handling as Python's. */
static double py_min(double a, double b) { return b < a ? b : a; }
static double py_max(double a, double b) { return b > a ? b : a; }

/* numpy's maximum: NaN propagates. */
static double np_maximum(double a, double b)
{
    if (a != a) return a;
    if (b != b) return b;
    return a >= b ? a : b;
}

/* pow with an exponent the compiler cannot turn into a multiplication (Python's ** is libm's
 * pow). */
static double py_pow(double x, double y)
{
    volatile double e = y;
    return pow(x, e);
}

static int fail(fa_master *m, int slave, int call, int status, int timed, double t)
{
    m->fail_slave = slave;
    m->fail_call = call;
    m->fail_status = status;
    m->fail_timed = timed;
    m->fail_time = t;
    return FA_FAILED;
}

/* The history's clock (Master._time): a sample stamped `a` is at secs(a) seconds; one unit of
 * it is `unit` seconds. Seconds with an adaptive step, step counters from t0 at a fixed one. */
static double unit_of(const fa_master *m) { return m->counters ? m->h : 1.0; }

static double secs(const fa_master *m, double a)
{
    return m->counters ? m->t0 + a * m->h : a;
}

/* ---------------------------------------------------------------------- arithmetic */
FA_API double fa_round9(double x)
{
    /* the product x 1e9 exactly as y + e (1e9 is a double): the integer nearest to it (ties
     * to even), divided by 1e9 with one rounding, is the double nearest to the decimal that
     * Python's round(x, 9) formats and parses. y - r is exact below 2^52, and only there a
     * tie of y can hide the side the exact product is on. */
    double y, e, r, d;
    if (!isfinite(x) || fabs(x) >= 1e16) return x;   /* beyond 2^53 every double is whole */
    if (fabs(x) >= 4e6) {             /* beyond the exact range: format and parse, as Python */
        char buf[64];
        snprintf(buf, sizeof buf, "%.9f", x);
        return strtod(buf, NULL);
    }
    y = x * 1e9;
    e = fma(x, 1e9, -y);
    r = nearbyint(y);                 /* ties to even: the tie of y itself */
    d = y - r;
    if (d == 0.5 && e > 0.0) r += 1.0;
    else if (d == -0.5 && e < 0.0) r -= 1.0;
    return r / 1e9;
}

/* coupling.py _weights: solve V^T w = rhs with V[i][j] = tau_i^j by Gaussian elimination with
 * partial pivoting. */
FA_API int fa_weights(const double *tau, int n, int kind, double *w)
{
    double a[3][3], piv;
    int i, j, k;
    if (n < 1 || n > 3 || kind < KIND_AVERAGE || kind > 2) return 0;
    if (kind != KIND_AVERAGE && n <= kind) {          /* too few samples: that derivative is 0 */
        for (i = 0; i < n; i++) w[i] = 0.0;
        return 1;
    }
    if (n == 1) {
        w[0] = 1.0;
        return 1;
    }
    for (j = 0; j < n; j++) {
        double pw = 1.0;
        for (i = 0; i < n; i++) {          /* row i: the i-th power of every node */
            a[i][j] = i == 0 ? 1.0 : (pw = i == 1 ? tau[j] : pw * tau[j]);
        }
    }
    for (i = 0; i < n; i++)
        w[i] = kind == KIND_AVERAGE ? 1.0 / (double)(i + 1) : (i == kind ? (kind == 2 ? 2.0 : 1.0)
                                                                          : 0.0);
    for (k = 0; k < n; k++) {
        int p = k;
        for (i = k + 1; i < n; i++)
            if (fabs(a[i][k]) > fabs(a[p][k])) p = i;
        if (a[p][k] == 0.0) return 0;
        if (p != k) {
            double tmp;
            for (j = 0; j < n; j++) {
                tmp = a[k][j];
                a[k][j] = a[p][j];
                a[p][j] = tmp;
            }
            tmp = w[k];
            w[k] = w[p];
            w[p] = tmp;
        }
        for (i = k + 1; i < n; i++) {
            double f = a[i][k] / a[k][k];
            for (j = k + 1; j < n; j++) a[i][j] = a[i][j] - f * a[k][j];
            w[i] = w[i] - f * w[k];
        }
    }
    for (i = n - 1; i >= 0; i--) {
        piv = w[i];
        for (j = i + 1; j < n; j++) piv = piv - a[i][j] * w[j];
        w[i] = piv / a[i][i];
    }
    return 1;
}

/* ---------------------------------------------------------------------- history */
static int nodes_of(const fa_master *m, const fa_slave *s)
{
    return m->p + 1 < s->count ? m->p + 1 : s->count;
}

/* _History.push: the oldest sample leaves beyond FA_DEPTH. */
static void push(fa_slave *s, double t, const double *u)
{
    int n = s->n_out;
    if (n) memcpy(s->hist + s->count * n, u, (size_t)n * sizeof(double));
    s->t[s->count] = t;
    s->count++;
    if (s->count > FA_DEPTH) {
        if (n) memmove(s->hist, s->hist + n, (size_t)(FA_DEPTH * n) * sizeof(double));
        memmove(s->t, s->t + 1, FA_DEPTH * sizeof(double));
        s->count = FA_DEPTH;
    }
}

static void pop(fa_slave *s) { s->count--; }

static void snapshot(fa_slave *s)
{
    if (s->n_out) memcpy(s->snap, s->hist, (size_t)(s->count * s->n_out) * sizeof(double));
    memcpy(s->snap_t, s->t, sizeof s->t);
    s->snap_count = s->count;
}

static void restore(fa_slave *s)
{
    if (s->n_out) memcpy(s->hist, s->snap, (size_t)(s->snap_count * s->n_out) * sizeof(double));
    memcpy(s->t, s->snap_t, sizeof s->t);
    s->count = s->snap_count;
}

/* ---------------------------------------------------------------------- extrapolation */
/* _combination's nodes: the newest `nodes` samples of `s` in units of `scale` from `t`, rounded
 * to 9 decimals. */
static void nodes_about(const fa_slave *s, int nodes, double t, double scale, double *tau)
{
    int q;
    for (q = 0; q < nodes; q++) tau[q] = fa_round9((s->t[s->count - nodes + q] - t) / scale);
}

/* The weights of kind `kind` (KIND_AVERAGE, 0, 1, 2; derivatives unscaled) on the newest `nodes`
 * samples of `s` about `t` in units of `scale`: on the step counters' grid the Python master's
 * own (coupling.weight_table, the nodes integers), else solved here. */
static int weights_about(const fa_master *m, const fa_slave *s, int nodes, double t,
                         double scale, int kind, double *w)
{
    double tau[3];
    if (m->counters) {
        int e = (int)(s->t[s->count - 1] - t), q;
        const double *row;
        if (e < -1 || e > 1) return 0;
        row = m->weights + (((e + 1) * 3 + (nodes - 1)) * 4 + kind + 1) * 3;
        for (q = 0; q < nodes; q++) w[q] = row[q];
        return 1;
    }
    nodes_about(s, nodes, t, scale, tau);
    return fa_weights(tau, nodes, kind, w);
}

/* _combination, one output: weights `w` on the newest `nodes` samples, summed left to right. */
static double combine(const fa_slave *s, const double *w, int nodes, int idx)
{
    const double *u = s->hist + (s->count - nodes) * s->n_out + idx;
    double acc;
    int i;
    if (nodes == 1) return w[0] * u[0];
    acc = w[0] * u[0];
    for (i = 1; i < nodes; i++) acc = acc + w[i] * u[i * s->n_out];
    return acc;
}

/* _fill: the inputs of `d` from its sources' polynomials about `t` (seconds): held over
 * [t, t + scale] (the step averages, or the values and derivatives at t), or the values at t. */
static int fill(fa_master *m, fa_slave *d, double t, double scale, int held)
{
    double w[3][3], pw[2] = {0.0, 0.0};
    int i, r, j, last = -1, nodes = 0;
    int rows = held && d->n_der ? d->n_der : 0;
    if (rows) {                           /* the powers once per scale (a fixed step: per run) */
        const double x = scale * unit_of(m);
        if (!(x == m->pow_arg && x > 0.0)) {
            m->pow1 = py_pow(x, 1.0);
            m->pow2 = py_pow(x, 2.0);
            m->pow_arg = x;
        }
        pw[0] = m->pow1;
        if (rows > 1) pw[1] = m->pow2;
    }
    for (i = 0; i < d->n_in; i++) {
        const fa_slave *s = &m->slaves[d->in_src[i]];
        if (d->in_src[i] != last) {       /* the weights of this source (computed once) */
            last = d->in_src[i];
            nodes = nodes_of(m, s);
            if (!weights_about(m, s, nodes, t, scale, held && !d->n_der ? KIND_AVERAGE : 0,
                               w[0]))
                return 0;
            for (r = 0; r < rows; r++) {
                if (!weights_about(m, s, nodes, t, scale, r + 1, w[r + 1])) return 0;
                for (j = 0; j < nodes; j++) w[r + 1][j] = w[r + 1][j] / pw[r];
            }
        }
        d->in_val[i] = combine(s, w[0], nodes, d->in_idx[i]);
        for (r = 0; r < rows; r++)
            d->der_val[r * d->n_in + i] = combine(s, w[r + 1], nodes, d->in_idx[i]);
    }
    return 1;
}

/* The scale of _point_inputs and the predictions: master.step on the history's clock. */
static double point_scale(const fa_master *m) { return m->h / unit_of(m); }

/* The value at t1 of output `idx` of `s` predicted by its polynomial. */
static double predicted(const fa_master *m, const fa_slave *s, double t1, int idx)
{
    double w[3] = {0.0, 0.0, 0.0};
    int nodes = nodes_of(m, s);
    weights_about(m, s, nodes, t1, point_scale(m), 0, w);
    return combine(s, w, nodes, idx);
}

/* ---------------------------------------------------------------------- one step */
static int set_held(fa_master *m, int n, double t0, double t1)
{
    fa_slave *d = &m->slaves[n];
    int st;
    if (!fill(m, d, t0, t1 - t0, 1)) return FA_BADARG;
    if (d->n_in) {
        st = d->set_real(d->c, d->in_vr, (size_t)d->n_in, d->in_val);
        if (st > 1) return fail(m, n, FA_CALL_SET_REAL, st, 1, secs(m, t0));
    }
    if (d->n_der && d->n_in) {
        st = d->set_der(d->c, d->der_vr, (size_t)(d->n_in * d->n_der), d->der_order,
                        d->der_val);
        if (st > 1) return fail(m, n, FA_CALL_SET_DER, st, 1, secs(m, t0));
    }
    return FA_DONE;
}

static int do_step(fa_master *m, int n, double t0, double t1)
{
    fa_slave *d = &m->slaves[n];
    double ta = secs(m, t0);
    int st = d->do_step(d->c, ta, (t1 - t0) * unit_of(m), 1);
    if (st > 1) return fail(m, n, FA_CALL_DO_STEP, st, 1, ta);
    return FA_DONE;
}

/* _outputs_after_step: a feedthrough slave first gets its inputs' values at t1. */
static int outputs_after_step(fa_master *m, int n, double t1)
{
    fa_slave *d = &m->slaves[n];
    int st;
    if (d->feedthrough && d->n_in) {
        if (!fill(m, d, t1, point_scale(m), 0)) return FA_BADARG;
        st = d->set_real(d->c, d->in_vr, (size_t)d->n_in, d->in_val);
        if (st > 1) return fail(m, n, FA_CALL_SET_REAL, st, 1, secs(m, t1));
    }
    if (d->n_out) {
        st = d->get_real(d->c, d->out_vr, (size_t)d->n_out, d->new_val);
        if (st > 1) return fail(m, n, FA_CALL_GET_REAL, st, 1, secs(m, t1));
    }
    return FA_DONE;
}

/* _macro_step: every slave's new outputs in its new_val. Gauss-Seidel pushes each slave's new
 * sample for the later ones and pops it after, as _History.push and pop do (a full history
 * loses its oldest sample on the way, as in Python). */
static int macro_step(fa_master *m, double t0, double t1)
{
    int i, rc;
    if (!m->gauss_seidel) {
        for (i = 0; i < m->n_slaves; i++)
            if ((rc = set_held(m, m->order[i], t0, t1)) != FA_DONE) return rc;
        for (i = 0; i < m->n_slaves; i++)
            if ((rc = do_step(m, m->order[i], t0, t1)) != FA_DONE) return rc;
        for (i = 0; i < m->n_slaves; i++)
            if ((rc = outputs_after_step(m, m->order[i], t1)) != FA_DONE) return rc;
        return FA_DONE;
    }
    for (i = 0; i < m->n_slaves; i++) m->slaves[i].mark = 0;
    for (i = 0; i < m->n_slaves; i++) {
        int n = m->order[i];
        fa_slave *s = &m->slaves[n];
        if ((rc = set_held(m, n, t0, t1)) != FA_DONE) return rc;
        if ((rc = do_step(m, n, t0, t1)) != FA_DONE) return rc;
        if ((rc = outputs_after_step(m, n, t1)) != FA_DONE) return rc;
        if (s->count > 0 && s->t[s->count - 1] == t1) {     /* a predicted sample */
            double *u = s->hist + (s->count - 1) * s->n_out;
            if (s->n_out) {
                memcpy(s->saved, u, (size_t)s->n_out * sizeof(double));
                memcpy(u, s->new_val, (size_t)s->n_out * sizeof(double));
            }
            s->mark = 2;
        } else {
            push(s, t1, s->new_val);
            s->mark = 1;
        }
    }
    for (i = 0; i < m->n_slaves; i++) {
        fa_slave *s = &m->slaves[i];
        if (s->mark == 1) {
            pop(s);
        } else if (s->mark == 2 && s->n_out) {
            memcpy(s->hist + (s->count - 1) * s->n_out, s->saved,
                   (size_t)s->n_out * sizeof(double));
        }
        s->mark = 0;
    }
    return FA_DONE;
}

/* _startup_step: predict, restore the FMU states, take the step again on the inputs
 * interpolated towards the prediction; the states are freed however it ends. */
static int startup_step(fa_master *m, double t0, double t1)
{
    int i, rc, got = 0;
    for (i = 0; i < m->n_slaves; i++) {
        fa_slave *s = &m->slaves[i];
        int st;
        s->state = NULL;
        st = s->get_state(s->c, &s->state);
        if (st > 1) return fail(m, i, FA_CALL_GET_STATE, st, 0, 0.0);
        got++;
    }
    rc = macro_step(m, t0, t1);
    if (rc == FA_DONE) {
        for (i = 0; i < m->n_slaves; i++) push(&m->slaves[i], t1, m->slaves[i].new_val);
        for (i = 0; i < m->n_slaves && rc == FA_DONE; i++) {
            fa_slave *s = &m->slaves[i];
            int st = s->set_state(s->c, s->state);
            if (st > 1) rc = fail(m, i, FA_CALL_SET_STATE, st, 0, 0.0);
        }
        if (rc == FA_DONE) rc = macro_step(m, t0, t1);
        if (rc == FA_DONE)
            for (i = 0; i < m->n_slaves; i++) pop(&m->slaves[i]);
    }
    for (i = 0; i < got; i++) {
        fa_slave *s = &m->slaves[i];
        int st = s->free_state(s->c, &s->state);
        if (st > 1) return fail(m, i, FA_CALL_FREE_STATE, st, 0, 0.0);
    }
    return rc;
}

static int step(fa_master *m, double t0, double t1)
{
    if (m->correct_startup && m->slaves[m->order[0]].count == 1) return startup_step(m, t0, t1);
    return macro_step(m, t0, t1);
}

/* ---------------------------------------------------------------------- error estimates */
/* _coupling_error (the peaks updated as there). */
static double coupling_error(fa_master *m, double t1, double dt)
{
    double err = 0.0;
    int q, i;
    for (q = 0; q < m->n_sources; q++) {
        fa_slave *s = &m->slaves[m->sources[q]];
        const double *u = s->hist + (s->count - 1) * s->n_out;
        double floor = s->n_out ? s->peak[0] : 0.0, worst = 0.0;
        for (i = 1; i < s->n_out; i++) floor = np_maximum(floor, s->peak[i]);
        for (i = 0; i < s->n_out; i++) s->peak[i] = np_maximum(s->peak[i], fabs(s->new_val[i]));
        if (floor == 0.0) continue;
        for (i = 0; i < s->n_out; i++) {
            double actual = s->new_val[i];
            double pred = predicted(m, s, t1, i);
            double rate = fabs(actual - u[i]) * (m->h / dt);
            double scale = m->tol * np_maximum(np_maximum(s->peak[i], floor), rate);
            double v = fabs(pred - actual) / scale;
            worst = i == 0 ? v : np_maximum(worst, v);
        }
        if (s->n_out) err = py_max(err, worst);
    }
    return err * dt / m->h;
}

/* _energy_error (the work summed as there). */
static double energy_error(fa_master *m, double t1, double dt)
{
    const fa_slave *fs = &m->slaves[m->f_slave], *xs = &m->slaves[m->x_slave];
    double f0 = fs->hist[(fs->count - 1) * fs->n_out + m->f_idx], f1 = fs->new_val[m->f_idx];
    double x0 = xs->hist[(xs->count - 1) * xs->n_out + m->x_idx], x1 = xs->new_val[m->x_idx];
    double x_pred = predicted(m, xs, t1, m->x_idx);
    double f_mean = 0.5 * (f0 + f1);
    double residual = fabs(f_mean * (x_pred - x1)), work, scale;
    if (m->f_pred) {
        double f_pred = predicted(m, fs, t1, m->f_idx);
        residual += 0.5 * fabs((f_pred - f1) * (x1 - x0));
    }
    work = fabs(f_mean * (x1 - x0));
    m->work += work;
    scale = m->tol * py_max(py_max(m->work, work * m->h / dt), 1e-300);
    return residual / scale;
}

/* ---------------------------------------------------------------------- the run */
/* _store: row `row` at time t. */
static int store(fa_master *m, long long row, double t)
{
    double *out = m->out + row * (1 + m->n_cols);
    int i;
    for (i = 0; i < m->n_slaves; i++) {
        fa_slave *s = &m->slaves[i];
        if (s->n_rec) {
            int st = s->get_real(s->c, s->rec_vr, (size_t)s->n_rec, s->rec_val);
            if (st > 1) return fail(m, i, FA_CALL_GET_REAL, st, 1, t);
        }
    }
    out[0] = t;
    for (i = 0; i < m->n_cols; i++) {
        const fa_slave *s = &m->slaves[m->col_slave[i]];
        out[1 + i] = m->col_rec[i] ? s->rec_val[m->col_index[i]]
                                   : s->hist[(s->count - 1) * s->n_out + m->col_index[i]];
    }
    if (row + 1 > m->rows) m->rows = row + 1;
    return FA_DONE;
}

/* The rollback's FMU states: taken (in the slaves' order), or restored and freed. */
static int save_states(fa_master *m)
{
    int i;
    for (i = 0; i < m->n_slaves; i++) {
        fa_slave *s = &m->slaves[i];
        int st;
        s->rb_state = NULL;
        st = s->get_state(s->c, &s->rb_state);
        if (st > 1) return fail(m, i, FA_CALL_GET_STATE, st, 0, 0.0);
        snapshot(s);
        if (s->n_out) memcpy(s->peak_saved, s->peak, (size_t)s->n_out * sizeof(double));
    }
    return FA_DONE;
}

static int free_states(fa_master *m, int rc)
{
    int i;
    for (i = 0; i < m->n_slaves; i++) {
        fa_slave *s = &m->slaves[i];
        int st = s->free_state(s->c, &s->rb_state);
        if (st > 1) rc = fail(m, i, FA_CALL_FREE_STATE, st, 0, 0.0);
    }
    return rc;
}

static int roll_back(fa_master *m)
{
    int i;
    for (i = 0; i < m->n_slaves; i++) {
        fa_slave *s = &m->slaves[i];
        int st = s->set_state(s->c, s->rb_state);
        if (st > 1) return fail(m, i, FA_CALL_SET_STATE, st, 0, 0.0);
        st = s->free_state(s->c, &s->rb_state);
        if (st > 1) return fail(m, i, FA_CALL_FREE_STATE, st, 0, 0.0);
        restore(s);
        if (s->n_out) memcpy(s->peak, s->peak_saved, (size_t)s->n_out * sizeof(double));
    }
    return FA_DONE;
}

static int check(const fa_master *m)
{
    int i, j;
    if (!m || !m->slaves || !m->order || m->n_slaves < 1 || m->p < 0 || m->p > 2 ||
        m->n_out < 1 || m->j < 1 || (m->n_cols && !m->out) || !(m->h > 0.0) ||
        !(m->dt_out > 0.0) || !(m->min_step > 0.0) || !(m->max_step >= m->min_step) ||
        m->n_sources < 0 || m->n_sources > m->n_slaves || (m->n_sources && !m->sources) ||
        m->rej_cap < 1 || !m->rejected_times || m->n_rej < 0 || m->n_rej > m->rej_cap)
        return 0;
    for (i = 0; i < m->n_slaves; i++) {
        const fa_slave *s = &m->slaves[i];
        if (m->order[i] < 0 || m->order[i] >= m->n_slaves) return 0;
        if (!s->set_real || !s->get_real || !s->do_step || s->n_in < 0 || s->n_out < 0 ||
            s->n_rec < 0 || s->n_der < 0 || s->n_der > 2 || s->count < 1 ||
            s->count > FA_DEPTH || !s->hist || !s->snap || !s->peak || !s->peak_saved)
            return 0;
        if (s->n_der && !s->set_der) return 0;
        if ((m->correct_startup || m->rollback) &&
            (!s->get_state || !s->set_state || !s->free_state))
            return 0;
        for (j = 0; j < s->n_in; j++)
            if (s->in_src[j] < 0 || s->in_src[j] >= m->n_slaves ||
                s->in_idx[j] < 0 || s->in_idx[j] >= m->slaves[s->in_src[j]].n_out)
                return 0;
    }
    for (i = 0; i < m->n_sources; i++)
        if (m->sources[i] < 0 || m->sources[i] >= m->n_slaves) return 0;
    if (!m->rollback &&
        (m->f_slave < 0 || m->f_slave >= m->n_slaves || m->x_slave < 0 ||
         m->x_slave >= m->n_slaves || m->f_idx < 0 || m->f_idx >= m->slaves[m->f_slave].n_out ||
         m->x_idx < 0 || m->x_idx >= m->slaves[m->x_slave].n_out))
        return 0;
    for (i = 0; i < m->n_cols; i++) {
        const fa_slave *s;
        if (m->col_slave[i] < 0 || m->col_slave[i] >= m->n_slaves) return 0;
        s = &m->slaves[m->col_slave[i]];
        if (m->col_index[i] < 0 || m->col_index[i] >= (m->col_rec[i] ? s->n_rec : s->n_out))
            return 0;
    }
    return 1;
}

/* _run_adaptive from output point m->j to j_end, resumable: its loop's variables are in m. */
FA_API int fa_run(fa_master *m, long long j_end)
{
    int i, rc;
    if (!check(m)) return FA_BADARG;
    if (j_end > m->n_out) j_end = m->n_out;
    for (; m->j <= j_end; m->j++) {
        double t_target = m->t0 + (double)m->j * m->dt_out;
        while (m->t < t_target - 1e-12 * m->dt_out) {
            double t = m->t, h = m->step, rest = t_target - t, t1, dt, err, e, grow, h_new;
            int last = rest <= h * (1 + 1e-9), discarded = 0, k;
            if (m->n_rej >= m->rej_cap) return FA_FULL;
            t1 = last ? t_target : t + (rest < 2 * h ? py_min(h, 0.5 * rest) : h);
            if (m->rollback && (rc = save_states(m)) != FA_DONE) return rc;
            dt = t1 - t;
            rc = step(m, t, t1);
            if (rc == FA_DONE) {
                err = m->rollback ? coupling_error(m, t1, dt) : energy_error(m, t1, dt);
            } else {
                if (rc != FA_FAILED || m->fail_status != 2 || !m->rollback)
                    return m->rollback ? free_states(m, rc) : rc;
                err = INFINITY;
                discarded = 1;
            }
            k = (m->p + 1 < m->slaves[m->order[0]].count ? m->p + 1
                                                         : m->slaves[m->order[0]].count) + 1;
            if (m->rollback && err > 1.0 && dt > m->min_step * (1 + 1e-9)) {
                double factor;
                m->rejected++;
                m->rejected_times[m->n_rej++] = t;
                if ((rc = roll_back(m)) != FA_DONE) return rc;
                factor = discarded ? 0.5
                                   : py_min(0.9, py_max(0.2, 0.9 * py_pow(err, -1.0 / k)));
                m->step = py_max(m->min_step, dt * factor);
                continue;
            }
            if (discarded) {
                rc = free_states(m, FA_DISCARDED);
                if (rc == FA_DISCARDED) {
                    m->fail_time = t;
                    m->fail_timed = 1;
                }
                return rc;
            }
            if (err > 1.0 && m->rollback) m->forced++;
            if (m->rollback && (rc = free_states(m, FA_DONE)) != FA_DONE) return rc;
            for (i = 0; i < m->n_slaves; i++) push(&m->slaves[i], t1, m->slaves[i].new_val);
            m->steps++;
            m->min_used = py_min(m->min_used, dt);
            m->max_used = py_max(m->max_used, dt);
            m->t = t1;
            if (m->go_on && !m->go_on()) {
                if (fabs(t1 - t_target) <= 1e-12 * m->dt_out &&
                    (rc = store(m, m->j, t_target)) != FA_DONE)
                    return rc;
                return FA_STOPPED;
            }
            e = py_max(err, 1e-10);
            /* without rollback (energy) a step is at most halved */
            grow = py_min(5.0, py_max(m->rollback ? 0.2 : 0.5,
                                      0.9 * py_pow(e, -0.7 / k) * py_pow(m->err_prev, 0.4 / k)));
            m->err_prev = e;
            h_new = dt * grow;
            h = dt >= h * (1 - 1e-9) ? h_new : (grow < 1 ? py_min(h, h_new) : py_max(h, h_new));
            m->step = py_min(m->max_step, py_max(m->min_step, h));
        }
        m->t = t_target;
        if ((rc = store(m, m->j, t_target)) != FA_DONE) return rc;
    }
    return FA_DONE;
}

/* ====================================================================== the implicit step */
/* implicit.py InterfaceIteration, on the step counters' grid. The sources (the slaves whose
 * outputs are exchanged, in coupling order) are the slaves with n_out > 0; u stacks their
 * outputs. */

/* _evaluate: the outputs at k + 1 of the slaves `src` feeds (src < 0: all), in coupling order,
 * stepped from their states at k with the interface `u` as the sources' samples at k + 1; into
 * their new_val. A slave not stepped since its state was taken (at_start) is not restored.
 * The histories are as before, however it ends. */
static int evaluate(fa_master *m, long long k, const double *u, int src)
{
    double a0 = (double)k, a1 = (double)(k + 1);
    int i, q, off = 0, rc = FA_DONE;
    for (q = 0; q < m->n_slaves; q++) {
        fa_slave *s = &m->slaves[m->order[q]];
        if (!s->n_out) continue;
        restore(s);
        if (!s->unknown) continue;
        push(s, a1, u + off);
        off += s->n_out;
    }
    for (i = 0; i < m->n_slaves && rc == FA_DONE; i++) {
        int n = m->order[i], st;
        fa_slave *s = &m->slaves[n];
        if (src >= 0 && !m->consumer[src * m->n_slaves + n]) continue;
        if (s->at_start) {                  /* not stepped since its state was taken */
            s->at_start = 0;
        } else {
            st = s->set_state(s->c, s->rb_state);
            if (st > 1) {
                rc = fail(m, n, FA_CALL_SET_STATE, st, 0, 0.0);
                break;
            }
        }
        if ((rc = set_held(m, n, a0, a1)) != FA_DONE) break;
        rc = do_step(m, n, a0, a1);
        if (m->serial && rc == FA_DONE) {   /* the slaves after it step on its new outputs */
            rc = outputs_after_step(m, n, a1);
            if (rc == FA_DONE && s->n_out && !s->unknown) push(s, a1, s->new_val);
        }
    }
    for (i = 0; i < m->n_slaves && rc == FA_DONE && !m->serial; i++) {
        int n = m->order[i];
        if (src >= 0 && !m->consumer[src * m->n_slaves + n]) continue;
        rc = outputs_after_step(m, n, a1);
    }
    for (q = 0; q < m->n_slaves; q++)
        if (m->slaves[q].n_out) restore(&m->slaves[q]);
    return rc;
}

/* _stack: the unknown sources' new outputs, in coupling order. */
static void stack(const fa_master *m, double *g)
{
    int q, off = 0;
    for (q = 0; q < m->n_slaves; q++) {
        const fa_slave *s = &m->slaves[m->order[q]];
        if (!s->n_out || !s->unknown) continue;
        memcpy(g + off, s->new_val, (size_t)s->n_out * sizeof(double));
        off += s->n_out;
    }
}

/* _residual: max |g - u| / (tol max(1, |g|)), NaN propagating as numpy's max. */
static double residual(const fa_master *m, const double *g, const double *u)
{
    double err = 0.0;
    int i;
    if (!m->size) return 0.0;
    for (i = 0; i < m->size; i++) {
        double v = fabs(g[i] - u[i]) / (m->itol * np_maximum(1.0, fabs(g[i])));
        err = i == 0 ? v : np_maximum(err, v);
    }
    return err;
}

/* _jacobian: dG/du by forward differences of the step (only the consumers of the perturbed
 * source step again; in the serial scheme every slave), into m->jac (column-major:
 * jac[j * size + i] = dG_i/du_j). */
static int jacobian(fa_master *m, long long k)
{
    int q, j, i, off = 0, rc;
    for (q = 0; q < m->n_slaves; q++) {
        int src = m->order[q], n_cons = 0, p, pos;
        const fa_slave *s = &m->slaves[src];
        if (!s->n_out || !s->unknown) continue;
        for (p = 0; p < m->n_slaves; p++)
            n_cons += m->serial || m->consumer[src * m->n_slaves + p];
        for (j = off; j < off + s->n_out; j++) {
            double d = 1e-6 * py_max(1.0, fabs(m->u[j]));
            memcpy(m->up, m->u, (size_t)m->size * sizeof(double));
            m->up[j] += d;
            if ((rc = evaluate(m, k, m->up, m->serial ? -1 : src)) != FA_DONE) return rc;
            m->jacobian_steps += n_cons;
            memcpy(m->col, m->g, (size_t)m->size * sizeof(double));
            for (p = 0, pos = 0; p < m->n_slaves; p++) {
                const fa_slave *c = &m->slaves[m->order[p]];
                if (!c->n_out || !c->unknown) continue;
                if (m->serial || m->consumer[src * m->n_slaves + m->order[p]])
                    memcpy(m->col + pos, c->new_val, (size_t)c->n_out * sizeof(double));
                pos += c->n_out;
            }
            for (i = 0; i < m->size; i++) m->jac[j * m->size + i] = (m->col[i] - m->g[i]) / d;
        }
        off += s->n_out;
    }
    return FA_DONE;
}

/* implicit.py _broyden: jac += (g - g_last - jac du) du^T / (du . du), du = u - u_last, in
 * place, element by element in the Python loop's order. */
static void broyden(fa_master *m)
{
    int n = m->size, i, j;
    double dd = 0.0;
    for (j = 0; j < n; j++) dd = dd + (m->u[j] - m->lu[j]) * (m->u[j] - m->lu[j]);
    if (!(dd > 0.0)) return;
    for (i = 0; i < n; i++) {
        double acc = 0.0, c;
        for (j = 0; j < n; j++) acc = acc + m->jac[j * n + i] * (m->u[j] - m->lu[j]);
        c = ((m->g[i] - m->lg[i]) - acc) / dd;
        for (j = 0; j < n; j++) m->jac[j * n + i] = m->jac[j * n + i] + c * (m->u[j] - m->lu[j]);
    }
}

/* Newton's update: x = (J - I)^-1 r by Gaussian elimination with partial pivoting; 0 if
 * singular. */
static int newton_solve(fa_master *m)
{
    int n = m->size, i, j, k;
    double *a = m->a, *x = m->x;
    for (j = 0; j < n; j++)
        for (i = 0; i < n; i++) a[i * n + j] = m->jac[j * n + i] - (i == j ? 1.0 : 0.0);
    memcpy(x, m->r, (size_t)n * sizeof(double));
    for (k = 0; k < n; k++) {
        int p = k;
        for (i = k + 1; i < n; i++)
            if (fabs(a[i * n + k]) > fabs(a[p * n + k])) p = i;
        if (a[p * n + k] == 0.0) return 0;
        if (p != k) {
            double tmp;
            for (j = 0; j < n; j++) {
                tmp = a[k * n + j];
                a[k * n + j] = a[p * n + j];
                a[p * n + j] = tmp;
            }
            tmp = x[k];
            x[k] = x[p];
            x[p] = tmp;
        }
        for (i = k + 1; i < n; i++) {
            double f = a[i * n + k] / a[k * n + k];
            for (j = k + 1; j < n; j++) a[i * n + j] = a[i * n + j] - f * a[k * n + j];
            x[i] = x[i] - f * x[k];
        }
    }
    for (i = n - 1; i >= 0; i--) {
        double acc = x[i];
        for (j = i + 1; j < n; j++) acc = acc - a[i * n + j] * x[j];
        if (!(fabs(a[i * n + i]) > 0.0)) return 0;
        x[i] = acc / a[i * n + i];
    }
    return 1;
}

/* _iqn: u = g + W alpha, alpha = argmin |V alpha + r| (rows scaled by 1 / max(1, |g|)), the
 * minimum-norm solution with singular values below 1e-12 times the largest cut (numpy's lstsq
 * with rcond = 1e-12), by a one-sided Jacobi SVD of the scaled V's transpose. */
static void iqn(fa_master *m, int ncols)
{
    int n = m->size, i, j, p, q, sweep;
    double *M = m->svd_m, *Vr = m->svd_v, *sv = m->a, smax = 0.0;   /* sv: singular values */
    if (!ncols) {
        for (i = 0; i < n; i++) m->u[i] = m->u[i] + 0.5 * m->r[i];
        return;
    }
    /* M's column i (length ncols) is row i of the scaled V */
    for (i = 0; i < n; i++) {
        double sc = 1.0 / np_maximum(1.0, fabs(m->g[i]));
        m->x[i] = -m->r[i] * sc;
        for (j = 0; j < ncols; j++) M[i * ncols + j] = m->cv[j * n + i] * sc;
        for (j = 0; j < n; j++) Vr[i * n + j] = i == j ? 1.0 : 0.0;
    }
    for (sweep = 0; sweep < 60; sweep++) {
        int rotated = 0;
        for (p = 0; p < n - 1; p++)
            for (q = p + 1; q < n; q++) {
                double al = 0.0, be = 0.0, ga = 0.0, zeta, t, c, s;
                for (j = 0; j < ncols; j++) {
                    al += M[p * ncols + j] * M[p * ncols + j];
                    be += M[q * ncols + j] * M[q * ncols + j];
                    ga += M[p * ncols + j] * M[q * ncols + j];
                }
                if (ga == 0.0 || fabs(ga) <= 1e-15 * sqrt(al * be)) continue;
                rotated = 1;
                zeta = (be - al) / (2.0 * ga);
                t = (zeta >= 0.0 ? 1.0 : -1.0) / (fabs(zeta) + sqrt(1.0 + zeta * zeta));
                c = 1.0 / sqrt(1.0 + t * t);
                s = c * t;
                for (j = 0; j < ncols; j++) {
                    double mp = M[p * ncols + j], mq = M[q * ncols + j];
                    M[p * ncols + j] = c * mp - s * mq;
                    M[q * ncols + j] = s * mp + c * mq;
                }
                for (j = 0; j < n; j++) {
                    double vp = Vr[j * n + p], vq = Vr[j * n + q];
                    Vr[j * n + p] = c * vp - s * vq;
                    Vr[j * n + q] = s * vp + c * vq;
                }
            }
        if (!rotated) break;
    }
    /* scaled V^T = U S Vr^T, so V = Vr S U^T and alpha = U S^+ Vr^T b */
    for (i = 0; i < n; i++) {
        double nrm = 0.0;
        for (j = 0; j < ncols; j++) nrm += M[i * ncols + j] * M[i * ncols + j];
        sv[i] = sqrt(nrm);
        if (sv[i] > smax) smax = sv[i];
    }
    for (j = 0; j < ncols; j++) m->alpha[j] = 0.0;
    for (i = 0; i < n; i++) {
        double proj = 0.0;
        if (!(sv[i] > 1e-12 * smax)) continue;
        for (j = 0; j < n; j++) proj += Vr[j * n + i] * m->x[j];
        proj = proj / (sv[i] * sv[i]);             /* (Vr_i . b) / s_i, over s_i for U_i */
        for (j = 0; j < ncols; j++) m->alpha[j] += M[i * ncols + j] * proj;
    }
    for (i = 0; i < n; i++) {
        double acc = m->g[i];
        for (j = 0; j < ncols; j++) acc = acc + m->cw[j * n + i] * m->alpha[j];
        m->u[i] = acc;
    }
}

/* InterfaceIteration.step from k to k + 1: the converged outputs in every slave's new_val. */
static int implicit_step(fa_master *m, long long k)
{
    int i, it, rc = FA_DONE, got = 0, fresh = 0, reused = 0, nv = 0, has_prev = 0, off;
    int has_last = 0;                        /* Newton: lu, lg hold the previous iteration's */
    double err = 0.0, err_prev = INFINITY;
    int n = m->size;
    for (i = 0; i < m->n_slaves; i++) snapshot(&m->slaves[i]);
    for (i = 0; i < m->n_slaves; i++) {
        fa_slave *s = &m->slaves[i];
        int st;
        s->rb_state = NULL;
        st = s->get_state(s->c, &s->rb_state);
        if (st > 1) {
            rc = fail(m, i, FA_CALL_GET_STATE, st, 0, 0.0);
            break;
        }
        s->at_start = 1;
        got++;
    }
    for (i = 0; i < m->n_reuse; i++) reused += m->reuse_cols[i];
    /* the first guess: the unknown sources' polynomials at k + 1 */
    for (i = 0, off = 0; i < m->n_slaves && rc == FA_DONE; i++) {
        const fa_slave *s = &m->slaves[m->order[i]];
        int o;
        if (!s->unknown) continue;
        for (o = 0; o < s->n_out; o++) m->u[off + o] = predicted(m, s, (double)(k + 1), o);
        off += s->n_out;
    }
    for (it = 1; it <= m->max_it && rc == FA_DONE; it++) {
        if ((rc = evaluate(m, k, m->u, -1)) != FA_DONE) break;
        stack(m, m->g);
        for (i = 0; i < n; i++) m->r[i] = m->g[i] - m->u[i];
        err = residual(m, m->g, m->u);
        if (err <= 1.0) {
            m->iterations += it;
            if (it > m->max_iterations) m->max_iterations = it;
            if (!m->newton && nv) {          /* this step's columns join the reused ones */
                if (m->n_reuse == FA_REUSED_STEPS) {
                    int drop = m->reuse_cols[0];
                    memmove(m->cv, m->cv + drop * n,
                            (size_t)((reused + nv - drop) * n) * sizeof(double));
                    memmove(m->cw, m->cw + drop * n,
                            (size_t)((reused + nv - drop) * n) * sizeof(double));
                    memmove(m->reuse_cols, m->reuse_cols + 1,
                            (FA_REUSED_STEPS - 1) * sizeof(int));
                    m->n_reuse--;
                }
                m->reuse_cols[m->n_reuse++] = nv;
            }
            break;
        }
        if (it == m->max_it || !isfinite(err)) {
            m->iterations += it;
            if (it > m->max_iterations) m->max_iterations = it;
            m->fail_kind = isfinite(err) ? FA_NOT_CONVERGED : FA_NOT_FINITE;
            m->fail_residual = err;
            m->fail_iterations = it;
            rc = FA_DIVERGED;
            break;
        }
        if (m->newton) {
            if (has_last && m->have_jac) broyden(m);
            memcpy(m->lu, m->u, (size_t)n * sizeof(double));
            memcpy(m->lg, m->g, (size_t)n * sizeof(double));
            has_last = 1;
            if (!m->have_jac || (err > 0.1 * err_prev && !fresh)) {
                if ((rc = jacobian(m, k)) != FA_DONE) break;
                m->have_jac = 1;
                fresh = 1;
            }
            if (!newton_solve(m)) {
                m->fail_kind = FA_SINGULAR;
                m->fail_residual = err;
                m->fail_iterations = it;
                rc = FA_DIVERGED;
                break;
            }
            for (i = 0; i < n; i++) m->u[i] = m->u[i] - m->x[i];
        } else {
            double *pr = m->col, *pg = m->up;   /* the previous iteration's r and g */
            if (has_prev) {
                double *v = m->cv + (reused + nv) * n, *w = m->cw + (reused + nv) * n;
                for (i = 0; i < n; i++) {
                    v[i] = m->r[i] - pr[i];
                    w[i] = m->g[i] - pg[i];
                }
                nv++;
            }
            memcpy(pr, m->r, (size_t)n * sizeof(double));
            memcpy(pg, m->g, (size_t)n * sizeof(double));
            has_prev = 1;
            iqn(m, reused + nv);
        }
        err_prev = err;
    }
    for (i = 0; i < got; i++) {
        fa_slave *s = &m->slaves[i];
        int st = s->free_state(s->c, &s->rb_state);
        if (st > 1) rc = fail(m, i, FA_CALL_FREE_STATE, st, 0, 0.0);
    }
    if (rc == FA_DIVERGED) m->fail_time = secs(m, (double)k);
    return rc;
}

FA_API int fa_run_implicit(fa_master *m, long long k_end)
{
    int i, rc;
    if (!check(m) || !m->counters || !m->weights || m->m_out < 1 || m->k < 0 ||
        m->size < 0 || m->max_it < 1 ||
        (m->size && (!m->u || !m->jac || !m->cv || !m->lu || !m->lg)))
        return FA_BADARG;
    if (k_end > m->total) k_end = m->total;
    while (m->k < k_end) {
        long long k = m->k;
        if ((rc = implicit_step(m, k)) != FA_DONE) return rc;
        for (i = 0; i < m->n_slaves; i++)
            push(&m->slaves[i], (double)(k + 1), m->slaves[i].new_val);
        m->k = k + 1;
        m->t = secs(m, (double)(k + 1));
        if ((k + 1) % m->m_out == 0 &&
            (rc = store(m, (k + 1) / m->m_out, m->t)) != FA_DONE)
            return rc;
        if (m->go_on && !m->go_on()) return FA_STOPPED;
    }
    return FA_DONE;
}
