/*
 * jacobian_hooks.c - a test host of the models' issue-24 hooks (fpm.h: fpm_model_nx,
 * fpm_model_jacobian, fpm_model_output_derivatives), before the FMI core calls them.
 *
 * Compiled by tests/common/test_jacobian.py with the model's source included (-DMODEL_C="...") so
 * that the host reads the model's state, with fpm_guard.c and the kernels, against the model's
 * generated fpm_vars.h. Usage:
 *
 *     jacobian_hooks H N name=value... [d1:name=value] [d2:name=value] [after:name=value]
 *
 * sets the parameters and inputs (real or string, by name) and input derivatives, initialises,
 * and prints one JSON object per line: "init" (after initialisation), "step" (after N doSteps of
 * H from 0), "restored" (a fresh model loaded from the state saved after the steps), "after" (the
 * stepped model after the "after:" inputs are set, without a step). Each line: the time, the
 * model's state (plant: y_acc, n; controller: xc, order), the linearisation's blocks A, B, C, D
 * and the first and second derivatives of every output in value-reference order.
 */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include MODEL_C

static void emit(void *env, int status, const char *category, const char *message)
{
    (void)env;
    fprintf(stderr, "[%d %s] %s\n", status, category, message);
}

static const fpm_logger LOG = {emit, NULL};

static int count(int causality)
{
    int vr, n = 0;
    for (vr = 0; vr < FPM_MAX_VARS; vr++) n += fpm_vars[vr].name && fpm_vars[vr].causality == causality;
    return n;
}

static void array(const char *name, const double *a, int n)
{
    int i;
    printf(", \"%s\": [", name);
    for (i = 0; i < n; i++) printf("%s%.17g", i ? ", " : "", a[i]);
    printf("]");
}

static void report(fpm_model *m, const char *what)
{
    static double A[64 * 64], B[64 * 8], C[64 * 64], D[64 * 8], d[2][64];
    const int nx = (int)fpm_model_nx(), nu = count(FPM_INPUT), ny = count(FPM_OUTPUT);
    int rc, vr, k = 0;
    rc = fpm_model_jacobian(m, &LOG, A, B, C, D);
    for (vr = 0; vr < FPM_MAX_VARS; vr++)
        if (fpm_vars[vr].name && fpm_vars[vr].causality == FPM_OUTPUT) {
            const unsigned v[2] = {(unsigned)vr, (unsigned)vr};
            const int order[2] = {1, 2};
            double both[2] = {0.0, 0.0};
            rc |= fpm_model_output_derivatives(m, &LOG, 2, v, order, both);
            d[0][k] = both[0];
            d[1][k] = both[1];
            k++;
        }
    printf("{\"what\": \"%s\", \"rc\": %d, \"t\": %.17g, \"nx\": %d, \"nu\": %d, \"ny\": %d", what,
           rc, fpm_model_time(m), nx, nu, ny);
#ifdef PLANT
    printf(", \"n\": %d", m->n);
    array("state", m->y_acc, m->nx);
#else
    printf(", \"n\": %d", m->f.order);
    array("state", m->xc, 2);
#endif
    array("A", A, nx * nx);
    array("B", B, nx * nu);
    array("C", C, ny * nx);
    array("D", D, ny * nu);
    array("d1", d[0], ny);
    array("d2", d[1], ny);
    printf("}\n");
}

static int set(fpm_model *m, const char *arg)
{
    const char *eq = strchr(arg, '='), *name = arg;
    char key[64];
    int order = 0, vr;
    if (strncmp(arg, "d1:", 3) == 0) order = 1;
    if (strncmp(arg, "d2:", 3) == 0) order = 2;
    if (order) name = arg + 3;
    if (eq == NULL || (size_t)(eq - name) >= sizeof key) return 0;
    memcpy(key, name, (size_t)(eq - name));
    key[eq - name] = '\0';
    for (vr = 0; vr < FPM_MAX_VARS; vr++)
        if (fpm_vars[vr].name && strcmp(fpm_vars[vr].name, key) == 0) break;
    if (vr == FPM_MAX_VARS) return 0;
    if (order) return fpm_model_set_input_derivative(m, &LOG, (unsigned)vr, order,
                                                     atof(eq + 1)) == FPM_OK;
    if (fpm_vars[vr].type == FPM_STRING)
        snprintf(fpm_model_values(m)->string[vr], FPM_STR_MAX, "%s", eq + 1);
    else
        fpm_model_values(m)->real[vr] = atof(eq + 1);
    return 1;
}

int main(int argc, char **argv)
{
    fpm_model *m = calloc(1, fpm_model_size()), *m2 = calloc(1, fpm_model_size());
    double h = atof(argv[1]), t = 0.0;
    long steps = atol(argv[2]), i;
    fpm_writer w = {NULL, 0, 0};
    fpm_reader r;
    int a;
    fpm_model_reset(m, 0.0);
    for (a = 3; a < argc; a++)
        if (strncmp(argv[a], "after:", 6) != 0 && !set(m, argv[a])) {
            fprintf(stderr, "bad argument %s\n", argv[a]);
            return 2;
        }
    if (fpm_model_init(m, &LOG) != FPM_OK) return 3;
    report(m, "init");
    for (i = 0; i < steps; i++, t += h)
        if (fpm_model_step(m, &LOG, t, h) != FPM_OK) return 4;
    report(m, "step");
    fpm_model_save(m, &w);                    /* count, then write */
    w.p = malloc(w.n);
    w.cap = w.n;
    w.n = 0;
    fpm_model_save(m, &w);
    memset(&r, 0, sizeof r);
    r.p = w.p;
    r.n = w.n;
    fpm_model_reset(m2, 0.0);
    memcpy(fpm_model_values(m2), fpm_model_values(m), sizeof(fpm_values));
    if (!fpm_model_load(m2, &r, 1, NULL) || r.pos != r.n) {
        fprintf(stderr, "restore failed: %s\n", r.why);
        return 5;
    }
    report(m2, "restored");
    for (a = 3; a < argc; a++)
        if (strncmp(argv[a], "after:", 6) == 0 && !set(m, argv[a] + 6)) return 2;
    report(m, "after");
    free(w.p);
    free(m);
    free(m2);
    return 0;
}
