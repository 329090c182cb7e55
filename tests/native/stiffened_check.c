/* stiffened_check.c - the stiffened rung of the plant kernel (fp_plant.c, rhs_stiffened) driven
 * under the sanitizers by tests/plant/test_stiffened.py.
 *
 * Reads from the file argv[1]: n, npts, then I0 I1 I2 g, I3, I5, K, D, tip_slope, tip_defl (n
 * each), Kg (n x n), the points (npts x (2 + n + n^2)), then a state (2 (n + 2)) and a force.
 * Prints the rhs and the energy at that state, the status of the refused Jacobian, and the state
 * after 40 RK4 substeps of 0.25 ms, one number a line (%.17g), for the test to compare with numpy.
 */
#include <stdio.h>
#include <stdlib.h>

#include "fp_plant.h"

static double *read_n(FILE *f, long n)
{
    double *a = malloc((size_t)(n > 0 ? n : 1) * sizeof *a);
    long i;
    for (i = 0; i < n; i++)
        if (fscanf(f, "%lf", &a[i]) != 1) exit(3);
    return a;
}

int main(int argc, char **argv)
{
    fp_plant p = {0};
    FILE *f;
    int n, npts, i, nx;
    double *I3, *I5, *K, *D, *ts, *td, *Kg, *pts, *x, *dx, *J, *b, *work, *jwork, u;
    long done = 0;
    if (argc != 2 || (f = fopen(argv[1], "r")) == NULL) return 2;
    if (fscanf(f, "%d %d %lf %lf %lf %lf", &n, &npts, &p.I0, &p.I1, &p.I2, &p.g) != 6) return 3;
    I3 = read_n(f, n); I5 = read_n(f, n); K = read_n(f, n); D = read_n(f, n);
    ts = read_n(f, n); td = read_n(f, n); Kg = read_n(f, (long)n * n);
    pts = read_n(f, (long)npts * (2 + n + n * n));
    p.n = n; p.preload = n > 0; p.stiffened = 1; p.npts = npts;
    p.I3 = I3; p.I5 = I5; p.K = K; p.D = D; p.tip_slope = ts; p.tip_defl = td; p.Kg = Kg;
    p.pts = pts;
    if (fp_plant_prepare(&p) != FP_OK) return 4;
    nx = p.nx;
    x = read_n(f, nx);
    if (fscanf(f, "%lf", &u) != 1) return 3;
    fclose(f);
    dx = malloc((size_t)nx * sizeof *dx);
    J = malloc((size_t)nx * nx * sizeof *J);
    b = malloc((size_t)nx * sizeof *b);
    jwork = malloc((size_t)fp_jacobian_work_size(&p) * sizeof *jwork);
    work = malloc((size_t)fp_work_size(&p, 4) * sizeof *work);
    fp_rhs(&p, x, u, dx);
    for (i = 0; i < nx; i++) printf("%.17g\n", dx[i]);
    printf("%.17g\n", fp_energy(&p, x));
    printf("%d\n", fp_jacobian(&p, x, u, J, b, jwork));
    {
        fp_input in = {0};
        in.u0 = u;
        if (fp_fixed_steps(&p, FP_RK4, fp_builtin_tableau(FP_RK4), &in, 0.0, 2.5e-4, 40, x, work,
                           &done) != FP_OK || done != 40)
            return 5;
    }
    for (i = 0; i < nx; i++) printf("%.17g\n", x[i]);
    free(I3); free(I5); free(K); free(D); free(ts); free(td); free(Kg); free(pts);
    free(x); free(dx); free(J); free(b); free(jwork); free(work);
    return 0;
}
