"""``PDLowPass``: the PD + low-pass controller as an FMI 2.0 co-simulation FMU (pythonfmu).

A thin adapter over the controller's compiled kernel (:class:`controller_fmu.kernel.FilterKernel`,
``native/fp_filter.c``, the same C the native FMUs link): it discretises the filter exactly over the
communication step and advances it; :class:`controller_fmu.pd_lowpass.PDLowPassModel` (numpy and
scipy, the specification) gives the parameters' checks and the direct feedthrough of order 0. This
class only holds the time and the inputs. The FMU ships the kernel for linux64 (and win64 when it
was built with the cross-compiler); if the host platform's is missing, instantiation fails with a
log message naming it.

Over ``doStep(t, h)`` the filter advances exactly: ``xc <- Ad(h) xc + Bd(h) e`` with the inputs
held (zero-order hold), or, when the sensors' time derivatives are given (inputs ``dphi_o``...,
``d2phi_o``..., FMI's input derivatives as variables: pythonfmu has no
``fmi2SetRealInputDerivatives``), exactly for the polynomial inputs
``y + dy (s - t) + d2y (s - t)^2 / 2``: ``xc <- Ad xc + G [e, de, d2e]``. ``F_c = -xc[0]`` (saturated) for filter orders 1 and 2; with
``filter_order = 0`` there is no filter and ``F_c = -e`` is computed from the current inputs
(direct feedthrough, declared in ``modelDescription.xml``).

Failures never raise (see :mod:`fmu_common.slave`): a non-finite input makes ``doStep`` return
fmi2Discard with the state unchanged, and a bad parameter is logged with status fmi2Error at
``exitInitializationMode``, after which every ``doStep`` returns fmi2Discard. ``F_c`` is never NaN:
it holds its last finite value.
"""
from __future__ import annotations

import math

from pythonfmu import DefaultExperiment

from controller_fmu import kernel
from controller_fmu.interface import MODEL, SENSORS, VARIABLES
from controller_fmu.pd_lowpass import ControllerParams, PDLowPassModel
from controller_fmu.sampled import SampledController
from fmu_common.slave import Fmi2Status, SlaveBase, StateError, check_finite

__all__ = ["PDLowPass"]


class PDLowPass(SlaveBase):
    """PD on the tip sensors, a low-pass filter, a saturation: ``F_c = -sat(H(s) e)``."""

    description = MODEL.description
    version = MODEL.version
    default_experiment = DefaultExperiment(start_time=MODEL.start_time,
                                           stop_time=MODEL.stop_time, step_size=MODEL.step_size)

    SENSORS = tuple(SENSORS)
    #: the sensors, then their first and second time derivatives at the start of a step
    INPUTS = tuple(v.name for v in VARIABLES if v.causality == "input")

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        # No silent fallback: without its compiled kernel the slave cannot be built, and the
        # KernelError (naming the missing file and the platform) makes fmi2Instantiate fail;
        # pythonfmu logs its message (the instance's own logger does not exist yet).
        kernel.library()
        self._register_table(VARIABLES, lambda n: self._force)
        self._t = self._t0 = 0.0
        self._model: PDLowPassModel | None = None
        #: the sampled controller (sample_period > 0; controller_fmu/sampled.py), else None
        self._sampled: SampledController | None = None
        self._kern: kernel.FilterKernel | None = None   # holds the filter state (output first)
        self._order = 0
        self._F = 0.0                 # F_c after the last step (orders 1, 2) or last finite F_c
        self._h = None                # step of the current discretisation
        self._prep = None             # the kernel's discretisation over the current step
        self._disc = {}               # step -> discretisation (a master's steps t1 - t0 differ
                                      # in the last bits: a few entries)

    # ------------------------------------------------------------------ set-up
    def setup_experiment(self, start_time, stop_time=None, tolerance=None):
        self._t = self._t0 = float(start_time)

    def _parameters_changed(self):
        self._model = None
        self._error = None

    def _prepare(self) -> bool:
        """Build the model from the parameters; on a bad one log it and return False."""
        try:
            params = ControllerParams(**self._par)
        except (TypeError, ValueError) as exc:
            self._error = f"bad parameter: {exc}"
            self.log(self._error, Fmi2Status.error)
            return False
        self._error = None
        self._model = PDLowPassModel(params)
        self._kern = kernel.FilterKernel(params)
        self._order = params.filter_order
        self._lim = params.force_limit
        self._h = None
        self._disc = {}
        self._gains = (params.kx, params.kp, params.kd)
        self._F = 0.0
        self._sampled = self._sampled_controller(params, self._kern)
        if self._order == 0 or self._sampled is not None:
            self._force()
        return True

    def _sampled_controller(self, params, kern):
        """The sampled controller of ``params`` on the C kernel's difference equation (None for
        the continuous one)."""
        if not params.sampled:
            return None
        return SampledController(params, self._t0,
                                 kern.sampled(params.sample_period, params.discretization))

    def exit_initialization_mode(self):
        self._prepare()
        self._initialized = True

    # ------------------------------------------------------------------ stepping
    def _inputs(self):
        return (self.x_o, self.phi_o, self.omega_o)    # the model's order: x_o, phi_o, omega_o

    def _finite_inputs(self) -> bool:
        return math.isfinite(self.x_o + self.phi_o + self.omega_o + self.dx_o + self.dphi_o
                             + self.domega_o + self.d2x_o + self.d2phi_o + self.d2omega_o)

    def _bad_inputs(self) -> str:
        bad = [f"{n} = {getattr(self, n)!r}" for n in self.INPUTS
               if not math.isfinite(getattr(self, n))]
        return ", ".join(bad)

    def _set_step(self, h: float):
        disc = self._disc.get(h)
        if disc is None:
            disc = self._kern.prepared(h)
            if len(self._disc) >= 8:
                self._disc.clear()
            self._disc[h] = disc
        self._prep = disc
        self._h = h

    def do_step(self, current_time, step_size):
        why = self._step_size_error(step_size)
        if why:
            return self._refuse(f"PDLowPass: {why}; step refused, the instance is unchanged")
        if self._error is not None or not self._initialized:
            return self._refuse(f"PDLowPass cannot step: "
                                f"{self._error or 'exitInitializationMode has not been called'}")
        why = self._check_time(current_time, self._t)
        if why:
            return self._refuse(why)
        if self._sampled is not None:
            return self._sampled_step(current_time, step_size)
        if not self._finite_inputs():
            return self._refuse(f"non-finite input at t = {current_time!r}: {self._bad_inputs()}; "
                                f"step rejected, state unchanged", Fmi2Status.discard)
        try:
            why = self._advance(step_size)
        except Exception as exc:          # noqa: BLE001 - an exception would be fmi2Fatal
            why = f"{type(exc).__name__}: {exc}"
        if why:
            return self._refuse(f"filter step rejected at t = {current_time!r}: {why}; "
                                f"state unchanged", Fmi2Status.discard)
        self._t = current_time + step_size
        return True

    def _sampled_step(self, t: float, h: float):
        """A step of the sampled controller: the tick at ``t`` (if any) samples the sensors, a
        step across a tick or a tick + delay is refused (docs/fmus.md); the input derivatives
        are not used (it samples values)."""
        c = self._sampled
        y = self._inputs()
        if c.at_tick(t) and not math.isfinite(sum(y)):
            return self._refuse(f"non-finite input at the tick t = {t!r}: {self._bad_inputs()}; "
                                f"step rejected, state unchanged", Fmi2Status.discard)
        try:
            self._F = c.step(t, h, y)
        except ValueError as exc:
            return self._refuse(f"PDLowPass: {exc}; step refused, state unchanged",
                                Fmi2Status.discard)
        self._t = t + h
        return True

    def _advance(self, h: float) -> str | None:
        """The exact step of the filter over ``h`` (the kernel's discretisation, with the inputs
        held or, given their derivatives, polynomial); returns why it cannot be taken, or None."""
        if not self._order:
            return None
        if h != self._h:
            self._set_step(h)
        kx, kp, kd = self._gains                 # the model's error_signal, inlined
        e = kx * self.x_o + kp * self.phi_o + kd * self.omega_o
        e1 = kx * self.dx_o + kp * self.dphi_o + kd * self.domega_o
        e2 = kx * self.d2x_o + kp * self.d2phi_o + kd * self.d2omega_o
        F = self._kern.step(self._prep, e, e1, e2)
        if F is None:
            return f"the filter state overflows (error signal {e!r})"
        self._F = F
        return None

    def _force(self) -> float:
        if self._model is None and (self._error is not None or not self._prepare()):
            return self._F
        if self._sampled is not None:           # at a tick with no delay: a feedthrough
            y = self._inputs()
            F = self._sampled.output(y) if math.isfinite(sum(y)) else math.nan
            if math.isfinite(F):
                return F
            self.log(f"F_c is not finite for the inputs {self._bad_inputs() or y}; F_c holds "
                     f"its last value {self._sampled.held!r}", Fmi2Status.warning)
            return self._sampled.held
        if self._order == 0:                    # direct feedthrough from the current inputs
            F = self._model.output((), self._inputs()) if self._finite_inputs() else math.nan
            if math.isfinite(F):
                self._F = F
            else:
                self.log(f"F_c is not finite for the inputs {self._bad_inputs() or self._inputs()}"
                         f"; F_c holds its last value {self._F!r}", Fmi2Status.warning)
        return self._F

    # ------------------------------------------------------------------ FMU state
    _STATE_KEYS = ("format", "version", "model", "t", "x", "F", "error", "initialized", "params",
                   "inputs", "sampled")

    def _get_fmu_state(self):
        x = [0.0, 0.0] if self._kern is None else [float(v) for v in self._kern.x]
        return {**self._state_header(), "t": self._t, "x": x, "F": self._F,
                "error": self._error, "initialized": self._initialized,
                "params": self._params_snapshot(),
                "inputs": [getattr(self, n) for n in self.INPUTS],
                "sampled": None if self._sampled is None else self._sampled.state()}

    @classmethod
    def _check_state(cls, state):
        cls._restored(state)

    @classmethod
    def _restored(cls, state):
        """``(model, kernel)`` a restore of ``state`` installs (None, None after a bad
        parameter); raises :class:`StateError` naming what is wrong."""
        cls._check_keys(state, cls._STATE_KEYS)
        params = state["params"]
        names = [v.name for v in VARIABLES if v.causality == "parameter"]
        if not isinstance(params, dict) or sorted(params) != sorted(names):
            raise StateError(f"params must name exactly the parameters {names}")
        check_finite("t", state["t"])
        check_finite("x", state["x"], 2)
        check_finite("F", state["F"])
        check_finite("inputs", state["inputs"], len(cls.INPUTS))
        if not isinstance(state["initialized"], bool):
            raise StateError("initialized must be true or false")
        if state["error"] is not None and not isinstance(state["error"], str):
            raise StateError("error must be null or a message")
        try:
            p = ControllerParams(**params)
            model, kern = PDLowPassModel(p), kernel.FilterKernel(p)
        except (TypeError, ValueError) as exc:
            if state["error"] is None and state["initialized"]:
                raise StateError(f"bad parameter: {exc}") from None
            return None, None, None
        sampled = None
        if p.sampled and state["initialized"]:
            sampled = SampledController(p, 0.0, kern.sampled(p.sample_period, p.discretization))
            if not isinstance(state["sampled"], dict):
                raise StateError("sampled must hold the sampled controller's state")
            try:
                t0 = state["sampled"].get("t0", 0.0)
                sampled.t0 = float(t0)
                sampled.restore(state["sampled"])
            except (TypeError, ValueError) as exc:
                raise StateError(f"sampled: {exc}") from None
            if sampled.t != float(state["t"]):
                raise StateError("sampled: its time is not the instance's")
        elif state["sampled"] is not None:
            raise StateError("sampled must be null for a continuous controller")
        return model, kern, sampled

    def _set_fmu_state(self, state):
        try:
            self._check_header(state)
            model, kern, sampled = self._restored(state)
        except Exception as exc:  # noqa: BLE001 - an exception would be fmi2Fatal
            self._restore_failed(exc)
            return
        # nothing below can fail: the instance changes all at once
        if not self._same_params(state["params"]) or self._model is None:
            self._restore_params(state["params"])
            if model is not None:
                params = model.params
                self._model, self._kern = model, kern
                self._order, self._lim = params.filter_order, params.force_limit
                self._gains = (params.kx, params.kp, params.kd)
                self._h, self._prep, self._disc = None, None, {}
            else:
                self._model = self._kern = None
        self._initialized = state["initialized"]
        self._t = float(state["t"])
        if self._kern is not None:
            self._kern.x[0], self._kern.x[1] = (float(v) for v in state["x"])
        self._F = float(state["F"])
        self._sampled = sampled
        self._error = state["error"]
        self._terminated = False
        for n, v in zip(self.INPUTS, state["inputs"], strict=True):
            setattr(self, n, float(v))
