//! rust_host - the closed loop of `tests/native/fmi2_host.c`, run by a Rust importer: the `fmi`
//! crate (crates.io, pinned in Cargo.toml) unpacks both FMI 2.0 FMUs, parses their model
//! descriptions, loads their binaries and instantiates them for co-simulation; this program only
//! calls the crate's instance API. The loop is the C host's: Jacobi coupling with held inputs
//! (every FMU gets its sources' outputs of the last communication point, then both step), and one
//! line per step: t x_o phi_o omega_o F_c, 17 significant digits each. Used by
//! tests/export/test_fmu_rust_host.py.
//!
//! usage: rust_host PLANT_FMU CTRL_FMU STEPS H [PLANT_PARAM=VALUE ...] [bench]
//!        rust_host --misuse PLANT_FMU
//!
//! The variables are found by name in the model descriptions the crate parsed (the C host is
//! given their value references instead): the plant's input F_c and outputs x_o, phi_o, omega_o,
//! the controller's inputs x_o, phi_o, omega_o and output F_c. `bench` prints the time per macro
//! step instead of the trajectory. `--misuse` calls fmi2DoStep before initialisation: the FMU
//! refuses it and logs why, through the crate's logger callback, which this program prints to
//! stderr as `log INSTANCE [LEVEL] MESSAGE`.
//!
//! Exit status as the C host's: 2 usage, 3 load, 4 instantiate, 5 setup, 6 parameter,
//! 7 initialisation, 8 first outputs, 9 set inputs, 10 step, 11 get outputs; and 12 terminate
//! (which the C host does not check).
use std::process::ExitCode;
use std::time::Instant;

use fmi::fmi2::import::Fmi2Import;
use fmi::fmi2::instance::{CoSimulation, Common, InstanceCS};
use fmi::traits::FmiImport;

/// Prints the records the crate's logger callback makes of the FMUs' messages.
struct StderrLogger;

impl log::Log for StderrLogger {
    fn enabled(&self, _: &log::Metadata) -> bool {
        true
    }

    fn log(&self, record: &log::Record) {
        // the crate's own messages (unpacking, loading) are debug and trace records
        if record.level() <= log::Level::Info {
            eprintln!("log {} [{}] {}", record.target(), record.level(), record.args());
        }
    }

    fn flush(&self) {}
}

static LOGGER: StderrLogger = StderrLogger;

fn vr(import: &Fmi2Import, name: &str) -> Result<u32, String> {
    import
        .model_description()
        .model_variable_by_name(name)
        .map(|v| v.value_reference)
        .map_err(|e| format!("{}: {e}", import.model_description().model_name))
}

fn load(path: &str) -> Result<Fmi2Import, ExitCode> {
    fmi::import::from_path::<Fmi2Import>(path).map_err(|e| {
        eprintln!("cannot import {path}: {e}");
        ExitCode::from(3)
    })
}

fn instantiate(import: &Fmi2Import, name: &str) -> Result<InstanceCS, ExitCode> {
    // visible = false, loggingOn = false: the C host's arguments
    import.instantiate_cs(name, false, false).map_err(|e| {
        eprintln!("fmi2Instantiate {name}: {e}");
        ExitCode::from(4)
    })
}

fn fail<E: std::fmt::Debug>(code: u8, what: &str) -> impl FnOnce(E) -> ExitCode + '_ {
    move |e| {
        eprintln!("{what}: {e:?}");
        ExitCode::from(code)
    }
}

fn misuse(path: &str) -> Result<(), ExitCode> {
    let import = load(path)?;
    let inst = instantiate(&import, "plant")?;
    let status = inst.do_step(0.0, 1e-3, true);
    println!("fmi2DoStep before initialisation: {status:?}");
    Ok(())
}

fn closed_loop(args: &[String]) -> Result<(), ExitCode> {
    let mut args = args.to_vec();
    let bench = args.last().map(|a| a == "bench").unwrap_or(false);
    if bench {
        args.pop();
    }
    if args.len() < 4 {
        eprintln!("usage: rust_host PLANT_FMU CTRL_FMU STEPS H [PLANT_PARAM=VALUE ...] [bench]");
        return Err(ExitCode::from(2));
    }
    let steps: u64 = args[2].parse().map_err(fail(2, "STEPS"))?;
    let h: f64 = args[3].parse().map_err(fail(2, "H"))?;
    // the imports own the unpacked folders: declared first, dropped after the instances
    let plant_fmu = load(&args[0])?;
    let ctrl_fmu = load(&args[1])?;
    let lookup = |import: &Fmi2Import, names: &[&str]| -> Result<Vec<u32>, ExitCode> {
        names.iter().map(|n| vr(import, n)).collect::<Result<_, _>>().map_err(fail(3, "variable"))
    };
    let sensors = ["x_o", "phi_o", "omega_o"];
    let pin = lookup(&plant_fmu, &["F_c"])?;
    let pout = lookup(&plant_fmu, &sensors)?;
    let cin = lookup(&ctrl_fmu, &sensors)?;
    let cout = lookup(&ctrl_fmu, &["F_c"])?;
    let mut params = Vec::new();
    for a in &args[4..] {
        let (name, value) = a.split_once('=').ok_or(ExitCode::from(2))?;
        let value: f64 = value.parse().map_err(fail(2, "parameter value"))?;
        params.push((lookup(&plant_fmu, &[name])?[0], value));
    }

    let mut p = instantiate(&plant_fmu, "plant")?;
    let mut c = instantiate(&ctrl_fmu, "controller")?;
    // no tolerance, start 0, no stop time: fmi2SetupExperiment(c, false, 0, 0, false, 0)
    Common::setup_experiment(&mut p, None, 0.0, None).map_err(fail(5, "setup plant"))?;
    Common::setup_experiment(&mut c, None, 0.0, None).map_err(fail(5, "setup controller"))?;
    for (vr, value) in &params {
        p.set_real(&[*vr], &[*value]).map_err(fail(6, "plant parameter"))?;
    }
    Common::enter_initialization_mode(&mut p).map_err(fail(7, "plant initialisation"))?;
    Common::exit_initialization_mode(&mut p).map_err(fail(7, "plant initialisation"))?;
    Common::enter_initialization_mode(&mut c).map_err(fail(7, "controller initialisation"))?;
    Common::exit_initialization_mode(&mut c).map_err(fail(7, "controller initialisation"))?;

    let mut y = [0.0f64; 3];
    let mut f = [0.0f64; 1];
    p.get_real(&pout, &mut y).map_err(fail(8, "plant outputs"))?;
    c.get_real(&cout, &mut f).map_err(fail(8, "controller output"))?;
    let mut out = String::with_capacity(if bench { 0 } else { 120 * steps as usize });
    let t0 = Instant::now();
    for k in 0..steps {
        let t = k as f64 * h;
        c.set_real(&cin, &y).map_err(fail(9, "controller inputs"))?;
        p.set_real(&pin, &f).map_err(fail(9, "plant input"))?;
        p.do_step(t, h, true).map_err(fail(10, "plant step"))?;
        c.do_step(t, h, true).map_err(fail(10, "controller step"))?;
        p.get_real(&pout, &mut y).map_err(fail(11, "plant outputs"))?;
        c.get_real(&cout, &mut f).map_err(fail(11, "controller output"))?;
        if !bench {
            // {:.16e}: 17 significant digits, correctly rounded (C's %.17g, written as 1.2e-3)
            out.push_str(&format!(
                "{:.16e} {:.16e} {:.16e} {:.16e} {:.16e}\n",
                (k + 1) as f64 * h,
                y[0],
                y[1],
                y[2],
                f[0]
            ));
        }
    }
    let elapsed = t0.elapsed().as_secs_f64();
    if bench {
        println!("{:.6e}", elapsed / steps as f64);
    } else {
        print!("{out}");
    }
    Common::terminate(&mut p).map_err(fail(12, "plant terminate"))?;
    Common::terminate(&mut c).map_err(fail(12, "controller terminate"))?;
    Ok(()) // the instances drop here (fmi2FreeInstance), then the imports
}

fn main() -> ExitCode {
    log::set_logger(&LOGGER).expect("one logger");
    log::set_max_level(log::LevelFilter::Trace);
    let args: Vec<String> = std::env::args().skip(1).collect();
    let res = if args.first().map(|a| a == "--misuse").unwrap_or(false) && args.len() == 2 {
        misuse(&args[1])
    } else {
        closed_loop(&args)
    };
    match res {
        Ok(()) => ExitCode::SUCCESS,
        Err(code) => code,
    }
}
