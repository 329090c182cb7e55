"""A scene's typed records: what to run, validated once when the scene is read.

A :class:`Scene` is a name, a description, the wiring and six frozen records:

========== ======================= ===========================================================
record     class                   scene keys
========== ======================= ===========================================================
plant      :class:`PlantSetup`     ``plant.*``: the physical plant (:class:`PlantParams`), the
                                   model's fidelity and the plant FMU's solver settings
controller :class:`ControllerParams` ``controller.*``: the PD and the low-pass filter
master     :class:`MasterSettings` ``master.*``: the coupling and the FMUs it runs
initial    :class:`InitialState`   ``initial.*``: the initial angle, position and rates
fidelity   :class:`FidelitySettings` ``fidelity.*``: how ``"auto"`` chooses the model
output     :class:`OutputSettings` ``stop_time``, ``output_interval``
========== ======================= ===========================================================

Every record checks its own fields when it is made (a :class:`~orchestration.scene.keys.ConfigError`,
a ``ValueError``, names the scene key and what is allowed), and the scene checks what ties the
records together (the steps against the output grid). Dotted keys are the records' names at the
edges only (scene files, ``--set``, sweep axes, SSP): :data:`KEYS` maps them to the fields,
:meth:`Scene.get` reads a key off the records and :mod:`orchestration.scene.schema` builds the
records from keys.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field, fields, replace
from types import MappingProxyType

from controller_fmu.pd_lowpass import ControllerParams
from fmu_common.checks import Param, boolean, check_fields, choice, integer, real, shown
from plant_fmu.integrators import REGISTRY
from plant_fmu.interface import FIDELITIES, FMU_SETTINGS
from plant_fmu.params import MAX_ELEMENTS, PlantParams

from .keys import FMU_FLAVOURS, ConfigError, ConfigTypeError, config_error
from .wiring import Connection, parse_connection

__all__ = ["AUTO", "ALGORITHMS", "FIRST", "FMU_FLAVOURS", "COMPARABLE_OUTPUTS", "PlantSetup",
           "MasterSettings", "InitialState", "FidelitySettings", "OutputSettings", "Scene",
           "DEFAULT_CONNECTIONS", "KEYS", "initial_energy", "MAX_DESCRIPTION", "PHI_MAX", "KeySpec",
           "key_specs"]

#: The value of ``plant.n_modes`` and ``plant.fidelity`` that lets a run choose the model.
AUTO = "auto"
#: ``plant.exact_step``: the exact rung's Radau IIA step, which is also its communication step
#: (the exact rung couples at its own step). Chosen by ``python3 bench/exact_convergence.py``
#: (docs/exact.md): the smallest cost at which the undamped filtered scene is within 1e-4 rad of
#: a refined reference at every angle from 0.05 rad to pi/6, through the FMU.
EXACT_STEP = 1e-3
ALGORITHMS = ("gauss-seidel", "jacobi", "implicit")
#: ``master.implicit_jacobian``: how the implicit master updates the interface
#: (:mod:`orchestration.cosim.implicit`): Newton on the step's sensitivity, or IQN-ILS.
IMPLICIT_JACOBIANS = ("newton", "iqn-ils")
#: ``master.implicit_scheme``: which outputs the implicit master iterates on: every exchanged one,
#: all FMUs stepping on the assumed values (parallel), or only those fed back to an FMU earlier in
#: the coupling order, the FMUs stepping one after the other (serial, ``master.first`` first).
IMPLICIT_SCHEMES = ("parallel", "serial")
#: master.error_estimator: the adaptive master's local error estimate (orchestration.cosim.master)
ESTIMATORS = ("extrapolation", "energy")
FIRST = ("controller", "plant")
#: ``master.coupling``: what an FMU's inputs are over a communication step
#: (:mod:`orchestration.cosim.coupling`): the polynomials of ``master.extrapolation`` (through
#: past samples, or the output derivatives' Taylor polynomial), or the Hermite coupling
#: (Gauss-Seidel on every output derivative the FMUs give: the Taylor polynomial at the step's
#: start, or the Hermite polynomial through the samples at both ends of the step when the source
#: stepped first; each passed as its least-squares quadratic over the step).
COUPLINGS = ("polynomial", "hermite")
#: ``master.interface``: the FMUs stepped as co-simulation slaves, or their Model Exchange
#: interfaces solved as one system (:mod:`orchestration.cosim.model_exchange`).
INTERFACES = ("co-simulation", "model-exchange")
#: ``master.solver``: the stiff solver of the model-exchange master (scipy's).
SOLVERS = ("radau", "bdf")
#: Outputs that every model has (0 for the rigid model's deflection), by result column.
COMPARABLE_OUTPUTS = ("x", "x_dot", "phi_o", "omega_o", "F_c", "tip_deflection", "eta_1")
#: The longest ``description`` (characters): a line or two of text, not a document.
MAX_DESCRIPTION = 1000
#: The largest ``|initial.phi|`` whatever ``plant.phi_limit`` (``inf`` included), rad.
PHI_MAX = 1e6
#: The paper's loop: the sensors to the controller, the force to the plant.
DEFAULT_CONNECTIONS = (
    "plant.x_o -> controller.x_o",
    "plant.phi_o -> controller.phi_o",
    "plant.omega_o -> controller.omega_o",
    "controller.F_c -> plant.F_c",
)


def _set(obj, name, value):
    object.__setattr__(obj, name, value)


def _checked(check, *args, **kw):
    """``check(*args, **kw)``, its TypeError or ValueError as a ConfigError (a
    :class:`~orchestration.scene.keys.ConfigTypeError` for a TypeError)."""
    try:
        return check(*args, **kw)
    except (TypeError, ValueError) as exc:
        raise config_error(exc) from None


@dataclass(frozen=True)
class PlantSetup:
    """``plant.*``: the plant's physical parameters, the model and the plant FMU's settings.

    ``n_modes`` and ``fidelity`` may be ``"auto"``: a run chooses them
    (:func:`orchestration.studies.fidelity.select_model`) and runs the scene it resolves, whose
    plant has both. Until then :attr:`params` raises: nothing can use a model not chosen yet.
    """

    beam: PlantParams = PlantParams()      # with n_modes = 0 while n_modes is "auto"
    n_modes_auto: bool = False
    fidelity: str = choice(FMU_SETTINGS["fidelity"], "the plant model: nonlinear, linear "
                           "(linearised upright), exact (geometrically exact beam), stiffened, "
                           "or auto (a run chooses)", (*FIDELITIES, AUTO))
    integrator: str = choice(FMU_SETTINGS["integrator"], "the plant FMU's integration method "
                             "(docs/integrators.md)", sorted(REGISTRY))
    step: float = real(FMU_SETTINGS["step"], "the plant's substep (initial step of the adaptive "
                       "methods); not the exact rung's", "s", low=0.0, high=1e6,
                       note="below the method's stability limit on the fastest mode")
    rtol: float = real(FMU_SETTINGS["rtol"], "relative tolerance of the adaptive and implicit "
                       "methods", low=0.0, high=1e6)
    atol: float = real(FMU_SETTINGS["atol"], "absolute tolerance of the adaptive and implicit "
                       "methods", low=0.0, high=1e6)
    phi_limit: float = real(FMU_SETTINGS["phi_limit"], "divergence bound on |phi|: the plant "
                            "stops a run beyond it", "rad", low=0.0, allow_inf=True)
    energy_limit: float = real(FMU_SETTINGS["energy_limit"], "divergence bound on |energy|: the "
                               "plant stops a run beyond it", "J", low=0.0, allow_inf=True)
    exact_step: float = real(EXACT_STEP, "the exact rung's Radau IIA step, also its "
                             "communication step", "s", low=0.0, high=1e6)

    def __post_init__(self):

        if not isinstance(self.beam, PlantParams):
            raise TypeError(f"beam must be a PlantParams, got {type(self.beam).__name__}")
        _checked(check_fields, self, "plant.")
        if self.integrator == "exponential" and self.fidelity != "linear":
            raise ConfigError("plant.integrator = 'exponential' integrates the linearised plant; "
                              "it needs plant.fidelity = 'linear'")

    @property
    def n_modes(self):
        """The number of cantilever modes, or ``"auto"``."""
        return AUTO if self.n_modes_auto else self.beam.n_modes

    @property
    def resolved(self) -> bool:
        """Whether the model is chosen (neither ``n_modes`` nor ``fidelity`` is ``"auto"``)."""
        return not self.n_modes_auto and self.fidelity != AUTO

    @property
    def params(self) -> PlantParams:
        """The plant's parameters, its model chosen (ConfigError while ``n_modes`` is auto)."""
        if self.n_modes_auto:
            raise ConfigError("plant.n_modes = 'auto' is chosen by a run: resolve the scene "
                              "first (orchestration.studies.fidelity.select_model)")
        return self.beam

    def with_model(self, n_modes: int, fidelity: str) -> "PlantSetup":
        """This plant with the model ``n_modes`` and ``fidelity`` chosen."""
        return replace(self, beam=self.beam.replace(n_modes=n_modes), n_modes_auto=False,
                       fidelity=fidelity)


@dataclass(frozen=True)
class MasterSettings:
    """``master.*``: the co-simulation's coupling (see ``orchestration.cosim``)."""

    algorithm: str = choice("gauss-seidel", "the coupling: gauss-seidel, jacobi, or implicit "
                            "(strongly coupled)", ALGORITHMS)
    first: str = choice("controller", "which FMU steps first in Gauss-Seidel", FIRST)
    step: float = real(2e-3, "communication step (initial step when adaptive)", "s", low=0.0,
                       high=1e6, note="at most stop_time; output_interval a multiple of it")
    extrapolation: int = integer(2, "input extrapolation: 0 (zero-order hold), 1 (linear), "
                                 "2 (quadratic)", low=0, high=2)
    adaptive: bool = boolean(False, "adaptive communication step",
                             note="not with master.algorithm = implicit")
    tolerance: float = real(1e-4, "the adaptive step's error tolerance", low=0.0, high=1e6)
    min_step: float = real(1e-6, "the adaptive step's lower bound", "s", low=0.0, high=1e6,
                           note="at most master.max_step")
    max_step: float = real(2e-2, "the adaptive step's upper bound (and the model-exchange "
                           "solver's)", "s", low=0.0, high=1e6)
    error_estimator: str = choice("extrapolation", "the adaptive step's error estimate",
                                  ESTIMATORS)
    input_derivatives: bool = boolean(True, "pass the extrapolation polynomial to FMUs that "
                                      "take input derivatives")
    fmus: str = choice("native", "the FMUs run: native (C) or python (pythonfmu)", FMU_FLAVOURS)
    compiled: object = field(default="auto", metadata={"param": Param(
        "other", "the master's loop in C (fixed-step, adaptive, implicit co-simulation; model "
        "exchange on radau): auto (where the FMUs allow it), true, false",
        note="auto, true or false")})
    output_derivatives: bool = boolean(False, "extrapolate outputs by the FMUs' output "
                                       "derivatives", note="native FMUs, master.input_derivatives")
    coupling: str = choice("polynomial", "the inputs over a step: polynomial (master."
                           "extrapolation's) or hermite (the FMUs' output derivatives: Taylor at "
                           "the step's start, or Hermite through both ends of the step for an "
                           "FMU that stepped first; as least-squares quadratics)", COUPLINGS,
                           note="hermite: gauss-seidel, native FMUs, a fixed step, "
                           "master.input_derivatives")
    interface: str = choice("co-simulation", "the FMUs stepped as slaves, or their Model "
                            "Exchange interfaces solved as one system", INTERFACES)
    solver: str = choice("radau", "the model-exchange master's stiff solver", SOLVERS)
    rtol: float = real(1e-6, "the model-exchange solver's relative tolerance", low=1e-14,
                       high=0.1)
    atol: float = real(1e-8, "the model-exchange solver's absolute tolerance (times each "
                       "state's nominal value)", low=1e-300, high=1e6)
    implicit_tolerance: float = real(1e-9, "the implicit master's interface tolerance "
                                     "(relative to max(1, |output|))", low=1e-15, high=1.0)
    max_iterations: int = integer(20, "the implicit master's iterations per step", low=1,
                                  high=1000)
    implicit_jacobian: str = choice("newton", "the implicit master's update: newton or "
                                    "iqn-ils", IMPLICIT_JACOBIANS)
    implicit_scheme: str = choice("parallel", "the implicit master's unknowns: every exchanged "
                                  "output (parallel) or those fed back to an earlier FMU in "
                                  "master.first's order (serial)", IMPLICIT_SCHEMES)

    def __post_init__(self):
        _checked(check_fields, self, "master.")
        if self.algorithm == "implicit" and self.adaptive:
            raise ConfigError("master.algorithm = 'implicit' takes a fixed step; "
                              "master.adaptive = true is not allowed with it")
        if self.output_derivatives:
            why = ("the pythonfmu FMUs give none" if self.fmus != "native" else
                   "the implicit master interpolates between the step's samples"
                   if self.algorithm == "implicit" else
                   "a zero-order hold (master.extrapolation = 0) uses no polynomial"
                   if self.extrapolation == 0 else
                   "with held inputs the derivatives at a step's end belong to the held value, "
                   "not to the input (master.input_derivatives = true is needed)"
                   if not self.input_derivatives else None)
            if why:
                raise ConfigError(f"master.output_derivatives = true cannot be used here: {why}")
        if self.coupling == "hermite":
            why = ("the pythonfmu FMUs give no output derivatives" if self.fmus != "native" else
                   f"it is a Gauss-Seidel coupling (master.algorithm = {self.algorithm!r})"
                   if self.algorithm != "gauss-seidel" else
                   "it takes a fixed step (master.adaptive = true)" if self.adaptive else
                   "it passes its polynomials as input derivatives (master.input_derivatives = "
                   "false)" if not self.input_derivatives else
                   "it couples co-simulation FMUs (master.interface = 'model-exchange')"
                   if self.interface != "co-simulation" else None)
            if why:
                raise ConfigError(f"master.coupling = 'hermite' cannot be used here: {why}")
        if self.interface == "model-exchange" and self.fmus != "native":
            raise ConfigError(f"master.interface = 'model-exchange' needs master.fmus = 'native' "
                              f"(the {self.fmus} FMUs are co-simulation only)")
        if not (isinstance(self.compiled, bool) or self.compiled == "auto"):
            raise ConfigError(f"master.compiled = {self.compiled!r} is not allowed; allowed: "
                              "'auto', true, false")
        if self.min_step > self.max_step:
            raise ConfigError(f"master.min_step = {self.min_step} exceeds master.max_step = "
                              f"{self.max_step}")


@dataclass(frozen=True)
class InitialState:
    """``initial.*``: the initial state (the beam undeformed)."""

    phi: float = real(math.pi / 6, "initial angle of the (undeformed) beam from the upward "
                      "vertical", "rad", check=False,
                      note="|initial.phi| <= plant.phi_limit (and <= 1e+06)")
    x: float = real(0.0, "initial cart position", "m", low=-1e6, high=1e6)
    phi_dot: float = real(0.0, "initial angular rate", "rad/s", low=-1e6, high=1e6,
                          note="the energy within plant.energy_limit")
    x_dot: float = real(0.0, "initial cart velocity", "m/s", low=-1e6, high=1e6,
                        note="the energy within plant.energy_limit")

    def __post_init__(self):
        _checked(check_fields, self, "initial.")
        # initial.phi's range is checked by the scene, against plant.phi_limit: its real limit
        if isinstance(self.phi, bool) or not isinstance(self.phi, (int, float)):
            raise ConfigTypeError(f"initial.phi must be a real number, got {shown(self.phi)}")
        try:
            _set(self, "phi", float(self.phi))
        except OverflowError:
            _set(self, "phi", math.inf)             # an integer beyond a double: out of range


@dataclass(frozen=True)
class FidelitySettings:
    """``fidelity.*``: how a run chooses the model when ``plant.n_modes`` or ``plant.fidelity``
    is ``"auto"`` (:mod:`orchestration.studies.fidelity`), and whether a run states its error
    figure (``companion``: the companion run it is made from,
    :mod:`orchestration.studies.error_figure`; off, the measured global bound only)."""

    tolerance: float = real(0.05, "relative agreement that makes a smaller model enough (auto)",
                            low=0.0, high=1.0)
    max_modes: int = integer(8, "the richest model plant.n_modes = auto tries", low=1,
                             high=MAX_ELEMENTS, note="at most plant.n_elements")
    outputs: tuple = field(default=("x", "phi_o", "omega_o", "F_c"), metadata={"param": Param(
        "other", "the outputs auto compares", note="a non-empty list of "
        + ", ".join(COMPARABLE_OUTPUTS))})
    companion: bool = boolean(True, "the run states its error figure, from a companion run "
                              "(false: the measured bound only)")

    def __post_init__(self):
        _checked(check_fields, self, "fidelity.")
        outs = self.outputs
        if (not isinstance(outs, (list, tuple)) or not outs
                or not all(isinstance(o, str) and o in COMPARABLE_OUTPUTS for o in outs)):
            raise ConfigError(f"fidelity.outputs = {outs!r} is not allowed; allowed: a "
                              f"non-empty list of {', '.join(COMPARABLE_OUTPUTS)}")
        _set(self, "outputs", tuple(outs))


@dataclass(frozen=True)
class OutputSettings:
    """``stop_time`` and ``output_interval``: the run's length and its output grid (s)."""

    stop_time: float = real(10.0, "the run's length", "s", low=0.0, high=1e6,
                            note="a multiple of output_interval")
    output_interval: float = real(0.002, "the output grid's interval", "s", low=0.0, high=1e6)

    def __post_init__(self):
        _checked(check_fields, self)
        n_out = self.stop_time / self.output_interval
        if not math.isfinite(n_out) or n_out < 1 - 1e-9 or abs(n_out - round(n_out)) > 1e-9 * n_out:
            raise ConfigError(f"stop_time = {self.stop_time} must be a positive multiple of "
                              f"output_interval = {self.output_interval}")

    @property
    def n_out(self) -> int:
        """The number of output intervals."""
        return int(round(self.stop_time / self.output_interval))


def initial_energy(p: PlantParams, initial: InitialState, linear: bool = False) -> float:
    """The plant's energy ``T + V`` (J) at ``initial``, the beam undeformed (every modal
    coordinate and rate 0), as the plant FMU computes it (``plant_fmu.dynamics``: the nonlinear
    model's ``energy``, or with ``linear`` the linearised one's). With ``eta = 0`` only the rigid
    invariants enter, ``I0 = m + rhoA L``, ``I1 = rhoA L^2/2``, ``I2 = rhoA L^3/3``, so no beam
    model is built (a scene is read without numpy); a test holds it to the models."""
    rhoA, L = p.rho * p.EA / p.E, p.L
    I0, I1, I2 = p.m + rhoA * L, rhoA * L * L / 2, rhoA * L ** 3 / 3
    phi, xd, phid = initial.phi, initial.x_dot, initial.phi_dot
    if linear:
        return (0.5 * I0 * xd * xd - I1 * xd * phid + 0.5 * I2 * phid * phid
                - 0.5 * p.g * I1 * phi * phi + p.g * I1)
    return (0.5 * I0 * xd * xd - I1 * xd * phid * math.cos(phi) + 0.5 * I2 * phid * phid
            + p.g * I1 * math.cos(phi))


def _keys() -> dict:
    """scene key -> (record, attribute path): the one map between the dotted keys and the
    records' fields, in the order of a scene file."""
    out = {"description": ("", "description")}
    out.update({f"plant.{f.name}": ("plant", "n_modes" if f.name == "n_modes" else f"beam.{f.name}")
                for f in fields(PlantParams)})
    out.update({f"plant.{f.name}": ("plant", f.name) for f in fields(PlantSetup)
                if f.name not in ("beam", "n_modes_auto")})
    out.update({f"controller.{f.name}": ("controller", f.name) for f in fields(ControllerParams)})
    out.update({f"initial.{f.name}": ("initial", f.name) for f in fields(InitialState)})
    out.update({f.name: ("output", f.name) for f in fields(OutputSettings)})
    out.update({f"master.{f.name}": ("master", f.name) for f in fields(MasterSettings)})
    out.update({f"fidelity.{f.name}": ("fidelity", f.name) for f in fields(FidelitySettings)})
    out["connections"] = ("", "connections")
    return out


def _connections(value) -> tuple:
    if isinstance(value, str) or not isinstance(value, (list, tuple)) or not value:
        raise ConfigError("connections must be a non-empty list of strings "
                          "'fmu.variable -> fmu.variable'")
    out = []
    for c in value:
        if isinstance(c, Connection):
            conn = c
        elif isinstance(c, str):
            try:
                conn = parse_connection(c)
            except ValueError as exc:
                raise ConfigError(f"connections {exc}") from None
        else:
            raise ConfigError("connections must be a non-empty list of strings "
                              "'fmu.variable -> fmu.variable'")
        for fmu in (conn.src, conn.dst):
            if fmu not in ("plant", "controller"):
                raise ConfigError(f"connections {str(conn)!r} names FMU {fmu!r}; allowed: "
                                  "plant, controller")
        out.append(conn)
    return tuple(out)



#: A sampled scene's communication step (:func:`tick_step`) may be at most this many times
#: smaller than the scene's own.
MAX_TICK_REFINEMENT = 1000


def tick_step(h: float, *instants: float) -> float:
    """The largest communication step up to ``h`` that divides every positive value of
    ``instants`` (a sampled controller's period and delay, the output interval): ``h`` itself
    when it does (to 1e-9), else ``g / ceil(g / h)`` with ``g`` their greatest common divisor
    (as fractions of at most 10^12 in the denominator; 0 when a value is no such fraction to
    1e-9)."""
    from fractions import Fraction

    values = [v for v in instants if v > 0]
    if all(abs(v / h - round(v / h)) <= 1e-9 * (v / h) for v in values):
        return h
    fr = [Fraction(v).limit_denominator(10 ** 12) for v in values]
    if any(not abs(float(f) - v) <= 1e-9 * v for f, v in zip(fr, values)):
        return 0.0                    # no such fraction (1e-320 s): no common step at all
    g = fr[0]
    for f in fr[1:]:
        g = Fraction(math.gcd(g.numerator * f.denominator, f.numerator * g.denominator),
                     g.denominator * f.denominator)
    return float(g / math.ceil(g / Fraction(h)))


@dataclass(frozen=True)
class Scene:
    """A validated scene: its name, description, wiring and records (see the module)."""

    name: str
    plant: PlantSetup = PlantSetup()
    controller: ControllerParams = ControllerParams()
    master: MasterSettings = MasterSettings()
    initial: InitialState = InitialState()
    fidelity: FidelitySettings = FidelitySettings()
    output: OutputSettings = OutputSettings()
    connections: tuple = field(default=DEFAULT_CONNECTIONS, metadata={"param": Param(
        "other", "the wiring", note="a non-empty list of 'fmu.variable -> fmu.variable' "
        "(FMUs plant, controller)")})
    description: str = field(default="", metadata={"param": Param(
        "other", "what the scene shows", note=f"a string of at most {MAX_DESCRIPTION} "
        "characters")})

    def __post_init__(self):
        for name, cls in (("plant", PlantSetup), ("controller", ControllerParams),
                          ("master", MasterSettings), ("initial", InitialState),
                          ("fidelity", FidelitySettings), ("output", OutputSettings)):
            if not isinstance(getattr(self, name), cls):
                raise TypeError(f"Scene.{name} must be a {cls.__name__}, got "
                                f"{type(getattr(self, name)).__name__}")
        _set(self, "connections", _connections(self.connections))
        if not isinstance(self.description, str):
            raise ConfigError("description must be a string")
        if len(self.description) > MAX_DESCRIPTION:
            raise ConfigError(f"description: {len(self.description)} characters; allowed: at most "
                              f"{MAX_DESCRIPTION}")
        if self.fidelity.max_modes > self.plant.beam.n_elements:
            raise ConfigError(f"fidelity.max_modes = {self.fidelity.max_modes} is out of range; "
                              f"allowed: integers 1..{self.plant.beam.n_elements}")
        self._check_initial_state()
        self._check_exact()
        self._check_sampled()
        self._check_stiffened()
        m, out = self.run_master, self.output
        key = "plant.exact_step" if self.plant.fidelity == "exact" else "master.step"
        if m.step > out.stop_time:
            raise ConfigError(f"{key} = {m.step} exceeds stop_time = {out.stop_time}")
        ratio = out.output_interval / m.step
        if not m.adaptive and (not math.isfinite(ratio) or abs(ratio - round(ratio)) > 1e-9 * ratio):
            raise ConfigError(f"output_interval = {out.output_interval} must be a multiple of "
                              f"{key} = {m.step}")

    def __repr__(self) -> str:
        """One line: the name, the model, the controller, the coupling and the stop time."""
        pl, c, m = self.plant, self.controller, self.master
        filt = ("no filter" if c.filter_order == 0 else
                f"order-{c.filter_order} filter {c.cutoff:g} rad/s")
        step = "adaptive" if m.adaptive else f"step {self.run_master.step:g} s"
        return (f"Scene({self.name!r}: {pl.n_modes} modes {pl.fidelity}, PD kp={c.kp:g} "
                f"kd={c.kd:g} {filt}, {m.algorithm} {step}, stop_time {self.output.stop_time:g} s)")

    @property
    def run_master(self) -> MasterSettings:
        """The master's settings a run uses: the scene's, but at the exact rung
        (``plant.fidelity = "exact"``) the communication step is ``plant.exact_step``, the
        beam's own Radau step. The exact beam carries undamped modes far above any
        communication rate (the second bending mode's neighbours up to the axial modes near
        8000 rad/s); a controller that samples it more coarsely than its integrator resolves it
        aliases them into the loop's band, so that a finer plant would give a worse coupled
        result (docs/exact.md). Sampled at the integrator's own step, the beam as integrated
        has nothing above the sampling's Nyquist frequency: L-stable Radau damps what the step
        does not resolve."""
        m = self.master
        if self.plant.fidelity == "exact":
            m = replace(m, step=self.plant.exact_step)
        c = self.controller
        if c.sampled:
            # the sampled controller's coupling is exact on the ticks' grid (docs/sampled.md):
            # Jacobi, every input held, the controller's force read after its sensors are set,
            # at the largest step up to the scene's that lands on every tick, tick + delay and
            # output point
            m = replace(m, algorithm="jacobi", extrapolation=0, input_derivatives=False,
                        output_derivatives=False, coupling="polynomial",
                        step=tick_step(m.step, c.sample_period, c.delay,
                                       self.output.output_interval))
        return m

    def _check_exact(self):
        """``plant.fidelity = "exact"`` runs in the native FMUs' co-simulation interface only, at
        a fixed step (``plant.exact_step``, :attr:`run_master`): the pythonfmu plant, Model
        Exchange, output derivatives and the adaptive step are not offered by it. It takes
        either damping law (:class:`plant_fmu.exact.FrameModalDamping` for the modal one)."""
        if self.plant.fidelity != "exact":
            return
        m = self.master
        why = ("master.fmus = 'python': the pythonfmu plant has no exact rung"
               if m.fmus != "native" else
               "master.adaptive = true: the exact rung couples at its own step, "
               "plant.exact_step" if m.adaptive else
               "master.interface = 'model-exchange': the exact beam steps implicitly inside the "
               "FMU (co-simulation only)" if m.interface == "model-exchange" else
               "master.output_derivatives = true: the exact rung gives no output derivatives"
               if m.output_derivatives else
               "master.coupling = 'hermite': the exact rung gives no output derivatives"
               if m.coupling == "hermite" else None)
        if why:
            raise ConfigError(f"plant.fidelity = 'exact' cannot be used with {why}")

    def _check_sampled(self):
        """A sampled controller (``controller.sample_period > 0``) runs in co-simulation (the
        native PDLowPassSampled, or the pythonfmu PDLowPass) at a fixed communication step that lands on every tick and every tick +
        delay: ``master.step`` (``plant.exact_step`` at the exact rung) divides
        ``controller.sample_period`` and ``controller.delay``. Its coupling is then exact, and
        the master's own choices of coupling (``master.algorithm``, ``extrapolation``, input and
        output derivatives) do not apply (:attr:`run_master`); both loops, Python and compiled,
        run it. The step is the largest up to ``master.step`` that lands on every tick, tick +
        delay and output point (:func:`tick_step`); one over :data:`MAX_TICK_REFINEMENT` times
        smaller is refused."""
        c = self.controller
        if not c.sampled:
            return
        m = self.master
        why = ("master.adaptive = true: the communication points must land on the ticks"
               if m.adaptive else
               "master.interface = 'model-exchange': the sampled controller is a co-simulation "
               "FMU" if m.interface == "model-exchange" else None)
        if why:
            raise ConfigError(f"controller.sample_period = {c.sample_period:g} cannot be used "
                              f"with {why}")
        h = self.plant.exact_step if self.plant.fidelity == "exact" else m.step
        key = "plant.exact_step" if self.plant.fidelity == "exact" else "master.step"
        lands = tick_step(h, c.sample_period, c.delay, self.output.output_interval)
        if lands < h / MAX_TICK_REFINEMENT:
            raise ConfigError(f"controller.sample_period = {c.sample_period:g} s, delay "
                              f"{c.delay:g} s: the step landing on every tick, tick + delay and "
                              f"output point is {lands:.3g} s, under {key} / "
                              f"{MAX_TICK_REFINEMENT}; allowed: values on a common grid")

    def _check_stiffened(self):
        """``plant.fidelity = "stiffened"`` gives no directional or output derivatives (its
        kernel has no exact Jacobians), which the Model Exchange master,
        ``master.output_derivatives`` and ``master.coupling = "hermite"`` need."""
        if self.plant.fidelity != "stiffened":
            return
        m = self.master
        why = ("master.interface = 'model-exchange': its master needs the FMUs' directional "
               "derivatives" if m.interface == "model-exchange" else
               "master.output_derivatives = true" if m.output_derivatives else
               "master.coupling = 'hermite': its output derivatives" if m.coupling == "hermite"
               else None)
        if why:
            raise ConfigError(f"plant.fidelity = 'stiffened' cannot be used with {why}, which "
                              "the stiffened rung does not give")

    def _check_initial_state(self):
        """The initial state within the plant's limits: ``|initial.phi|`` at most
        ``plant.phi_limit`` (and :data:`PHI_MAX`); the plant FMU stops a run whose ``|phi|``
        exceeds ``plant.phi_limit`` or whose ``|energy|`` exceeds ``plant.energy_limit``, so a
        scene that starts beyond them would stop at its first step."""
        phi, lim = self.initial.phi, min(self.plant.phi_limit, PHI_MAX)
        if not abs(phi) <= lim and lim < PHI_MAX:
            raise ConfigError(f"initial.phi = {phi:.6g} is beyond plant.phi_limit = {lim:.4g} rad "
                              f"({math.degrees(lim):.4g} deg), where the plant stops a run; "
                              f"allowed: |initial.phi| <= {lim:.6g}")
        if not abs(phi) <= lim:
            raise ConfigError(f"initial.phi = {phi:.6g} is out of range; allowed: |initial.phi| "
                              f"<= {lim:g}")
        e_lim = self.plant.energy_limit
        if math.isfinite(e_lim):
            energy = initial_energy(self.plant.beam, self.initial,
                                    linear=self.plant.fidelity == "linear")
            if not abs(energy) <= e_lim:
                raise ConfigError(f"the initial state's energy ({energy:.4g} J, from initial.phi, "
                                  f"initial.x_dot and initial.phi_dot) is beyond "
                                  f"plant.energy_limit = {e_lim:.4g} J, where the plant stops a "
                                  "run")

    @property
    def resolved(self) -> bool:
        """Whether the model is chosen (see :attr:`PlantSetup.resolved`)."""
        return self.plant.resolved

    def get(self, key: str):
        """The value of the scene key ``key``, read off the records (in its edge form: lists of
        strings for ``connections`` and ``fidelity.outputs``); KeyError for an unknown key."""
        record, path = KEYS[key]
        obj = getattr(self, record) if record else self
        for part in path.split("."):
            obj = getattr(obj, part)
        if key == "plant.n_modes":
            return self.plant.n_modes
        if key == "connections":
            return [str(c) for c in obj]
        return list(obj) if isinstance(obj, tuple) else obj

    @property
    def config(self) -> MappingProxyType:
        """Every scene key with its value: the records in their edge form (scene files, sweep
        keys, SSP annotations)."""
        return MappingProxyType({key: self.get(key) for key in KEYS})

    def replace(self, **changes) -> "Scene":
        """A copy with records (or the name, description, connections) replaced, validated."""
        return replace(self, **changes)


#: scene key -> (record, attribute path) (see :func:`_keys`)
KEYS = _keys()


@dataclass(frozen=True)
class KeySpec:
    """One scene key as ``flexpend keys`` lists it: its ``type``, ``default``, ``unit`` (None:
    none), ``allowed`` (the rule its record enforces, and what it needs with other keys) and
    one line of ``meaning``. Read off the records' fields (:class:`fmu_common.checks.Param`),
    which check the values by the same rule."""

    key: str
    type: str
    default: object
    unit: str | None
    allowed: str
    meaning: str

    def __repr__(self) -> str:
        allowed = self.allowed if len(self.allowed) <= 70 else self.allowed[:67] + "..."
        return (f"KeySpec({self.key}: {self.type} = {shown(self.default)}"
                f"{' ' + self.unit if self.unit else ''}; {allowed})")


_TYPES = {"real": "float", "int": "int", "bool": "bool", "choice": "str"}


def _param(key: str):
    """The Param of ``key`` and the prefix its record's messages give field names."""
    record, path = KEYS[key]
    cls = {"": Scene, "plant": PlantSetup, "controller": ControllerParams, "master": MasterSettings,
           "initial": InitialState, "fidelity": FidelitySettings, "output": OutputSettings}[record]
    name = path
    if path.startswith("beam."):
        cls, name = PlantParams, path[len("beam."):]
    elif key == "plant.n_modes":
        cls = PlantParams
    f = next(f for f in fields(cls) if f.name == name)
    return f.metadata["param"], (f"{record}." if record and record != "output" else "")


def key_specs() -> tuple:
    """Every scene key, in the order of a scene file, as a :class:`KeySpec`."""
    default = Scene(name="default")
    out = []
    for key in KEYS:
        param, prefix = _param(key)
        value = default.get(key)
        kind = _TYPES.get(param.kind) or ("list of str" if isinstance(value, list) else
                                          "str or bool" if key == "master.compiled" else
                                          type(value).__name__)
        allowed = param.allowed(prefix)
        if key == "plant.n_modes":
            kind, allowed = "int or str", f"{allowed}, or {AUTO!r} (a run chooses)"
        out.append(KeySpec(key, kind, value, param.unit, allowed, param.meaning))
    return tuple(out)
