/*
 * fpm_pending.c - TEMPORARY stubs of the models' Jacobian and output-derivative hooks of
 * issue 24 (fpm.h: fpm_model_nx, fpm_model_jacobian, fpm_model_output_derivative,
 * fpm_model_max_output_derivative_order), so that the Model-Exchange side builds and is tested
 * before the kernels' implementation lands. The lead removes this file (and its entry in
 * orchestration/export/native_fmus.py: CORE_SOURCES) when merging that implementation.
 */
#include "fpm.h"

/* The number of states the table declares (fpm_var.state), as the models will give it. */
size_t fpm_model_nx(void)
{
    size_t i, n = 0;
    for (i = 0; i < FPM_MAX_VARS; i++)
        if (fpm_vars[i].name != NULL && fpm_vars[i].state) n++;
    return n;
}

int fpm_model_jacobian(fpm_model *m, const fpm_logger *lg, double *A, double *B, double *C,
                       double *D)
{
    (void)m; (void)A; (void)B; (void)C; (void)D;
    fpm_log(lg, FPM_ERROR, "not yet: the exact linearisation of %s is pending (issue 24)",
            fpm_model_name);
    return FPM_ERROR;
}

int fpm_model_output_derivative(fpm_model *m, const fpm_logger *lg, unsigned vr, int order,
                                double *value)
{
    (void)m; (void)vr; (void)order; (void)value;
    fpm_log(lg, FPM_ERROR, "not yet: the output derivatives of %s are pending (issue 24)",
            fpm_model_name);
    return FPM_ERROR;
}

int fpm_model_max_output_derivative_order(void) { return 2; }
