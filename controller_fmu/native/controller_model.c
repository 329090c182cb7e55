/*
 * controller_model.c - PDLowPass as a native FMU model (see fpm.h), on the filter's compiled
 * kernel (controller_fmu/native/fp_filter.c): the behaviour of the pythonfmu slave
 * (controller_fmu/fmu.py).
 *
 * Over doStep(t, h) the filter advances exactly, xc <- Ad(h) xc + G(h) [e, e', e''], with the
 * error signal e = kx x_o + kp phi_o + kd omega_o and its time derivatives from the sensors'
 * input derivatives (fmi2SetRealInputDerivatives; zero: held inputs). F_c = -sat(xc[0]); with
 * filter_order = 0 there is no filter and F_c = -sat(e) from the current inputs (direct
 * feedthrough). F_c is never NaN: with non-finite inputs it holds its last value.
 */
#include <math.h>
#include <stdio.h>
#include <string.h>

#include "fp_filter.h"
#include "fpm.h"
#include "fpm_vars.h"

/* the sensors in the kernel's order: x_o, phi_o, omega_o */
static const unsigned SENSOR_VRS[3] = {VR_x_o, VR_phi_o, VR_omega_o};
static const char *SENSOR_NAMES[3] = {"x_o", "phi_o", "omega_o"};

typedef struct disc {
    double h;
    double Ad[4], G[6];
} disc;

struct fpm_model {
    fpm_values v;
    double t0, t;
    int initialized;
    char error[FPM_MSG_MAX];
    fpf_filter f;
    double d[2][3];             /* first and second time derivatives of the sensors */
    double xc[2];
    double F;                   /* F_c after the last step, or the last finite F_c */
    int stepped;                /* a doStep succeeded since initialisation (input_now) */
    double step_y[9];           /* the sensors' polynomial that step used (sensors() layout) */
    double step_h;              /* and its length */
    disc cache[2];
    int next;
    /* the sampled controller (FPM_SAMPLED; controller_fmu/sampled.py): the filter's difference
     * equation over T (xc holds its state), the next tick's index, the force waiting for its
     * delay (pending; it acts from t0 + (k - 1) T + tau on); F is the force held */
    double T, tau, sAd[4], sBd[2], sCd[2], sDd;
    double k;                   /* an integer, as a double (saved exactly) */
    int pending;
    double pend_F;
    /* its FMI 3.0 clocks (FPM_N_CLOCKS; fpm.h): the instance uses them (event mode), and which
     * are active in the current super-dense instant (neither is part of an FMU state) */
    int clocked;
    int active[2];
};

size_t fpm_model_size(void) { return sizeof(fpm_model); }
fpm_values *fpm_model_values(fpm_model *m) { return &m->v; }
double fpm_model_time(const fpm_model *m) { return m->t; }

void fpm_model_reset(fpm_model *m, double start_time)
{
    memset(m, 0, sizeof *m);
    fpm_start_values(&m->v);
    m->t0 = m->t = start_time;
}

/* check_real of fmu_common/checks.py, as ControllerParams uses it */
static int check(const fpm_logger *lg, const char *name, double v, double low, int low_open,
                 double high, int allow_inf)
{
    int ok = !isnan(v) && (isfinite(v) || (allow_inf && v == INFINITY)) &&
             (low_open ? v > low : v >= low) && v <= high;
    if (!ok)
        fpm_log(lg, FPM_ERROR, "bad parameter: %s = %.17g is out of range; allowed: %s%g, %g]",
                name, v, low_open ? "(" : "[", low, high);
    return ok;
}

/* The sampled controller's parameters (controller_fmu/pd_lowpass.py): delay <= sample_period,
 * a known discretization; the continuous PDLowPass runs sample_period = 0 only. */
static int sampled_parameters(const fpm_model *m, const fpm_logger *lg)
{
    const double *r = m->v.real;
    const char *disc = m->v.string[VR_discretization];
    if (!(r[VR_delay] <= r[VR_sample_period])) {
        fpm_log(lg, FPM_ERROR, "bad parameter: delay = %.17g is out of range; allowed: "
                "[0, sample_period] = [0, %.17g] s", r[VR_delay], r[VR_sample_period]);
        return 0;
    }
    if (strcmp(disc, "tustin") != 0 && strcmp(disc, "zoh") != 0) {
        fpm_log(lg, FPM_ERROR, "bad parameter: discretization = '%s' is not allowed; allowed: "
                "tustin, zoh", disc);
        return 0;
    }
#if FPM_SAMPLED
    if (!(r[VR_sample_period] > 0.0)) {
        fpm_log(lg, FPM_ERROR, "bad parameter: sample_period = %.17g: %s is the sampled "
                "controller (sample_period > 0); the continuous one (sample_period = 0) is the "
                "FMU PDLowPass", r[VR_sample_period], fpm_model_name);
        return 0;
    }
#else
    if (r[VR_sample_period] != 0.0) {
        fpm_log(lg, FPM_ERROR, "bad parameter: sample_period = %.17g: %s is the continuous "
                "controller (sample_period = 0); the sampled one is the FMU PDLowPassSampled",
                r[VR_sample_period], fpm_model_name);
        return 0;
    }
#endif
    return 1;
}

static int prepare(fpm_model *m, const fpm_logger *lg)
{
    const double *r = m->v.real;
    if (!check(lg, "kp", r[VR_kp], -1e12, 1, 1e12, 0) ||
        !check(lg, "kd", r[VR_kd], -1e12, 1, 1e12, 0) ||
        !check(lg, "kx", r[VR_kx], -1e12, 1, 1e12, 0))
        return 0;
    if (!(r[VR_filter_order] >= 0 && r[VR_filter_order] <= 2)) {
        fpm_log(lg, FPM_ERROR, "bad parameter: filter_order = %.17g is out of range; allowed: "
                "integers 0..2", r[VR_filter_order]);
        return 0;
    }
    if (!check(lg, "cutoff", r[VR_cutoff], 0.0, 1, 1e9, 0) ||
        !check(lg, "filter_damping", r[VR_filter_damping], 0.0, 1, 100.0, 0) ||
        !check(lg, "force_limit", r[VR_force_limit], 0.0, 1, INFINITY, 1) ||
        !check(lg, "sample_period", r[VR_sample_period], 0.0, 0, 1e3, 0) ||
        !check(lg, "delay", r[VR_delay], 0.0, 0, 1e3, 0))
        return 0;
    if (!sampled_parameters(m, lg)) return 0;
    m->f.order = (int)r[VR_filter_order];
    m->f.kp = r[VR_kp];
    m->f.kd = r[VR_kd];
    m->f.kx = r[VR_kx];
    m->f.cutoff = r[VR_cutoff];
    m->f.damping = r[VR_filter_damping];
    m->f.force_limit = r[VR_force_limit];
    if (fpf_check(&m->f) != FPF_OK) {
        fpm_log(lg, FPM_ERROR, "bad parameter: the filter's parameters are out of range");
        return 0;
    }
    m->xc[0] = m->xc[1] = 0.0;
    m->F = 0.0;
    m->stepped = 0;
    memset(m->step_y, 0, sizeof m->step_y);
    m->step_h = 0.0;
    m->cache[0].h = m->cache[1].h = -1.0;
    m->t = m->t0;
    m->T = r[VR_sample_period];
    m->tau = r[VR_delay];
    m->k = 0.0;
    m->pending = 0;
    m->pend_F = 0.0;
#if FPM_SAMPLED
    {
        const int tustin = strcmp(m->v.string[VR_discretization], "tustin") == 0;
        const int rc = fpf_sampled(&m->f, m->T, tustin, m->sAd, m->sBd, m->sCd, &m->sDd);
        if (rc == FPF_BADARG && tustin) {
            fpm_log(lg, FPM_ERROR, "bad parameter: sample_period = %.17g is out of range for "
                    "the tustin filter prewarped at cutoff = %.17g rad/s; allowed: below pi / "
                    "cutoff = %.6g s (or discretization = 'zoh')", m->T, m->f.cutoff,
                    3.141592653589793 / m->f.cutoff);
            return 0;
        }
        if (rc != FPF_OK) {
            fpm_log(lg, FPM_ERROR, "bad parameter: the filter's difference equation over "
                    "sample_period = %.17g is not finite", m->T);
            return 0;
        }
    }
#endif
    return 1;
}

/* The filter's discretisations depend on the filter's parameters and the step only. */
void fpm_model_keep(fpm_model *m, const fpm_model *from)
{
    const fpf_filter *a = &m->f, *b = &from->f;
    if (a->order == b->order && memcmp(&a->kp, &b->kp, sizeof a->kp) == 0 &&
        memcmp(&a->kd, &b->kd, sizeof a->kd) == 0 && memcmp(&a->kx, &b->kx, sizeof a->kx) == 0 &&
        memcmp(&a->cutoff, &b->cutoff, sizeof a->cutoff) == 0 &&
        memcmp(&a->damping, &b->damping, sizeof a->damping) == 0 &&
        memcmp(&a->force_limit, &b->force_limit, sizeof a->force_limit) == 0) {
        memcpy(m->cache, from->cache, sizeof m->cache);
        m->next = from->next;
    }
}

int fpm_model_init(fpm_model *m, const fpm_logger *lg)
{
    m->initialized = prepare(m, lg);
    return m->initialized ? FPM_OK : FPM_ERROR;
}

int fpm_model_initialized(const fpm_model *m) { return m->initialized; }

void fpm_model_save(const fpm_model *m, fpm_writer *w)
{
    int k;
    fpm_put_f64(w, m->t0);
    fpm_put_f64(w, m->t);
    fpm_put_i32(w, m->initialized);
    for (k = 0; k < 3; k++) {
        fpm_put_f64(w, m->d[0][k]);
        fpm_put_f64(w, m->d[1][k]);
    }
    fpm_put_f64(w, m->xc[0]);
    fpm_put_f64(w, m->xc[1]);
    fpm_put_f64(w, m->F);
    fpm_put_i32(w, m->stepped);
    for (k = 0; k < 9; k++) fpm_put_f64(w, m->step_y[k]);
    fpm_put_f64(w, m->step_h);
    fpm_put_f64(w, m->k);                     /* the sampled controller's (0 in PDLowPass) */
    fpm_put_i32(w, m->pending);
    fpm_put_f64(w, m->pend_F);
}

/* The sampled controller's instants (controller_fmu/sampled.py): two instants within
 * TICK_TOLERANCE of the sample period are one. */
#define TICK_TOLERANCE 1e-9

#if FPM_SAMPLED
static double tick_at(const fpm_model *m, double k) { return m->t0 + k * m->T; }
#endif

/* What a restored state of the sampled controller must hold (PDLowPass: nothing of it): k an
 * integer >= 0 with the time reached between the last tick taken and the next,
 * t0 + (k - 1) T <= t <= t0 + k T; a pending force only with a delay, before it acts, and
 * within the limit; none pending: 0. */
static int sampled_state_holds(const fpm_model *m, fpm_reader *r, double t, double k,
                               int pending, double pend_F)
{
#if FPM_SAMPLED
    const double tol = TICK_TOLERANCE * m->T;
    if (!(k >= 0.0 && k == floor(k) && k < 9.0e15))
        return fpm_reject(r, "the next tick's index %g is not an integer >= 0", k);
    if (!(t <= tick_at(m, k) + tol && (k == 0.0 || t >= tick_at(m, k - 1.0) - tol)))
        return fpm_reject(r, "t = %.17g is not between the last tick taken and the next "
                          "(tick %g at %.17g)", t, k, tick_at(m, k));
    if (pending && (m->tau == 0.0 || k == 0.0 || !(t < tick_at(m, k - 1.0) + m->tau - tol)))
        return fpm_reject(r, "a force is pending where none can be (delay %g, t = %.17g)",
                          m->tau, t);
    if (!(fabs(pend_F) <= m->f.force_limit) || (!pending && pend_F != 0.0))
        return fpm_reject(r, "the pending force %g is not one the controller computes", pend_F);
    return 1;
#else
    (void)m;
    (void)t;
    if (k != 0.0 || pending || pend_F != 0.0)
        return fpm_reject(r, "a state of the sampled controller (PDLowPassSampled)");
    return 1;
#endif
}

int fpm_model_load(fpm_model *m, fpm_reader *r, int initialized, const fpm_model *live)
{
    fpm_logger lg;
    double t0, t, xc[2], F, step_y[9], step_h, tick, pend_F;
    int k, init, stepped, pending;
    (void)live;                    /* prepare() is cheap here: rebuilt (fpm_model_keep keeps the
                                      filter's discretisations) */
    lg = fpm_reader_logger(r);
    fpm_get_finite(r, "t0", &t0);
    fpm_get_finite(r, "t", &t);
    if (!fpm_get_int_in(r, "initialized", 0, 1, &init)) return 0;
    if (initialized >= 0 && init != initialized)
        return fpm_reject(r, "the model is %sinitialised in a state that needs %s",
                          init ? "" : "not ", initialized ? "an initialised one" : "none");
    for (k = 0; k < 3; k++) {                 /* any values: legal calls can set them */
        fpm_get_f64(r, "an input derivative", &m->d[0][k]);
        fpm_get_f64(r, "an input derivative", &m->d[1][k]);
    }
    fpm_get_finite(r, "xc[0]", &xc[0]);
    fpm_get_finite(r, "xc[1]", &xc[1]);
    fpm_get_finite(r, "F_c", &F);
    fpm_get_int_in(r, "stepped", 0, 1, &stepped);
    for (k = 0; k < 9; k++) fpm_get_finite(r, "the inputs of the last step", &step_y[k]);
    fpm_get_finite(r, "the last step's length", &step_h);
    fpm_get_finite(r, "the next tick's index", &tick);
    fpm_get_int_in(r, "the pending flag", 0, 1, &pending);
    fpm_get_finite(r, "the pending force", &pend_F);
    if (r->why[0] != '\0') return 0;
    if (!(step_h >= 0.0) || (!stepped && step_h != 0.0))
        return fpm_reject(r, "the last step's length %g is not that of a step", step_h);
    for (k = 0; k < 9 && !stepped; k++)
        if (step_y[k] != 0.0)
            return fpm_reject(r, "the inputs of a step that was not taken are not 0");
    if (stepped && r->interface == FPM_MODEL_EXCHANGE)
        return fpm_reject(r, "a Model-Exchange state cannot hold a communication step's inputs "
                          "(stepped = 1)");
    m->t0 = t0;
    m->t = t0;
    if (!init) {                              /* as reset left it (F_c: a feedthrough read) */
        if (t != t0 || xc[0] != 0.0 || xc[1] != 0.0 || stepped || tick != 0.0 || pending
            || pend_F != 0.0)
            return fpm_reject(r, "the filter of a model not initialised has moved");
        m->F = F;
        return 1;
    }
    /* the parameters with the checks of initialisation, and everything derived from them */
    if (!prepare(m, &lg)) return 0;
    m->initialized = 1;
    if (!(t >= t0)) return fpm_reject(r, "t = %.17g is before the start t0 = %.17g", t, t0);
    if (xc[1] != 0.0 && m->f.order < 2)
        return fpm_reject(r, "xc[1] = %g but the filter has order %d", xc[1], m->f.order);
    if (xc[0] != 0.0 && m->f.order < 1)
        return fpm_reject(r, "xc[0] = %g but there is no filter", xc[0]);
    if (!(fabs(F) <= m->f.force_limit))
        return fpm_reject(r, "F_c = %g exceeds force_limit = %g", F, m->f.force_limit);
    if (!sampled_state_holds(m, r, t, tick, pending, pend_F)) return 0;
    m->t = t;
    m->xc[0] = xc[0];
    m->xc[1] = xc[1];
    m->F = F;
    m->stepped = stepped;
    m->k = tick;
    m->pending = pending;
    m->pend_F = pend_F;
    memcpy(m->step_y, step_y, sizeof step_y);
    m->step_h = step_h;
    return 1;
}

/* The sensors and their derivatives, y = [x_o, phi_o, omega_o, d.., d2..]; 1 if all finite. */
static int sensors(const fpm_model *m, double *y)
{
    int k, ok = 1;
    for (k = 0; k < 3; k++) {
        y[k] = m->v.real[SENSOR_VRS[k]];
        y[3 + k] = m->d[0][k];
        y[6 + k] = m->d[1][k];
    }
    for (k = 0; k < 9; k++) ok = ok && isfinite(y[k]);
    return ok;
}

static void name_bad(const double *y, char *buf, size_t n)
{
    int k;
    size_t used = 0;
    static const char *PRE[3] = {"", "d", "d2"};
    buf[0] = '\0';
    for (k = 0; k < 9 && used < n; k++)
        if (!isfinite(y[k]))
            used += (size_t)snprintf(buf + used, n - used, "%s%s%s = %g", used ? ", " : "",
                                     PRE[k / 3], SENSOR_NAMES[k % 3], y[k]);
}

#if FPM_SAMPLED
/* The force of the tick at hand for the error signal e, and the filter state after it:
 * u = sat(-(Cd xf + Dd e)), xf <- Ad xf + Bd e. 1 if both are finite. */
static int sampled_force(const fpm_model *m, double e, double *u, double *xf)
{
    const int n = m->f.order;
    double v = m->sDd * e, x0 = 0.0, x1 = 0.0;
    int i;
    for (i = 0; i < n; i++) v += m->sCd[i] * m->xc[i];
    if (n == 1) {
        x0 = m->sAd[0] * m->xc[0] + m->sBd[0] * e;
    } else if (n == 2) {
        x0 = m->sAd[0] * m->xc[0] + m->sAd[1] * m->xc[1] + m->sBd[0] * e;
        x1 = m->sAd[2] * m->xc[0] + m->sAd[3] * m->xc[1] + m->sBd[1] * e;
    }
    if (!(isfinite(v) && isfinite(x0) && isfinite(x1))) return 0;
    *u = -v;
    if (*u < -m->f.force_limit) *u = -m->f.force_limit;
    if (*u > m->f.force_limit) *u = m->f.force_limit;
    xf[0] = x0;
    xf[1] = x1;
    return 1;
}

/* The sample of the tick at hand (the time reached, t): the sensors set now give the force u
 * and the filter state after the tick, xf; FPM_OK, or `status` with a message naming `what`
 * (the state unchanged) for a non-finite input or a filter that overflows. The one arithmetic
 * of both paths: a tick taken inside doStep, a tick of sample_clock. */
static int take_sample(const fpm_model *m, const fpm_logger *lg, int status, double t,
                       const char *what, double *u, double *xf)
{
    double y[9], e[3];
    char bad[256];
    if (!sensors(m, y)) {
        name_bad(y, bad, sizeof bad);
        fpm_log(lg, status, "non-finite input at the tick t = %.17g: %s; %s, state unchanged",
                t, bad, what);
        return status;
    }
    fpf_error(&m->f, y, e);
    if (!sampled_force(m, e[0], u, xf)) {
        fpm_log(lg, status, "the sample at t = %.17g overflows the filter (error signal "
                "%.17g); %s, state unchanged", t, e[0], what);
        return status;
    }
    return FPM_OK;
}

/* A communication step of the sampled controller (controller_fmu/sampled.py, step): the tick
 * at t (if any) samples the sensors set now; a force whose delay runs out at t + h takes over;
 * a step across a tick or a tick + delay is refused (fmi2Discard), the state unchanged. */
static int sampled_step(fpm_model *m, const fpm_logger *lg, double t, double h)
{
    const double tol = TICK_TOLERANCE * m->T, tick = tick_at(m, m->k);
    double k = m->k, xf[2] = {m->xc[0], m->xc[1]}, held = m->F, pend_F = m->pend_F;
    double end = t + h, next;
    int pending = m->pending;
    if (t > tick + tol) {
        fpm_log(lg, FPM_ERROR, "the tick at t = %.17g was missed (the step starts at %.17g)",
                tick, t);
        return FPM_ERROR;
    }
    if (m->clocked) {                         /* the clocks take the instants (event mode) */
        const double due = tick_at(m, k - 1.0) + m->tau;
        if (fabs(t - tick) <= tol) {
            fpm_log(lg, FPM_DISCARD, "the step from t = %.17g starts at a tick not taken: "
                    "activate sample_clock there (fmi3SetClock in event mode, then "
                    "fmi3UpdateDiscreteStates); step refused, state unchanged", t);
            return FPM_DISCARD;
        }
        if (pending && fabs(t - due) <= tol) {
            fpm_log(lg, FPM_DISCARD, "the step from t = %.17g starts where the force of the "
                    "last sample takes over: activate force_clock there (fmi3SetClock in event "
                    "mode, then fmi3UpdateDiscreteStates); step refused, state unchanged", t);
            return FPM_DISCARD;
        }
    } else if (fabs(t - tick) <= tol) {
        double u;
        int rc = take_sample(m, lg, FPM_DISCARD, t, "step rejected", &u, xf);
        if (rc != FPM_OK) return rc;
        k += 1.0;
        if (m->tau == 0.0) {
            held = u;
        } else {
            pending = 1;
            pend_F = u;
        }
    }
    next = tick_at(m, k);
    if (pending && tick_at(m, k - 1.0) + m->tau < next) next = tick_at(m, k - 1.0) + m->tau;
    if (end > next + tol) {
        fpm_log(lg, FPM_DISCARD, "the step from t = %.17g over h = %.17g crosses the "
                "controller's instant t = %.17g (a sample every sample_period = %.17g s, the "
                "force delay = %.17g s after it): land a communication point on it; step "
                "refused, state unchanged", t, h, next, m->T, m->tau);
        return FPM_DISCARD;
    }
    if (!m->clocked && pending && fabs(end - (tick_at(m, k - 1.0) + m->tau)) <= tol) {
        held = pend_F;
        pending = 0;
        pend_F = 0.0;
    }
    m->k = k;
    m->xc[0] = xf[0];
    m->xc[1] = xf[1];
    m->F = held;
    m->pending = pending;
    m->pend_F = pend_F;
    m->t = end;
    m->stepped = 1;
    m->step_h = h;
    return FPM_OK;
}
#endif

int fpm_model_step(fpm_model *m, const fpm_logger *lg, double t, double h)
{
    double y[9], e[3], F;
    disc *d;
    char bad[256];
    if (!m->initialized) {
        fpm_log(lg, FPM_ERROR, "%s cannot step: it was not initialised", fpm_model_name);
        return FPM_ERROR;
    }
#if FPM_SAMPLED
    return sampled_step(m, lg, t, h);
#endif
    if (!sensors(m, y)) {
        name_bad(y, bad, sizeof bad);
        fpm_log(lg, FPM_DISCARD, "non-finite input at t = %.17g: %s; step rejected, state "
                "unchanged", t, bad);
        return FPM_DISCARD;
    }
    if (m->f.order) {
        if (m->cache[0].h == h) d = &m->cache[0];
        else if (m->cache[1].h == h) d = &m->cache[1];
        else {
            d = &m->cache[m->next];
            if (fpf_discretize(&m->f, h, 1, d->Ad, d->G) != FPF_OK) {
                d->h = -1.0;
                fpm_log(lg, FPM_DISCARD, "filter step rejected at t = %.17g: the matrix "
                        "exponential over h = %.17g overflows; state unchanged", t, h);
                return FPM_DISCARD;
            }
            d->h = h;
            m->next = 1 - m->next;
        }
        fpf_error(&m->f, y, e);
        if (fpf_step(&m->f, d->Ad, d->G, e, m->xc, &F) != FPF_OK) {
            fpm_log(lg, FPM_DISCARD, "filter step rejected at t = %.17g: the filter state "
                    "overflows (error signal %.17g); state unchanged", t, e[0]);
            return FPM_DISCARD;
        }
        m->F = F;
    }
    m->t = t + h;
    m->stepped = 1;
    memcpy(m->step_y, y, sizeof m->step_y);
    m->step_h = h;
    return FPM_OK;
}

/* ================================================================== Model Exchange (issue 24)
 * The states [xc_1, xc_2]: the filter state (FPM_NX = 2; beyond the filter order 0 with
 * derivative 0), with xc' = Af xc + Bf e (controllable canonical form, pd_lowpass.py), e from the
 * sensors set now (no input derivatives in Model Exchange); F_c = -sat(xc_1) (filter order 0:
 * -sat(e), direct feedthrough). The state lives where co-simulation keeps it (xc, t; F holds
 * -sat(xc_1)), so FMU states save and restore it. No event indicators: the saturation acts on
 * the output alone (xc' has no saturation in it), so F_c stays continuous in time and nothing in
 * this FMU jumps; an integrator of the plant sees a kink in its input, which it handles as any
 * other non-smooth input. */
size_t fpm_model_nz(void) { return FPM_NZ; }

int fpm_model_me_init(fpm_model *m, const fpm_logger *lg)
{
    (void)m;
    (void)lg;
    return FPM_OK;
}

int fpm_model_set_time(fpm_model *m, const fpm_logger *lg, double t)
{
    if (!(t >= m->t0)) {
        fpm_log(lg, FPM_ERROR, "time = %.17g is before the start time %.17g", t, m->t0);
        return FPM_ERROR;
    }
    m->t = t;
    return FPM_OK;
}

void fpm_model_get_states(const fpm_model *m, double *x)
{
    x[0] = m->f.order >= 1 ? m->xc[0] : 0.0;
    x[1] = m->f.order >= 2 ? m->xc[1] : 0.0;
}

static double saturated(const fpm_model *m, double F)
{
    if (F < -m->f.force_limit) return -m->f.force_limit;
    if (F > m->f.force_limit) return m->f.force_limit;
    return F;
}

int fpm_model_set_states(fpm_model *m, const fpm_logger *lg, const double *x)
{
    (void)lg;
    if (m->f.order >= 1) {                    /* beyond the filter order: not used */
        m->xc[0] = x[0];
        m->F = saturated(m, -x[0]);
    }
    if (m->f.order >= 2) m->xc[1] = x[1];
    return FPM_OK;
}

int fpm_model_derivatives(fpm_model *m, const fpm_logger *lg, double *dx)
{
    double y[9], e[3], wc = m->f.cutoff;
    int k;
    dx[0] = dx[1] = 0.0;
    if (m->f.order == 0) return FPM_OK;
    for (k = 0; k < 3; k++) y[k] = m->v.real[SENSOR_VRS[k]];
    for (k = 3; k < 9; k++) y[k] = 0.0;       /* no input derivatives in Model Exchange */
    if (!(isfinite(y[0]) && isfinite(y[1]) && isfinite(y[2]))) {
        char bad[256];
        name_bad(y, bad, sizeof bad);
        fpm_log(lg, FPM_ERROR, "non-finite input at t = %.17g: %s", m->t, bad);
        return FPM_ERROR;
    }
    fpf_error(&m->f, y, e);
    if (m->f.order == 1) {
        dx[0] = wc * (e[0] - m->xc[0]);
    } else {
        dx[0] = m->xc[1];
        dx[1] = wc * wc * (e[0] - m->xc[0]) - 2.0 * m->f.damping * wc * m->xc[1];
    }
    if (!(isfinite(dx[0]) && isfinite(dx[1]))) {
        fpm_log(lg, FPM_ERROR, "the filter's derivative is not finite at t = %.17g (error signal "
                "%g)", m->t, e[0]);
        return FPM_ERROR;
    }
    return FPM_OK;
}

/* xc_1: a force, |kp| x 1 rad, or force_limit when that is smaller (no limit is the largest
 * double, never the scale); xc_2: cutoff times that. */
void fpm_model_nominals(const fpm_model *m, double *nominal)
{
    double f = fmin(fabs(m->f.kp), m->f.force_limit);
    if (!(isfinite(f) && f > 0.0)) f = 1.0;
    nominal[0] = f;
    nominal[1] = isfinite(f * m->f.cutoff) && f * m->f.cutoff > 0.0 ? f * m->f.cutoff : 1.0;
    if (m->f.order < 2) nominal[1] = 1.0;
    if (m->f.order < 1) nominal[0] = 1.0;
}

int fpm_model_event_indicators(fpm_model *m, const fpm_logger *lg, double *z)
{
    (void)m;
    (void)lg;
    (void)z;
    return FPM_OK;
}

int fpm_model_event_update(fpm_model *m, const fpm_logger *lg, int *terminate)
{
    (void)m;
    (void)lg;
    *terminate = 0;
    return FPM_OK;
}

int fpm_model_get_local(fpm_model *m, const fpm_logger *lg, unsigned vr, double *value)
{
    const fpm_var *v = &fpm_vars[vr];
    double a[2];
    int rc = FPM_OK;
    if (!m->initialized && !prepare(m, lg)) {
        fpm_log(lg, FPM_ERROR, "%s cannot be computed: a parameter is bad (above)", v->name);
        return FPM_ERROR;
    }
    if (v->state) {
        fpm_model_get_states(m, a);
        *value = a[v->state - 1];
    } else if (v->der) {
        rc = fpm_model_derivatives(m, lg, a);
        *value = a[v->der - 1];
    } else {
        fpm_log(lg, FPM_ERROR, "value reference %u is not a Model-Exchange local", vr);
        return FPM_ERROR;
    }
    return rc;
}
/* ================================================================== end of Model Exchange */

int fpm_model_get_output(fpm_model *m, const fpm_logger *lg, unsigned vr, double *value)
{
    double y[9], e[3], F;
    if (vr != VR_F_c) {
        fpm_log(lg, FPM_ERROR, "value reference %u is not an output", vr);
        return FPM_ERROR;
    }
    if (!m->initialized && !prepare(m, lg)) {
        fpm_log(lg, FPM_ERROR, "F_c cannot be computed: a parameter is bad (above)");
        return FPM_ERROR;
    }
#if FPM_SAMPLED
    if (m->clocked && m->initialized) {       /* event mode: the force of the active clocks */
        const double due = tick_at(m, m->k - 1.0) + m->tau;
        if (m->active[1] && m->pending && fabs(m->t - due) <= TICK_TOLERANCE * m->T) {
            *value = m->pend_F;
            return FPM_OK;
        }
        if (!(m->tau == 0.0 && m->active[0])) {
            *value = m->F;
            return FPM_OK;
        }
    }
    if (m->tau == 0.0 && fabs(m->t - tick_at(m, m->k)) <= TICK_TOLERANCE * m->T) {
        double u, xf[2];                      /* the tick at hand: a feedthrough of the inputs */
        if (sensors(m, y)) {
            fpf_error(&m->f, y, e);
            if (sampled_force(m, e[0], &u, xf)) {
                *value = u;
                return FPM_OK;
            }
        }
        fpm_log(lg, FPM_WARNING, "F_c is not finite for the inputs given at the tick t = %.17g; "
                "F_c holds its last value %.17g", m->t, m->F);
        *value = m->F;
        return FPM_WARNING;
    }
    *value = m->F;
    return FPM_OK;
#endif
    if (m->f.order == 0) {                    /* direct feedthrough of the current inputs */
        if (sensors(m, y)) {
            fpf_error(&m->f, y, e);
            F = -e[0];
            if (F < -m->f.force_limit) F = -m->f.force_limit;
            if (F > m->f.force_limit) F = m->f.force_limit;
            if (isfinite(F)) {
                m->F = F;
            } else {
                fpm_log(lg, FPM_WARNING, "F_c is not finite for the inputs given; F_c holds its "
                        "last value %.17g", m->F);
                *value = m->F;
                return FPM_WARNING;
            }
        } else {
            char bad[256];
            name_bad(y, bad, sizeof bad);
            fpm_log(lg, FPM_WARNING, "F_c is not finite for the inputs %s; F_c holds its last "
                    "value %.17g", bad, m->F);
            *value = m->F;
            return FPM_WARNING;
        }
    }
    if (!isfinite(m->F)) {                    /* never: F_c holds its last finite value */
        fpm_log(lg, FPM_ERROR, "F_c = %g is not finite at t = %.17g", m->F, m->t);
        return FPM_ERROR;
    }
    *value = m->F;
    return FPM_OK;
}

int fpm_model_set_input_derivative(fpm_model *m, const fpm_logger *lg, unsigned vr, int order,
                                   double value)
{
    int k;
#if FPM_SAMPLED
    (void)m;
    (void)value;
    fpm_log(lg, FPM_ERROR, "fmi2SetRealInputDerivatives: %s samples its inputs at its ticks and "
            "takes no input derivatives (canInterpolateInputs = false; value reference %u, "
            "order %d)", fpm_model_name, vr, order);
    return FPM_ERROR;
#endif
    for (k = 0; k < 3; k++)
        if (vr == SENSOR_VRS[k] && (order == 1 || order == 2)) {
            m->d[order - 1][k] = value;
            if (m->stepped) {     /* the inputs set now replace the last step's polynomial */
                m->stepped = 0;   /* (input_now): as after initialisation */
                memset(m->step_y, 0, sizeof m->step_y);
                m->step_h = 0.0;
            }
            return FPM_OK;
        }
    fpm_log(lg, FPM_ERROR, "fmi2SetRealInputDerivatives: PDLowPass takes derivatives of order 1 "
            "and 2 of x_o, phi_o, omega_o only (got order %d of value reference %u)", order, vr);
    return FPM_ERROR;
}

/* ================================================================== Jacobians and output
 * derivatives (issue 24; fpm.h) on the kernel's fpf_linearize and fpf_output_derivatives.
 *
 * States [xc_1, xc_2] (rows and columns beyond the filter order are 0); inputs phi_o, omega_o,
 * x_o (the table's order, which is fpf_linearize's); the output F_c. The saturation's slope is
 * that of the branch computing the value: 1 for |v| <= force_limit (the bound included), 0
 * beyond (fp_filter.h), v = xc_1, or e for filter_order 0. Before initialisation: FPM_ERROR (the
 * core refuses earlier). */
#define JAC_NX 2

size_t fpm_model_nx(void) { return JAC_NX; }

int fpm_model_max_output_derivative_order(void) { return FPM_OUTPUT_DERIVATIVE_ORDER; }
int fpm_model_offers_me(void) { return FPM_OFFERS_ME; }
int fpm_model_offers_jacobian(void) { return FPM_OFFERS_JACOBIAN; }

/* The sensors' values and first and second derivatives now (sensors() layout: x_o, phi_o,
 * omega_o, then their rates, then their second derivatives): after a doStep, the polynomial that
 * step used (the inputs and input derivatives at its start) evaluated at its end; otherwise
 * (after initialisation, after an input derivative was set since the last doStep, and always in
 * Model Exchange, which takes no doStep) the inputs set now with the input derivatives set now
 * (0 in Model Exchange). "A step was taken" is the flag stepped, set by a successful doStep,
 * cleared by initialisation and by fmi2SetRealInputDerivatives, saved with FMU states. 1 if all
 * are finite. */
static int input_now(const fpm_model *m, double *y)
{
    int k, ok = 1;
    if (m->stepped) {
        const double h = m->step_h;
        for (k = 0; k < 3; k++) {
            const double y0 = m->step_y[k], y1 = m->step_y[3 + k], y2 = m->step_y[6 + k];
            y[k] = y0 + h * (y1 + 0.5 * h * y2);
            y[3 + k] = y1 + h * y2;
            y[6 + k] = y2;
        }
    } else {
        ok = sensors(m, y);
    }
    for (k = 0; k < 9; k++) ok = ok && isfinite(y[k]);
    return ok;
}

static int ready_now(const fpm_model *m, const fpm_logger *lg, const char *what, double *e)
{
    double y[9];
    if (!m->initialized) {
        fpm_log(lg, FPM_ERROR, "%s: the model is not initialised", what);
        return 0;
    }
    if (!input_now(m, y)) {
        char bad[256];
        name_bad(y, bad, sizeof bad);
        fpm_log(lg, FPM_ERROR, "%s: non-finite input at t = %.17g: %s", what, m->t, bad);
        return 0;
    }
    fpf_error(&m->f, y, e);
    return 1;
}

int fpm_model_jacobian(fpm_model *m, const fpm_logger *lg, double *A, double *B, double *C,
                       double *D)
{
    double e[3], a[4], b[6], c[2], d[3];
    int n = m->f.order, i, j, k = 0, nu = 0, ny = 0;
    unsigned vr;
    if (!ready_now(m, lg, "the linearisation", e)) return FPM_ERROR;
    if (fpf_linearize(&m->f, m->xc, e[0], a, b, c, d) != FPF_OK) {
        fpm_log(lg, FPM_ERROR, "the linearisation is not finite at t = %.17g (filter state %g, "
                "%g; error signal %g)", m->t, m->xc[0], m->xc[1], e[0]);
        return FPM_ERROR;
    }
    for (vr = 0; vr < FPM_MAX_VARS; vr++)
        if (fpm_vars[vr].name != NULL) {
            nu += fpm_vars[vr].causality == FPM_INPUT;
            ny += fpm_vars[vr].causality == FPM_OUTPUT;
        }
    if (A != NULL) {
        for (i = 0; i < JAC_NX * JAC_NX; i++) A[i] = 0.0;
        for (i = 0; i < n; i++)
            for (j = 0; j < n; j++) A[i * JAC_NX + j] = a[i * n + j];
    }
    if (B != NULL) for (i = 0; i < JAC_NX * nu; i++) B[i] = 0.0;
    if (C != NULL) for (i = 0; i < ny * JAC_NX; i++) C[i] = 0.0;
    if (D != NULL) for (i = 0; i < ny * nu; i++) D[i] = 0.0;
    /* the inputs, each at its column of fpf_linearize (phi_o 0, omega_o 1, x_o 2) */
    for (vr = 0; vr < FPM_MAX_VARS; vr++)
        if (fpm_vars[vr].name != NULL && fpm_vars[vr].causality == FPM_INPUT) {
            const int col = vr == VR_phi_o ? 0 : vr == VR_omega_o ? 1 : vr == VR_x_o ? 2 : -1;
            if (col >= 0) {
                if (B != NULL)
                    for (i = 0; i < n; i++) B[i * nu + k] = b[i * 3 + col];
                if (D != NULL) D[k] = d[col];     /* F_c: the only output (row 0) */
            }
            k++;
        }
    if (C != NULL)
        for (j = 0; j < n; j++) C[j] = c[j];
    for (i = 0; i < n * n + 3 * n + n + 3; i++) {
        const double v = i < n * n ? a[i] : i < n * n + 3 * n ? b[i - n * n]
                         : i < n * n + 4 * n ? c[i - n * n - 3 * n] : d[i - n * n - 4 * n];
        if (!isfinite(v)) {
            fpm_log(lg, FPM_ERROR, "the linearisation is not finite at t = %.17g (filter "
                    "state %g, %g)", m->t, m->xc[0], m->xc[1]);
            return FPM_ERROR;
        }
    }
    return FPM_OK;
}

int fpm_model_output_derivatives(fpm_model *m, const fpm_logger *lg, size_t n,
                                 const unsigned vr[], const int order[], double values[])
{
    double e[3], d[4];
    int have = 0;
    size_t i;
    for (i = 0; i < n; i++) {
        if (vr[i] != VR_F_c) {
            fpm_log(lg, FPM_ERROR, "value reference %u is not an output", vr[i]);
            return FPM_ERROR;
        }
        if (order[i] < 1 || order[i] > FPM_OUTPUT_DERIVATIVE_ORDER) {
            fpm_log(lg, FPM_ERROR, "the derivative of order %d of F_c: orders 1 to %d only",
                    order[i], FPM_OUTPUT_DERIVATIVE_ORDER);
            return FPM_ERROR;
        }
        if (!have) {                  /* every order at once, for the whole request */
            if (!ready_now(m, lg, "the output derivatives", e)) return FPM_ERROR;
            if (fpf_output_derivatives(&m->f, m->xc, e, d) != FPF_OK) {
                fpm_log(lg, FPM_ERROR, "the derivative of order %d of F_c is not finite at t = "
                        "%.17g (filter state %g, %g; error signal %g, rates %g, %g)", order[i],
                        m->t, m->xc[0], m->xc[1], e[0], e[1], e[2]);
                return FPM_ERROR;
            }
            have = 1;
        }
        values[i] = d[order[i] - 1];
    }
    return FPM_OK;
}
/* ================================================================== end of Jacobians and output
 * derivatives */

/* ================================================================== clocks (issue 38; fpm.h)
 * PDLowPassSampled's FMI 3.0 clocks, run in co-simulation with event mode (docs/fmus.md):
 * sample_clock (0) ticks at t0 + k T and samples the inputs set in that event mode, with the
 * arithmetic of a tick taken inside doStep (take_sample); force_clock (1) ticks at
 * t0 + tau + k T, where the force of the sample tau before takes over (F_c). With no delay the
 * two coincide and the force takes over at the sample; with delay = sample_period the force due
 * at a tick takes over before the tick's sample, whichever clock the importer activates first.
 * An instance without event mode (eventModeUsed = false) takes both inside doStep, as before. */
#if FPM_N_CLOCKS > 0
#if !FPM_SAMPLED || FPM_N_CLOCKS != 2
#error "the controller's clocks are the sampled controller's two"
#endif
static const unsigned CLOCK_VRS[2] = {VR_sample_clock, VR_force_clock};
static const char *const CLOCK_NAMES[2] = {"sample_clock", "force_clock"};

int fpm_model_n_clocks(void) { return FPM_N_CLOCKS; }

int fpm_model_clock_of(unsigned vr)
{
    int i;
    for (i = 0; i < FPM_N_CLOCKS; i++)
        if (vr == CLOCK_VRS[i]) return i;
    return -1;
}

void fpm_model_use_clocks(fpm_model *m, int on)
{
    if (!on) m->active[0] = m->active[1] = 0;
    m->clocked = on ? 1 : 0;
}

int fpm_model_clock_timing(fpm_model *m, const fpm_logger *lg, const char *fn, int clock,
                           double *interval, double *shift)
{
    const double T = m->v.real[VR_sample_period], tau = m->v.real[VR_delay];
    if (!(T > 0.0 && T <= 1e3 && tau >= 0.0 && tau <= T)) {
        fpm_log(lg, FPM_ERROR, "%s: %s has no interval: sample_period = %.17g, delay = %.17g "
                "(allowed: 0 < sample_period <= 1000 s, 0 <= delay <= sample_period)", fn,
                CLOCK_NAMES[clock], T, tau);
        return FPM_ERROR;
    }
    *interval = T;
    *shift = clock == 1 ? tau : 0.0;
    return FPM_OK;
}

int fpm_model_set_clock(fpm_model *m, const fpm_logger *lg, const char *fn, int clock,
                        int active, int apply)
{
    const double tol = TICK_TOLERANCE * m->T;
    if (!active) {
        if (m->active[clock])
            fpm_log(lg, FPM_ERROR, "%s: %s cannot be deactivated (canBeDeactivated = false)",
                    fn, CLOCK_NAMES[clock]);
        return m->active[clock] ? FPM_ERROR : FPM_OK;
    }
    if (!m->initialized) {
        fpm_log(lg, FPM_ERROR, "%s: %s was not initialised", fn, fpm_model_name);
        return FPM_ERROR;
    }
    if (clock == 0 && !(fabs(m->t - tick_at(m, m->k)) <= tol)) {
        fpm_log(lg, FPM_ERROR, "%s: sample_clock ticks at t = %.17g next (every sample_period "
                "= %.17g s from the start %.17g, each tick once), not at t = %.17g", fn,
                tick_at(m, m->k), m->T, m->t0, m->t);
        return FPM_ERROR;
    }
    if (clock == 1) {
        const double j = floor((m->t - m->t0 - m->tau) / m->T + 0.5);
        if (!(j >= 0.0 && fabs(m->t - (tick_at(m, j) + m->tau)) <= tol)) {
            fpm_log(lg, FPM_ERROR, "%s: force_clock ticks at t0 + delay + k sample_period "
                    "(t0 = %.17g, delay = %.17g s, sample_period = %.17g s), not at t = %.17g",
                    fn, m->t0, m->tau, m->T, m->t);
            return FPM_ERROR;
        }
    }
    if (apply) m->active[clock] = 1;
    return FPM_OK;
}

int fpm_model_get_clock(const fpm_model *m, int clock) { return m->active[clock]; }

int fpm_model_clock_update(fpm_model *m, const fpm_logger *lg)
{
    const double tol = TICK_TOLERANCE * m->T;
    double held = m->F, pend_F = m->pend_F, k = m->k, xf[2] = {m->xc[0], m->xc[1]};
    int pending = m->pending;
    if (!m->active[0] && !m->active[1]) return FPM_OK;
    /* the force due now takes over at force_clock, or at the latest before this tick's sample
     * (delay = sample_period: both at one instant) */
    if (pending && fabs(m->t - (tick_at(m, k - 1.0) + m->tau)) <= tol) {
        held = pend_F;
        pending = 0;
        pend_F = 0.0;
    }
    if (m->active[0]) {
        double u;
        int rc = take_sample(m, lg, FPM_ERROR, m->t, "the sample is not taken", &u, xf);
        if (rc != FPM_OK) return rc;
        k += 1.0;
        if (m->tau == 0.0) {                  /* no delay: the force takes over at its sample */
            held = u;
        } else {
            pending = 1;
            pend_F = u;
        }
    }
    m->k = k;
    m->xc[0] = xf[0];
    m->xc[1] = xf[1];
    m->F = held;
    m->pending = pending;
    m->pend_F = pend_F;
    m->active[0] = m->active[1] = 0;
    return FPM_OK;
}

int fpm_model_clocked_set(fpm_model *m, const fpm_logger *lg, const char *fn, int mode,
                          const unsigned vr[], size_t n)
{
    size_t i;
    int j;
    if (!m->clocked || vr == NULL || (mode & (FPM_INSTANTIATED | FPM_INIT)) || m->active[0])
        return FPM_OK;
    for (i = 0; i < n; i++)
        for (j = 0; j < 3; j++)
            if (vr[i] == SENSOR_VRS[j]) {
                fpm_log(lg, FPM_ERROR, "%s: %s is clocked by sample_clock: set it in event mode "
                        "while sample_clock is active (its next tick: t = %.17g); nothing was "
                        "set", fn, SENSOR_NAMES[j], tick_at(m, m->k));
                return FPM_ERROR;
            }
    return FPM_OK;
}
#endif
