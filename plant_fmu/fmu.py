"""``FlexiblePendulum``: the cart with a flexible beam as an FMI 2.0 co-simulation FMU (pythonfmu).

A thin adapter: the physics is :class:`plant_fmu.dynamics.PlantModel` (or
:class:`~plant_fmu.dynamics.LinearPlantModel` with ``fidelity = "linear"``), the time stepping is a
stepper of :mod:`plant_fmu.integrators` chosen by name; both run the compiled kernel
(:mod:`plant_fmu.kernel`), which the FMU ships for linux64 (and win64 when it was built with the
cross-compiler). If the host platform's kernel is missing, instantiation fails with a log message
naming it: there is no slower fallback. Over ``doStep(t, h)`` the input ``F_c`` is
held (zero-order hold) and the stepper advances to ``t + h``. No output depends directly on
``F_c``; the outputs are computed from the state when they are read.

Failures never raise (see :mod:`fmu_common.slave`); each one is logged with a message naming
its cause, ``doStep`` returns fmi2Discard and the outputs keep the last accepted state:

* a non-finite ``F_c``: the step is rejected and the state unchanged (a retry may follow);
* a failed integrator, a non-finite state, ``|phi| > phi_limit`` or ``|energy| > energy_limit``
  (divergence): the slave refuses to step until a saved FMU state is restored;
* a bad parameter (logged with status fmi2Error at ``exitInitializationMode``): every ``doStep``
  is refused.

The FMU state (``fmi2GetFMUstate``, ``fmi2SerializeFMUstate``) holds the stepper's whole state
(time, plant state, input, substep grid, method data such as the adaptive step or the Newton
matrices), the input, the error status and the parameters.
"""
from __future__ import annotations

import math

import numpy as np
from pythonfmu import DefaultExperiment

from plant_fmu import kernel
from plant_fmu.dynamics import model_for
from fmu_common.checks import check_real
from fmu_common.slave import Fmi2Status, SlaveBase, StateError, check_finite
from plant_fmu.integrators import REGISTRY, make_stepper
from plant_fmu.interface import (FIDELITIES, FMU_SETTINGS, INITIAL_STATE, MODEL, N_ETA_OUTPUTS,
                                 OUTPUTS, VARIABLES)
from plant_fmu.params import PlantParams

__all__ = ["FlexiblePendulum", "FMU_DEFAULTS", "OUTPUTS"]

#: The FMU's settings and initial state beyond PlantParams, with their defaults.
FMU_DEFAULTS = {**FMU_SETTINGS, **{k: v for k, (_, v) in INITIAL_STATE.items()}}

#: A state whose squared norm exceeds this has blown up; below it every output is finite.
STATE_NORM2_LIMIT = 1e200

#: The most substeps one ``doStep`` may take (bounded work per call): a fixed-step method whose
#: communication step needs more is refused (fmi2Discard, nothing changed); an adaptive method that
#: reaches it stops, like a failed integrator (restore a saved state to continue).
MAX_SUBSTEPS = 100_000

#: Inputs: the force, and its first and second time derivatives at the start of a step (FMI's
#: input derivatives as variables, since pythonfmu has no fmi2SetRealInputDerivatives). Over
#: ``doStep(t, h)`` the force is ``F_c + dF_c (s - t) + d2F_c (s - t)^2 / 2``: integrated at the
#: stage times by the explicit RK methods and symplectic Euler, held at its step average by the
#: others. Left at 0 they give the zero-order hold.
INPUTS = ("F_c", "dF_c", "d2F_c")


class FlexiblePendulum(SlaveBase):
    """A cart on a rail with an elastic beam hinged on it; the input is the force on the cart."""

    description = MODEL.description
    version = MODEL.version
    default_experiment = DefaultExperiment(start_time=MODEL.start_time,
                                           stop_time=MODEL.stop_time, step_size=MODEL.step_size)

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        # No silent fallback: without its compiled kernel the slave cannot be built, and the
        # KernelError (naming the missing file and the platform) makes fmi2Instantiate fail;
        # pythonfmu logs its message (the instance's own logger does not exist yet).
        kernel.library()
        self._register_table(VARIABLES, lambda n: (lambda: self._output(n)))
        self._vr = {v.name: vr for vr, v in self.vars.items()}
        self._out = {self._vr[n]: 0.0 for n in OUTPUTS}   # value reference -> output value
        self._vr_energy = self._vr["energy"]
        self._vr_eta = [self._vr[f"eta_{j}"] for j in range(1, N_ETA_OUTPUTS + 1)]
        self._shape_vrs = frozenset([self._vr["tip_deflection"], *self._vr_eta])
        self._shape_dirty = False
        self._t0 = 0.0
        self._model = None
        self._stepper = None
        self._y = None                     # the last accepted state
        self._dirty = False                # outputs not yet computed from self._y
        self._energy = None
        self._energy_fresh = True

    # ------------------------------------------------------------------ set-up
    def setup_experiment(self, start_time, stop_time=None, tolerance=None):
        self._t0 = float(start_time)

    def _parameters_changed(self):
        self._model = self._stepper = None
        self._error = None

    @classmethod
    def _validated(cls, par: dict):
        """``(PlantParams, FMU settings)`` from the parameters; raises naming the bad one."""
        p = PlantParams(**{k: par[k] for k in cls.dataclass_defaults(PlantParams)})
        s = {k: par[k] for k in FMU_DEFAULTS}
        if s["fidelity"] not in FIDELITIES:
            raise ValueError(f"fidelity = {s['fidelity']!r} is not allowed; allowed: "
                             f"{', '.join(FIDELITIES)}")
        if s["fidelity"] == "exact":
            raise ValueError("fidelity = 'exact' (the geometrically exact beam) runs in the "
                             "native FlexiblePendulum only (master.fmus = 'native'), not in "
                             "this pythonfmu one")
        if s["integrator"] not in REGISTRY:
            raise ValueError(f"integrator = {s['integrator']!r} is unknown; known: "
                             f"{', '.join(sorted(REGISTRY))}")
        if s["integrator"] == "exponential" and s["fidelity"] != "linear":
            raise ValueError("integrator = 'exponential' integrates the plant linearised at the "
                             "upright rest state: it needs fidelity = 'linear'")
        for k in ("step", "rtol", "atol"):
            s[k] = check_real(k, s[k], low=0.0, high=math.inf, high_open=True)
        for k in ("phi_limit", "energy_limit"):
            s[k] = check_real(k, s[k], low=0.0, allow_inf=True)
        for k in ("phi0", "x0", "phi_dot0", "x_dot0"):
            s[k] = check_real(k, s[k])
        return p, s

    @classmethod
    def _build(cls, par: dict, t0: float):
        """``(model, stepper, settings)`` from the parameters and the start time; raises naming
        the bad parameter (also an initial state whose outputs or energy would not be finite)."""
        p, s = cls._validated(par)
        model = model_for(p, s["fidelity"])
        y0 = model.initial_state(phi=s["phi0"], x=s["x0"], phi_dot=s["phi_dot0"],
                                 x_dot=s["x_dot0"])
        with np.errstate(over="ignore", invalid="ignore"):
            norm2 = float(y0 @ y0)
            energy = float(model.energy(y0)) if norm2 <= STATE_NORM2_LIMIT else math.inf
        if not (norm2 <= STATE_NORM2_LIMIT and math.isfinite(energy)):
            init = ", ".join(f"{k} = {s[k]!r}" for k in INITIAL_STATE)
            raise ValueError(f"the initial state ({init}) is too large: its energy or outputs "
                             f"would not be finite (|state| must stay below 1e100)")
        stepper = make_stepper(s["integrator"], model, t0, y0, u=0.0, h=s["step"],
                               rtol=s["rtol"], atol=s["atol"])
        return model, stepper, s

    def _prepare(self) -> bool:
        """Build the model and the stepper from the parameters; log a bad one and return False."""
        self._stepper = None
        try:
            model, stepper, s = self._build(self._par, self._t0)
        except Exception as exc:         # noqa: BLE001 - any failure here is a bad parameter
            self._model = None
            self._error = f"bad parameter: {exc}"
            self.log(self._error, Fmi2Status.error)
            return False
        self._install(model, stepper, s)
        self._error = None
        self._accept(stepper.y, None)
        return True

    def _install(self, model, stepper, s):
        self._model, self._stepper = model, stepper
        self._phi_limit, self._energy_limit = s["phi_limit"], s["energy_limit"]
        self._check_energy = math.isfinite(self._energy_limit)
        self._nq, self._n = model.nq, model.n

    def exit_initialization_mode(self):
        self._prepare()
        self._initialized = True

    # ------------------------------------------------------------------ stepping
    def do_step(self, current_time, step_size):
        why = self._step_size_error(step_size)
        if why:
            return self._refuse(f"FlexiblePendulum: {why}; step refused, the instance is "
                                f"unchanged")
        st = self._stepper
        if st is None or self._error is not None or not self._initialized:
            return self._refuse(f"FlexiblePendulum cannot step: "
                                f"{self._error or 'exitInitializationMode has not been called'}")
        u, du, d2u = self.F_c, self.dF_c, self.d2F_c
        if not math.isfinite(u + du + d2u):
            bad = ", ".join(f"{n} = {v!r}" for n, v in zip(INPUTS, (u, du, d2u))
                            if not math.isfinite(v))
            return self._refuse(f"non-finite input {bad or 'sum'} at t = {current_time!r}; step "
                                f"rejected, state unchanged", Fmi2Status.discard)
        why = self._check_time(current_time, st.t)
        if why:
            return self._refuse(why)
        t_end = current_time + step_size
        if not st.adaptive and (t_end - st.t) > MAX_SUBSTEPS * st.h:
            return self._refuse(f"doStep from t = {current_time!r} over {step_size!r} needs "
                                f"{math.ceil((t_end - st.t) / st.h)} substeps of step = {st.h!r}, "
                                f"more than the cap of {MAX_SUBSTEPS} per doStep: take shorter "
                                f"communication steps or a larger step; step refused, state "
                                f"unchanged", Fmi2Status.discard)
        if not (du or d2u):
            st.u = u
        elif st.POLYNOMIAL_INPUT:
            st.set_input(u, du, d2u, t=current_time)
        else:                                 # a held-input method: the polynomial's average
            h = step_size
            st.u = u + h * (0.5 * du + h * d2u / 6.0)
        try:
            ok, msg = st.advance(t_end, max_steps=MAX_SUBSTEPS)
            if not ok:
                return self._diverged(f"integrator {st.name!r} failed between t = "
                                      f"{current_time!r} and {t_end!r}: {msg}")
            return self._check(st.y, t_end)
        except Exception as exc:          # noqa: BLE001 - an exception would be fmi2Fatal
            return self._diverged(f"integrator {st.name!r} failed between t = {current_time!r} "
                                  f"and {t_end!r}: {type(exc).__name__}: {exc}")

    def _check(self, y, t_end) -> bool:
        """Accept the state ``y`` reached at ``t_end`` unless it diverged."""
        norm2 = float(y @ y)
        if not norm2 <= STATE_NORM2_LIMIT:      # keeps every output finite (catches NaN too)
            return self._diverged(f"divergence at t = {t_end!r}: the state's norm "
                                  f"{math.sqrt(norm2)!r} exceeds 1e100 (numerical blow-up)")
        phi = float(y[1])
        if not abs(phi) <= self._phi_limit:
            return self._diverged(f"divergence at t = {t_end!r}: |phi| = {abs(phi)!r} exceeds "
                                  f"phi_limit = {self._phi_limit!r}")
        energy = None
        if self._check_energy:
            energy = self._model.energy(y)
            if not abs(energy) <= self._energy_limit:
                return self._diverged(f"divergence at t = {t_end!r}: |energy| = {abs(energy)!r} "
                                      f"exceeds energy_limit = {self._energy_limit!r}")
        self._accept(y, energy)
        return True

    def _diverged(self, message: str) -> bool:
        self._error = message + "; restore a saved FMU state to continue"
        return self._refuse(self._error)

    def _accept(self, y, energy):
        """``y`` is the new accepted state (``energy`` its energy if already computed)."""
        self._y = y.copy()
        self._energy = energy
        self._dirty = self._shape_dirty = True
        self._energy_fresh = False

    # ------------------------------------------------------------------ outputs
    def _refresh(self):
        """The sensor outputs from the last accepted state (the shape outputs and the energy
        are computed when they are read)."""
        m, y, out, vr = self._model, self._y, self._out, self._vr
        out[vr["phi_o"]], out[vr["omega_o"]] = m.tip_angle(y)
        out[vr["x_o"]] = float(y[0])
        out[vr["x_dot"]] = float(y[self._nq])
        out[vr["phi"]] = float(y[1])
        self._dirty = False

    def _refresh_shape(self):
        """Tip deflection and modal coordinates from the last accepted state."""
        y, out = self._y, self._out
        if self._n:
            out[self._vr["tip_deflection"]] = float(self._model.tip_defl @ y[2:self._nq])
            for j, vr_j in enumerate(self._vr_eta[:self._n]):
                out[vr_j] = float(y[2 + j])
        self._shape_dirty = False

    def _refresh_energy(self):
        energy = self._energy
        self._out[self._vr_energy] = self._model.energy(self._y) if energy is None else energy
        self._energy_fresh = True

    def get_real(self, vrs):
        if self._model is None and self._error is None:
            self._prepare()                    # outputs read in initialisation mode
        if self._dirty:
            self._refresh()
        if self._shape_dirty and not self._shape_vrs.isdisjoint(vrs):
            self._refresh_shape()
        if not self._energy_fresh and self._vr_energy in vrs:
            self._refresh_energy()
        out = self._out
        try:
            return [out[vr] for vr in vrs]
        except KeyError:                       # not only outputs: pythonfmu's generic path
            return super().get_real(vrs)

    def _output(self, name):
        return self.get_real([self._vr[name]])[0]

    # ------------------------------------------------------------------ FMU state
    _STATE_KEYS = ("format", "version", "model", "params", "t0", "inputs", "initialized", "error",
                   "stepper", "y")

    def _get_fmu_state(self):
        st = self._stepper
        return {**self._state_header(), "params": self._params_snapshot(), "t0": self._t0,
                "inputs": [self.F_c, self.dF_c, self.d2F_c],
                "initialized": self._initialized, "error": self._error,
                "stepper": None if st is None else st.get_state(),
                "y": None if self._y is None else self._y.tolist()}

    @classmethod
    def _check_state(cls, state):
        cls._restored(state)

    @classmethod
    def _restored(cls, state):
        """What a restore of ``state`` installs: ``(model, stepper, settings, y)`` (None for the
        parts the state has not), built from scratch; raises :class:`StateError` naming what is
        wrong (keys, types, sizes, finiteness, parameter ranges, the stepper's own checks)."""
        cls._check_keys(state, cls._STATE_KEYS)
        params = state["params"]
        names = [v.name for v in VARIABLES if v.causality == "parameter"]
        if not isinstance(params, dict) or sorted(params) != sorted(names):
            raise StateError(f"params must name exactly the parameters {names}")
        t0 = check_finite("t0", state["t0"])
        check_finite("inputs", state["inputs"], 3)
        if not isinstance(state["initialized"], bool):
            raise StateError("initialized must be true or false")
        if state["error"] is not None and not isinstance(state["error"], str):
            raise StateError("error must be null or a message")
        built = None
        try:
            built = cls._build(params, t0)
        except Exception as exc:   # noqa: BLE001 - a bad parameter
            if state["error"] is None and state["initialized"]:
                raise StateError(f"bad parameter: {exc}") from None
        if built is None:           # a state saved after a bad parameter: nothing to restore
            if state["stepper"] is not None or state["y"] is not None:
                raise StateError("a state with bad parameters cannot hold a plant state")
            return None, None, None, None
        model, stepper, s = built
        y = None
        if state["y"] is not None:
            y = np.array(check_finite("y", state["y"], stepper.nx))
        if state["stepper"] is not None:
            snap = state["stepper"]
            if not isinstance(snap, dict):
                raise StateError("stepper must be an object")
            _check_tree_finite("stepper", snap)
            try:
                stepper.set_state(snap)
            except Exception as exc:  # noqa: BLE001
                raise StateError(f"stepper: {type(exc).__name__}: {exc}") from None
            if not (np.all(np.isfinite(stepper.y)) and math.isfinite(stepper.t)):
                raise StateError("stepper: the state is not finite")
        return model, stepper, s, y

    def _set_fmu_state(self, state):
        try:
            self._check_header(state)
            model, stepper, s, y = self._restored(state)
        except Exception as exc:  # noqa: BLE001 - an exception would be fmi2Fatal
            self._restore_failed(exc)
            return
        # nothing below can fail: the instance changes all at once
        self._par, self._par_snap = dict(state["params"]), None
        self._t0 = float(state["t0"])
        if model is None:
            self._model = self._stepper = None
        else:
            self._install(model, stepper, s)
        self.F_c, self.dF_c, self.d2F_c = (float(v) for v in state["inputs"])
        self._initialized = state["initialized"]
        self._error = state["error"]
        self._terminated = False
        if y is not None:
            self._accept(y, None)
        elif stepper is not None:
            self._accept(stepper.y, None)


def _check_tree_finite(name, value, strict=False):
    """No number of a stepper snapshot is NaN; none is infinite in an array, in the time, the
    state, the step or the input (a scalar option such as ``max_step`` may be infinite)."""
    if isinstance(value, dict):
        for k, v in value.items():
            _check_tree_finite(f"{name}.{k}", v, strict or k in ("t", "y", "h", "u", "du", "d2u"))
    elif isinstance(value, list):
        for i, v in enumerate(value):
            _check_tree_finite(f"{name}[{i}]", v, True)
    elif isinstance(value, float) and (value != value or (strict and not math.isfinite(value))):
        raise StateError(f"{name} = {value!r} is not finite")
