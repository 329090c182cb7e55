"""What the terminal shows: the text of an analysis, a design, a run's summary and a sweep.

Each function returns lines (no trailing newline); the command line prints them. Numbers are
printed with the digits that mean something (:func:`num`).
"""
from __future__ import annotations

import math

from plant_fmu.params import damping_text

__all__ = ["num", "filter_text", "analysis_lines", "margin_lines", "mode_text", "validity_text",
           "figure_text", "sampled_lines", "sampled_margin_lines",
           "run_lines", "design_lines", "verdict_lines", "sweep_lines", "coupling_text",
           "stability_lines"]


def num(v, spec=".4g") -> str:
    """A number as text: ``spec`` digits, ``-`` for None or NaN, ``inf`` for infinity."""
    if v is None or (isinstance(v, float) and math.isnan(v)):
        return "-"
    if isinstance(v, float) and math.isinf(v):
        return "inf" if v > 0 else "-inf"
    return format(v, spec)


def filter_text(order, cutoff, damping) -> str:
    return {0: "none", 1: f"1st order, wc = {cutoff:g} rad/s",
            2: f"2nd order, wc = {cutoff:g} rad/s, zf = {damping:g}"}[order]


def analysis_lines(plant, controller, a) -> list[str]:
    """``flexpend analyze``: the loop, its closed-loop eigenvalues, the verdict and the margins
    (:class:`~orchestration.studies.analysis.Analysis`)."""
    p, c = plant, controller
    out = [f"plant: n_modes = {p.n_modes}, zeta = {p.zeta:g}, damping = {p.damping}, "
           f"gravity_preload = {str(p.gravity_preload).lower()}",
           "  linearised at the upright rest state: "
           + (a.loop or f"{p.n_modes} modes, {damping_text(p)}"),
           f"controller: kp = {c.kp:g}, kd = {c.kd:g}, kx = {c.kx:g}, filter: "
           f"{filter_text(c.filter_order, c.cutoff, c.filter_damping)}"]
    if a.cantilever_frequencies:
        out.append("cantilever frequencies (rad/s): "
                   + ", ".join(f"{w:.2f}" for w in a.cantilever_frequencies))
    out += ["", f"{'closed-loop eigenvalue':>30}  {'|lambda| rad/s':>14}  {'damping ratio':>13}"]
    for re, im, wn, zeta in a.modes():
        lam = f"{re:+.4f} {'+-' if im > 0 else '  '} {im:.4f}j" if im > 0 else f"{re:+.4f}"
        out.append(f"{lam:>30}  {wn:14.3f}  {num(zeta, '13.4f'):>13}")
    verdict = "STABLE" if a.stable else "UNSTABLE"
    note = " (cart drift roots at 0 left aside)" if c.kx == 0 else ""
    out += ["", f"max real part{note}: {a.max_real_part:+.4f}  ->  {verdict}"]
    out += margin_lines(a.margins)
    if getattr(a, "sampled", None) is not None:
        out += [""] + sampled_lines(a.sampled, c.kx == 0)
    return out


def sampled_lines(sp, drift: bool = False) -> list[str]:
    """The sampled controller's discrete-time loop (``flexpend analyze`` of a scene with
    ``controller.sample_period > 0``; :class:`~orchestration.studies.sampled.SampledPoles`): T,
    tau and the discretization, each pole ``z`` (one of a conjugate pair) beside its s-plane
    equivalent ``log(z) / T``, the spectral radius, the margin ``1 - max |z|`` and the verdict."""
    how = {"tustin": "tustin filter (prewarped at the cutoff)",
           "zoh": "zoh filter (its zero-order-hold equivalent)"}[sp.discretization]
    out = [f"sampled controller: T = {num(sp.T * 1e3)} ms, delay tau = {num(sp.tau * 1e3)} ms, "
           f"{how}",
           "  the plant's exact zero-order-hold discretisation; the lines above are the "
           "continuous controller's (T -> 0)",
           "",
           f"{'closed-loop pole z':>30}  {'|z|':>9}  {'s = log(z) / T (1/s)':>30}  "
           f"{'damping ratio':>13}"]
    for z, s in zip(sp.z, sp.s):
        if z.imag < 0:
            continue
        pm = "+-" if z.imag > 0 else "  "
        zt = f"{z.real:+.6f} {pm} {abs(z.imag):.6f}j" if z.imag > 0 else f"{z.real:+.6f}"
        if not math.isfinite(s.real):
            st, zeta = "-inf (z = 0)", float("nan")
        else:
            st = (f"{s.real:+.4f} {pm} {abs(s.imag):.4f}j" if z.imag > 0 else
                  f"{s.real:+.4f} + {s.imag:.4f}j" if s.imag != 0 else f"{s.real:+.4f}")
            wn = abs(s)
            zeta = -s.real / wn if wn > 0 else float("nan")
        out.append(f"{zt:>30}  {abs(z):9.6f}  {st:>30}  {num(zeta, '13.4f'):>13}")
    verdict = "STABLE" if sp.stable else "UNSTABLE"
    note = " (cart drift poles at z = 1 left aside)" if drift else ""
    rate = -math.log(sp.spectral_radius) / sp.T if sp.spectral_radius > 0 else math.inf
    out += ["", f"spectral radius max |z|{note}: {sp.spectral_radius:.6f}, margin 1 - max |z| = "
                f"{sp.margin:+.6f}  ->  {verdict} (stable iff max |z| < 1)",
            f"slowest decay rate -log(max |z|) / T = {num(rate, '+.4f')} 1/s (the continuous "
            "loop's: minus its max real part above)"]
    m = getattr(sp, "margins", None)
    if m is not None:
        out += sampled_margin_lines(m)
    return out


def sampled_margin_lines(m: dict) -> list[str]:
    """The sampled loop's margins (:func:`orchestration.studies.sampled.sampled_margins`)."""
    if not m["nominal_stable"]:
        return [f"margins of the sampled loop: {m['note']}"]
    lo, hi = m["gain_margin_lower"], m["gain_margin_upper"]
    gain = ("stable for loop-gain factors "
            + (f"from x{num(lo)} ({num(m['gain_margin_lower_db'], '+.3g')} dB) " if lo > 0
               else "above 0 ")
            + (f"to x{num(hi)} ({num(m['gain_margin_upper_db'], '+.3g')} dB)"
               if math.isfinite(hi) else "without an upper bound (up to x1000)"))
    out = [f"margins of the sampled loop (a pole on the unit circle): {gain}"]
    if m["phase_margin_deg"] is not None and math.isfinite(m["phase_margin_deg"]):
        delay = (f"; delay margin {num(m['delay_margin_s'] * 1e3)} ms"
                 if m["delay_margin_s"] is not None else "")
        out.append(f"  phase margin {num(m['phase_margin_deg'])} deg {m['phase_margin_sense']} "
                   f"(a pole at {num(m['phase_margin_freq'])} rad/s){delay}")
    elif m["note"]:
        out.append(f"  {m['note']}")
    return out


def margin_lines(m: dict) -> list[str]:
    """The margins of :func:`orchestration.studies.analysis.margins`, the same numbers and words
    as its JSON: the gain range, the phase margin (the smallest phase change at any gain
    crossover) with every crossover, the delay margin; for an unstable loop, the note instead."""
    cross = m["gain_crossovers"]

    def change(r):
        ph = r["phase_change_deg"]
        return f"{num(abs(ph))} deg {'lag' if ph >= 0 else 'lead'}"

    listed = "; ".join(f"{num(r['frequency'])} rad/s: {change(r)}" for r in cross)
    if not m["nominal_stable"]:
        return [m["note"]] + ([f"  gain crossovers (phase change that puts a root on the "
                               f"imaginary axis): {listed}"] if cross else [])

    def where(db, freq):
        return (f"{num(db, '+.3g')} dB, " + ("a real root through 0" if freq == 0 else
                                              f"roots at +-{num(freq)}j"))

    lo, hi = m["gain_margin_lower"], m["gain_margin_upper"]
    if lo == 0.0 and math.isinf(hi):
        gain = "gain margin: none needed, the loop is stable for every loop-gain factor > 0"
    elif lo == 0.0:
        gain = (f"gain margin: stable for loop-gain factors up to x{num(hi)} "
                f"({where(m['gain_margin_upper_db'], m['gain_margin_upper_freq'])})")
    elif math.isinf(hi):
        gain = (f"gain margin: stable for every loop-gain factor above x{num(lo)} "
                f"({where(m['gain_margin_lower_db'], m['gain_margin_lower_freq'])}); no gain "
                "increase destabilises it")
    else:
        gain = (f"gain margin: stable for loop-gain factors from x{num(lo)} "
                f"({where(m['gain_margin_lower_db'], m['gain_margin_lower_freq'])}) to "
                f"x{num(hi)} ({where(m['gain_margin_upper_db'], m['gain_margin_upper_freq'])})")
    out = [gain]
    if not cross:
        out.append(f"phase margin: inf ({m['note']})")
        return out
    pm = (f"phase margin: {num(m['phase_margin_deg'])} deg of {m['phase_margin_sense']} at "
          f"{num(m['phase_margin_freq'])} rad/s")
    if len(cross) == 1:
        out.append(pm + " (the only gain crossover)")
    else:
        out += [pm + f", the smallest phase change at any of the {len(cross)} gain crossovers "
                "that puts a closed-loop root on the imaginary axis:", f"  {listed}"]
    out.append(f"delay margin: {num(1e3 * m['delay_margin_s'])} ms (its lag reaches the phase "
               f"change at {num(m['delay_margin_freq'])} rad/s first)")
    return out


def mode_text(m) -> str:
    """One fitted mode, with the linear prediction beside it."""
    if m is None:
        return "-"
    lin = m.get("linear")
    lin_text = (f"   (linear: {lin['rate']:+.3f} +- {lin['frequency']:.2f}j)" if lin else "")
    if m["reliable"]:
        u = (m.get("fit") or {}).get("rate_uncertainty")
        unc = f" (+- {u:.2g})" if u is not None else ""
        weak = (": not counted, its uncertainty unknown" if u is None else
                ": not counted, its uncertainty exceeds its distance from zero"
                if not abs(m["rate"]) > u else "")
        return (f"rate {m['rate']:+.3f} 1/s{unc} at {m['frequency']:.2f} rad/s{weak}"
                f"{lin_text}")
    return f"{m['note']}{lin_text}"


def validity_text(v: dict) -> str:
    """The model-form error bound of a run's summary (``validity``) in one phrase."""
    if v.get("model_form_error") is None:
        return f"model-form error: not measured ({v.get('note') or 'no bound'})"
    at = "" if v["rung"].startswith("rigid") else f"{100 * v['deflection']:.2g} % deflection, "
    laws = v.get("damping")
    name = {"modal": "modal", "kelvin-voigt": "Kelvin-Voigt"}
    under = (f" ({name[laws['rungs']]} damping, against the exact beam's "
             f"{name[laws['exact']]})" if laws and not v["rung"].startswith("rigid") else "")
    return (f"model-form error <= {v['model_form_error']:.1e} rad ({100 * v['relative']:.2g} % "
            f"of max |phi_o|; measured bound for the {v['rung']} rung{under} at {at}"
            f"{v['rate']:.3g} rad/s)")


def figure_text(f: dict) -> str:
    """A run's error figure (the summary's ``error_figure``,
    :func:`orchestration.studies.error_figure.assess`) in one phrase: the figure, its share of
    the largest ``|phi_o|`` and what it compares with; or why there is none."""
    c = f["companion"]
    if f["figure"] is None:
        return f"error: no figure ({f['why']})"
    if c["own"]:
        how = f"the run is on its companion's model, {c['text']}: its own error, the floor"
    else:
        how = (f"{f['kappa']:.3g} x its difference {f['difference']:.1e} from its companion "
               f"run ({c['text']}) + the companion's own error {f['floor']:.1e}")
    return (f"error <= {f['figure']:.1e} rad ({100 * f['relative']:.2g} % of max |phi_o|) "
            f"against the exact beam: {how}")


def run_lines(name: str, s: dict, written=()) -> list[str]:
    """A run's summary (:func:`orchestration.studies.summary.summarize`) for the terminal."""
    if s["stopped"] is not None:
        verdict = f"STOPPED at t = {num(s['stopped']['time'], '.4g')} s"
    else:
        verdict = {"stable": "stable", "unstable": "UNSTABLE",
                   "undetermined": "undetermined"}.get(s.get("verdict"), "undetermined")
        if s.get("verdict") == "undetermined" and s.get("verdict_reason"):
            verdict += f" ({s['verdict_reason']})"
    out = [f"{name}: {verdict}"]
    if s["stopped"] is not None:
        out.append(f"  stopped: {s['stopped']['reason']}")
    if s.get("model"):
        m = s["model"]
        auto = " and ".join(k for k, on in (("plant.n_modes", m["n_modes_auto"]),
                                               ("plant.fidelity", m["fidelity_auto"])) if on)
        on = (f"on {', '.join(m['outputs'])}" if m["n_modes_auto"] else
              "of max |phi_o| for the error figure")
        out.append(f"  model: {m['n_modes']} modes, {m['fidelity']} ({auto} = auto, tolerance "
                   f"{100 * m['tolerance']:g} % {on})")
        out += [f"    {part}" for part in m["reason"].split("; ")]
    out.append(f"  slow (rigid) oscillation: {mode_text(s.get('slow'))}")
    out.append(f"  bending oscillation:      {mode_text(s.get('bending'))}")
    if s.get("other"):                  # a sampled loop's aliased or higher mode that grows
        out.append(f"  other oscillation:        {mode_text(s['other'])}")
    elif (s.get("verdict_modes") or {}).get("other"):
        out.append(f"  other oscillation:        {s['verdict_modes']['other']}")
    if s.get("linear_loop"):
        out.append(f"  linear: {s['linear_loop']}")
    if s.get("error_figure"):
        out.append(f"  {figure_text(s['error_figure'])}")
    v = s.get("validity")
    if v and v.get("max_abs_phi") is not None:
        beyond = (f"; WARNING, outside its measured range: {'; '.join(v['warnings'])}"
                  if v["warnings"] else "")
        out.append(f"  {'up to the stop, ' if s['stopped'] is not None else ''}"
                   f"{'global bound: ' if s.get('error_figure') else ''}{validity_text(v)}"
                   f"{beyond}")
    ne = s.get("numerical_error")
    if ne is not None:
        out.append("  numerical error: " + (
            f"<= {ne['phi_o']:.1e} rad ({ne['method']})" if ne["phi_o"] is not None else
            f"not estimated ({ne['note']})"))
    if s.get("max_abs_F_c") is not None:
        out.append(f"  max |F_c|: {s['max_abs_F_c']:.4g} N; max |x|: {s['max_abs_x']:.4g} m")
    if "wall_time" in s:
        loop = s.get("master_loop") or ""
        if loop.startswith("model-exchange"):
            out.append(f"  wall time: {s['wall_time']:.3g} s ({s['steps']} solver steps; "
                       f"{loop})")
        else:
            loop = f"; {loop} loop" if loop else ""
            out.append(f"  wall time: {s['wall_time']:.3g} s ({s['steps']} communication "
                       f"steps, {s['rejected_steps']} rejected{loop})")
        if "iterations_per_step_mean" in s:
            out.append(f"  interface iterations per step: mean {s['iterations_per_step_mean']:.3g}"
                       f", max {s['iterations_per_step_max']} (implicit master; "
                       f"{s['jacobian_steps']} FMU steps on difference Jacobians)")
    if "max_error_phi_o" in s:
        out.append(f"  max error against the monolithic reference: phi_o "
                   f"{s['max_error_phi_o']:.3e} rad, eta_1 {s['max_error_eta_1']:.3e} m kg^0.5")
    if written:
        out.append(f"  wrote {', '.join(str(w) for w in written)}")
    return out


def coupling_text(k: dict) -> str:
    """A coupling (``transition_matrix``'s keywords) in words."""
    alg = k["algorithm"] + (f" ({k['first']} first)" if k["algorithm"] == "gauss-seidel" else "")
    if k.get("coupling") == "hermite":
        return f"{alg}, Hermite (output derivatives)"
    if not k["extrapolation"]:
        how = "zero-order hold"
    else:
        how = f"extrapolation {k['extrapolation']}, " + (
            "input derivatives" if k["input_derivatives"] else "held average")
        how += ", output derivatives" if k["output_derivatives"] else ""
    return f"{alg}, {how}"


def _step_text(H) -> str:
    if H is None:
        return "stable up to 1 s"
    if H == 0:
        return "unstable at every step"
    return f"{num(H * 1e3)} ms"


def stability_lines(r: dict) -> list[str]:
    """``flexpend stability``: the scene's coupling, its largest stable communication step and
    the plant's substep limit; then every coupling the master offers, and the one allowing the
    largest step (:func:`orchestration.api.stability`)."""
    sc = r["scene"]
    k = sc["coupling"]
    h = sc["substep_limit"]
    lines = [f"{r['name']}: the linear co-simulation's largest stable communication step "
             "(rho(Phi) = 1)"]
    if r.get("loop"):
        lines.append(f"  plant: {r['loop']}")
    lines += [f"  assumes {a}" for a in r["assumes"]]
    lines += [f"  its coupling: {coupling_text(k)}, master.step = {num(k['step'] * 1e3)} ms",
              f"    largest stable step: {_step_text(sc['critical_step'])}",
              "    plant substep limit: " + ("none (A-stable)" if h is None else
                                             f"{num(h * 1e3)} ms")]
    rows = r["couplings"]
    w = max(len(coupling_text(c)) for c in rows)
    lines.append("  every coupling:")
    lines += [f"    {coupling_text(c):<{w}}  {_step_text(c['critical_step'])}" for c in rows]
    key = lambda c: math.inf if c["critical_step"] is None else c["critical_step"]  # noqa: E731
    best = max(rows, key=key)
    lines.append(f"  the largest step: {coupling_text(best)} ({_step_text(best['critical_step'])})")
    return lines


def design_lines(d) -> list[str]:
    """``flexpend design``'s report (a :class:`~orchestration.report.design.DesignReport`)."""
    r, c = d.result, d.controller
    uset = r.uncertainty.describe()
    crit = r.criterion

    def where(pl):
        return f"n_modes = {pl.n_modes}, zeta = {pl.zeta:g}, EI = {pl.EI:.4g}, m = {pl.m:.3g}"

    law = {"modal": "modal damping", "kelvin-voigt": "Kelvin-Voigt damping, zeta in mode 1"}[
        d.plant.damping]

    def root(z):
        return f"{z.real:+.4f} +- {abs(z.imag):.2f}j" if z.imag else f"{z.real:+.4f}"

    ch, wc_ = r.chosen, r.worst
    out = [f"robust low-pass design for the PD kp = {c.kp:g}, kd = {c.kd:g}, kx = {c.kx:g}",
           f"uncertainty: n_modes {uset['n_modes'][0]}..{uset['n_modes'][1]}, zeta "
           f"{uset['zeta'][0]:g}..{uset['zeta'][1]:g} ({law}), "
           f"EI {uset['EI'][0]:.4g}..{uset['EI'][1]:.4g}, "
           f"m {uset['m'][0]:.3g}..{uset['m'][1]:.3g}; searched on {r.levels} levels, checked on "
           f"{r.check_levels} levels ({wc_.n_plants} plants)",
           f"criterion: the smallest closed-loop "
           f"{'decay rate' if crit == 'decay' else 'damping ratio'} over the set, maximised",
           *([f"  of the sampled loop (T = {num(c.sample_period * 1e3)} ms, delay tau = "
              f"{num(c.delay * 1e3)} ms, {c.discretization} filter): its roots are the s-plane "
              "equivalents log(z) / T of its poles (decay rate -log(max |z|) / T)"]
             if c.sampled else []),
           "",
           f"chosen filter: {filter_text(ch.filter_order, ch.cutoff, ch.filter_damping)}",
           "  " + " ".join(f"--set {k}={v:g}" for k, v in r.filter_keys().items()),
           f"  worst-case decay rate {wc_.decay:+.4f} 1/s: root {root(wc_.decay_root)} at "
           f"{where(wc_.decay_plant)}",
           f"  worst-case damping ratio {wc_.damping:+.5f}: root {root(wc_.damping_root)} at "
           f"{where(wc_.damping_plant)}",
           f"  {'STABLE' if wc_.stable else 'UNSTABLE'} over the whole set",
           "",
           f"{'filter':<56}  {'worst decay 1/s':>15}  {'worst damping':>13}"]
    rows = [(f"best {o}{'st' if o == 1 else 'nd'} order", cc, ww)
            for o, (cc, ww) in r.per_order.items()]
    rows += [(k, cc, ww) for k, (cc, ww) in r.baseline.items()]
    for label, cc, ww in rows:
        text = f"{label}: {filter_text(cc.filter_order, cc.cutoff, cc.filter_damping)}"
        out.append(f"{text:<56}  {ww.decay:+15.4f}  {ww.damping:+13.5f}")
    if d.written:
        out += ["", "wrote " + ", ".join(str(w) for w in d.written)]
    return out


def verdict_lines(stats) -> list[str]:
    """A sweep's verdicts (:func:`orchestration.sweeps.engine.sweep_stats`): stable, unstable
    and undetermined apart, and, for the runs whose fits do not decide, what the linearised loop
    says instead."""
    finished = stats["ok"] + stats["failed"]
    if not finished or "stable" not in stats:      # no verdict asked for (--columns)
        return []
    share = stats["stable_fraction"]
    why = "; ".join(f"{n} {text}" for n, text in ((stats["no_fit"], "whose fits do not decide"),
                                                  (stats["failed"], "stopped early")) if n)
    out = [f"  verdicts of the {finished} finished run{'s' if finished != 1 else ''}: "
           f"{stats['stable']} stable"
           + (f" ({100 * share:.1f} % of those with a verdict)" if share is not None else "")
           + f", {stats['unstable']} unstable, {stats['undetermined']} undetermined"
           + (f" ({why})" if why else "")
           + (f"; {stats['invalid']} left their rung's measured range" if stats.get("invalid")
              else "")]
    n, k = stats["no_fit"], stats.get("no_fit_linear_stable")
    if n:
        runs = "the run" if n == 1 else f"the {n} runs"
        every = "" if n == 1 else " in both" if n == 2 else f" in all {n}"
        linear = "" if k is None else "; the linearised loop is " + (
            f"stable{every}" if k == n else f"unstable{every}" if k == 0 else
            f"stable in {k} of them, unstable in {n - k}")
        where = ": the table's verdict_reason" if "verdict_reason" in stats.get(
            "columns", ["verdict_reason"]) else ""
        out.append(f"  undetermined: {runs} whose fits do not decide (too short, too few "
                   f"periods in the linear range, or a rate within its uncertainty of zero"
                   f"{where}){linear}")
    return out


def sweep_lines(plan, res, stats, executor) -> list[str]:
    """A sweep's counts, verdicts and decay rates (:func:`orchestration.sweeps.engine.
    sweep_stats`)."""
    out = [f"{plan.scene.name}: {stats['runs']} runs: {stats['ok']} ok, {stats['failed']} failed"
           + (f", {stats['lost']} lost (their workers died; rerun the same command to retry "
              "them)" if stats["lost"] else "")
           + (f"; {res.ran} ran in {res.seconds:.1f} s on {executor.describe()}" if res.ran
              else "; 0 ran")
           + (f", {res.skipped} were already done" if res.skipped else "")]
    out += verdict_lines(stats)
    if "worst_decay_rate" in stats:
        worst = res.rows[stats["worst_run"]]
        where = ", ".join(f"{k} = {num(worst[k]) if isinstance(worst[k], float) else worst[k]}"
                          for k in plan.keys)
        out.append(f"  decay rate -max(fitted rate): worst {stats['worst_decay_rate']:+.4g} 1/s "
                   f"(run {stats['worst_run']}: {where}), median "
                   f"{stats['median_decay_rate']:+.4g}, best {stats['best_decay_rate']:+.4g}")
    if "worst_linear_decay_rate" in stats:
        out.append(f"  linearised loop over the same runs: worst decay rate "
                   f"{stats['worst_linear_decay_rate']:+.4g} 1/s (run "
                   f"{stats['worst_linear_run']})")
    for c, r in (stats.get("columns_range") or {}).items():     # the columns asked for
        def text(v):
            return str(v) if isinstance(v, int) else num(v)
        out.append(f"  {c}: smallest {text(r['min'])} (run {r['min_run']}), median "
                   f"{text(r['median'])}, largest {text(r['max'])} (run {r['max_run']}) over "
                   f"{r['runs']} runs")
    for c, f in (stats.get("columns_flags") or {}).items():
        out.append(f"  {c}: true in {f['true']} runs, false in {f['false']}")
    if "design_worst_case" in stats:
        w = stats["design_worst_case"]
        at = ", ".join(f"{k} = {num(v)}" for k, v in w["decay_rate_at"].items())
        out.append(f"  flexpend design's worst case over the uncertainty set (linear, "
                   f"{w['plants']} plants): {w['decay_rate']:+.4g} 1/s at {at}")
    failed = [r for r in res.rows if r["status"] != "ok"]
    out += [f"  run {r['run']} {r['status']}: {(r['message'] or '')[:160]}" for r in failed[:3]]
    if len(failed) > 3:
        out.append(f"  ... {len(failed) - 3} more (the table has every message)")
    out.append(f"  wrote {res.table}" + (f", {res.plot}" if res.plot else ""))
    return out
