// The closed loop of tests/c_host/fmi2_host.c in a JVM, with FMI4j (JNI): Gauss-Seidel, controller
// first, inputs held, the controller's inputs set again before its output is read.
//
//   java Loop H STEPS EVERY PLANT.fmu CTRL.fmu VRx VRphi VRomega VRFin VRcx VRcphi VRcomega VRFout
//        [p|c:R|I|B|S:VR=VALUE ...]
//
// prints "t x_o phi_o omega_o F_c" at t = 0 and every EVERY steps; exit status 5 when an instance
// could not be made. A Boolean start value false is not written: FMI4j 0.38.0's writeBoolean(false)
// arrives in the FMU as true (its boolean array is passed where fmi2Boolean, an int, is expected);
// false is every Boolean's default here.
import java.io.File;
import no.ntnu.ihb.fmi4j.importer.fmi2.CoSimulationSlave;
import no.ntnu.ihb.fmi4j.importer.fmi2.Fmu;

public class Loop {
    public static void main(String[] a) throws Exception {
        double h = Double.parseDouble(a[0]);
        long steps = Long.parseLong(a[1]), every = Long.parseLong(a[2]);
        Fmu pf = Fmu.from(new File(a[3])), cf = Fmu.from(new File(a[4]));
        CoSimulationSlave p = pf.asCoSimulationFmu().newInstance("plant");
        CoSimulationSlave c = cf.asCoSimulationFmu().newInstance("controller");
        long[] pout = {Long.parseLong(a[5]), Long.parseLong(a[6]), Long.parseLong(a[7])};
        long[] pin = {Long.parseLong(a[8])};
        long[] cin = {Long.parseLong(a[9]), Long.parseLong(a[10]), Long.parseLong(a[11])};
        long[] cout = {Long.parseLong(a[12])};
        if (!p.setupExperiment(0.0, 0.0, 0.0) || !c.setupExperiment(0.0, 0.0, 0.0)) {
            System.err.println("no instance (setupExperiment failed)");
            System.exit(5);
        }
        for (int i = 13; i < a.length; ++i) {
            CoSimulationSlave s = a[i].charAt(0) == 'p' ? p : c;
            char type = a[i].charAt(2);
            long[] vr = {Long.parseLong(a[i].substring(4, a[i].indexOf('=')))};
            String v = a[i].substring(a[i].indexOf('=') + 1);
            if (type == 'R') {
                double x = v.equals("inf") ? Double.POSITIVE_INFINITY
                         : v.equals("-inf") ? Double.NEGATIVE_INFINITY : Double.parseDouble(v);
                s.writeReal(vr, new double[] {x});
            } else if (type == 'I') {
                s.writeInteger(vr, new int[] {Integer.parseInt(v)});
            } else if (type == 'B') {
                if (!v.equals("0")) s.writeBoolean(vr, new boolean[] {true});
            } else {
                s.writeString(vr, new String[] {v});
            }
        }
        p.enterInitializationMode();
        c.enterInitializationMode();
        p.exitInitializationMode();
        c.exitInitializationMode();
        double[] y = new double[3], f = new double[1];
        p.readReal(pout, y);
        for (int k = 0; k < 2; ++k) {
            c.writeReal(cin, y);
            c.readReal(cout, f);
            p.writeReal(pin, f);
            p.readReal(pout, y);
        }
        StringBuilder out = new StringBuilder();
        out.append(0.0 + " " + y[0] + " " + y[1] + " " + y[2] + " " + f[0] + "\n");
        for (long i = 0; i < steps; ++i) {
            double ta = i * h, tb = (i + 1) * h;
            c.writeReal(cin, y);
            if (!c.doStep(ta, h)) System.exit(9);
            c.writeReal(cin, y);
            c.readReal(cout, f);
            p.writeReal(pin, f);
            if (!p.doStep(ta, h)) System.exit(9);
            p.readReal(pout, y);
            if ((i + 1) % every == 0) out.append(tb + " " + y[0] + " " + y[1] + " " + y[2] + " " + f[0] + "\n");
        }
        System.out.print(out);
        p.terminate();
        c.terminate();
        p.close();
        c.close();
        pf.close();
        cf.close();
    }
}
