// The native plant as a Model-Exchange FMU in a JVM, through FMI4j's Model-Exchange import (JNI):
// FMI4j 0.38.0 has the Model-Exchange instance API but no solver of its own (its Apache Commons
// Math solvers went with 0.x's stepper), so this host integrates with classical Runge-Kutta.
//
//   java MeLoop PLANT.fmu H STEPS EVERY VRout [R:VR=VALUE|I:VR=VALUE ...]
//
// prints "t out x_0 .. x_nx-1" at t = 0 and every EVERY steps, then "nominals ..." ; exit status 9
// when a call fails, 8 when the FMU asks to terminate.
import java.io.File;
import no.ntnu.ihb.fmi4j.FmiStatus;
import no.ntnu.ihb.fmi4j.importer.fmi2.Fmu;
import no.ntnu.ihb.fmi4j.importer.fmi2.ModelExchangeInstance;

public class MeLoop {
    static ModelExchangeInstance m;
    static int nx;

    static void ok(FmiStatus s) {
        if (s != FmiStatus.OK) {
            System.err.println("status " + s);
            System.exit(9);
        }
    }

    static double[] f(double t, double[] x) {
        double[] dx = new double[nx];
        ok(m.setTime(t));
        ok(m.setContinuousStates(x));
        ok(m.getDerivatives(dx));
        return dx;
    }

    static double[] axpy(double[] x, double h, double[] k) {
        double[] y = new double[x.length];
        for (int i = 0; i < x.length; ++i) y[i] = x[i] + h * k[i];
        return y;
    }

    public static void main(String[] a) throws Exception {
        Fmu fmu = Fmu.from(new File(a[0]));
        double h = Double.parseDouble(a[1]);
        long steps = Long.parseLong(a[2]), every = Long.parseLong(a[3]);
        long[] out = {Long.parseLong(a[4])};
        m = fmu.asModelExchangeFmu().newInstance("plant");
        nx = m.getModelDescription().getNumberOfContinuousStates();
        if (!m.setupExperiment(0.0, 0.0, 0.0)) System.exit(9);
        for (int i = 5; i < a.length; ++i) {
            long[] vr = {Long.parseLong(a[i].substring(2, a[i].indexOf('=')))};
            String v = a[i].substring(a[i].indexOf('=') + 1);
            if (a[i].charAt(0) == 'I') ok(m.writeInteger(vr, new int[] {Integer.parseInt(v)}));
            else ok(m.writeReal(vr, new double[] {Double.parseDouble(v)}));
        }
        if (!m.enterInitializationMode() || !m.exitInitializationMode()) System.exit(9);
        ok(m.newDiscreteStates());
        ok(m.enterContinuousTimeMode());
        double[] x = new double[nx], y = new double[1];
        ok(m.getContinuousStates(x));
        StringBuilder s = new StringBuilder();
        double t = 0.0;
        for (long i = 0; i <= steps; ++i) {
            if (i % every == 0) {
                ok(m.readReal(out, y));
                s.append(t).append(' ').append(y[0]);
                for (double v : x) s.append(' ').append(v);
                s.append('\n');
            }
            if (i == steps) break;
            double[] k1 = f(t, x), k2 = f(t + h / 2, axpy(x, h / 2, k1));
            double[] k3 = f(t + h / 2, axpy(x, h / 2, k2)), k4 = f(t + h, axpy(x, h, k3));
            for (int j = 0; j < nx; ++j) x[j] += h / 6 * (k1[j] + 2 * k2[j] + 2 * k3[j] + k4[j]);
            t = (i + 1) * h;
            ok(m.setTime(t));
            ok(m.setContinuousStates(x));
            if (m.completedIntegratorStep().getTerminateSimulation()) System.exit(8);
        }
        double[] nom = new double[nx];
        ok(m.getNominalsOfContinuousStates(nom));
        s.append("nominals");
        for (double v : nom) s.append(' ').append(v);
        s.append('\n');
        System.out.print(s);
        m.terminate();
        m.close();
        fmu.close();
    }
}
