"""The plant file's schema: its keys, their meaning and the limits of its numbers.

A plant file is YAML (see ``config/systems/``). The plant is a hybrid automaton
(Heracleous et al., eq. 1-3): named states, inputs and outputs; modes, each with linear or
affine dynamics (continuous or discrete time) or a named nonlinear model; guards, each
autonomous (on a state) or controlled (on an input); bounds on measurement noise,
disturbances and per-mode modelling uncertainty; fault channels; a sample time; an initial
mode and state.

Schema (``format_version: 1``)::

    format_version: 1
    name: pwa_cascade                 # identifier, [A-Za-z0-9_]+
    description: free text            # not part of the plant's identity
    time: continuous                  # continuous | discrete (default of every mode)
    sample_time: 0.01                 # s, > 0
    states: [x1, x2, b1, b2]
    inputs: []                        # may be empty
    outputs: [y1, y2]
    disturbances: [w1, w2, w3, w4]    # bounded unknown inputs w (may be empty)
    bounds:
      disturbance: [1.0, 1.0, 1.0, 1.0]    # |w_i| <= bound, one per disturbance
      measurement_noise: [0.0, 0.0]        # |v_i| <= bound, one per output
    shared: {B: ..., C: ..., D: ..., E: ...}  # defaults for every mode that omits them
    modes:
      safe:
        dynamics: linear              # linear | nonlinear
        time: continuous              # optional override of the plant's default
        A: [[...]]                    # n x n
        B: [[...]]                    # n x nu (default zeros)
        C: [[...]]                    # ny x n (required, here or in shared)
        D: [[...]]                    # n x nw (default zeros)
        E: [[...]]                    # ny x nw (default zeros)
        offset: [...]                 # n, affine term (default zeros)
        uncertainty: [...]            # n, |eta_i| <= bound added to x_{k+1} (default zeros)
      tank_mode:
        dynamics: nonlinear
        model: three_tank             # a model of fd_monitor.model.nonlinear
        params: {name: value, ...}    # checked against the model's parameter list
        C: ...                        # as above
    guards:
      - name: g_safe_to_x2            # optional; default "<from>-><to>"
        from: safe
        to: x2_high
        kind: autonomous              # autonomous (conditions on states) | controlled (on inputs)
        when: [{var: x2, op: ">", value: 0.4}]   # all conditions must hold
    faults:
      - {name: bias_y1, kind: sensor_bias, output: y1}      # y_i += f
      - {name: act_u1, kind: actuator, input: u1}           # u_j += f (in the plant only)
      - {name: b1_step, kind: state_jump, state: b1}        # x_j jumps by the change of f
      - {name: leak, kind: process, F: [1.0, 0.0, 0.0]}     # dx (or x_{k+1}) += F f
      - {name: gust, kind: process, F: {safe: [...], x2_high: [...]},   # F per mode
         E: [0.0, 1.0]}                                                # optional: y += E f
      - {name: leak1, kind: parameter, parameter: leak_area_1}  # model parameter += f
    initial:
      mode: safe
      state: [0.0, 0.6, 0.0, 0.1]
    switching: guards                 # optional: guards (default) | arbitrary (any mode
                                      # sequence, e.g. the switched designs of Farhat & Koenig)
    lpv:                              # optional: parameter-dependent linear modes
      parameters:
        - {name: rho1, min: -1.0, max: 1.0, measured: true}   # measured: false = uncertain
    # and in a linear mode:  A_rho: [A_1, ..., A_d] (d x n x n), B_rho (d x n x nu)
    # so that A(rho) = A + sum_j rho_j A_j, B(rho) = B + sum_j rho_j B_j (thesis 5.2, 6.5).
    limits:                           # optional: the physical range of what is measured
      outputs: {y1: [-1.0, 1.0]}      # [min, max] per output (any subset), output units
      inputs: {u1: [0.0, 2.0]}        # [min, max] per input (any subset)
    units:                            # optional: the unit of each channel ("-" if none);
      outputs: {y1: m, y2: m}         # used in reports and plots, never in arithmetic
      states: {x1: m}                 # (any subset of states, inputs, outputs)
    envelope:                         # optional: the declared operating envelope (the
      states: {x1: [0.0, 1.0], ...}   # region a `thresholds` design certifies and the
      inputs: {u1: [-1.0, 1.0], ...}  # runtime checks); every state and input needs a
      modes: {safe: {states: {x2: [0.0, 0.4]}}}   # range; `modes` narrows them per mode

``units`` name the unit of each state, input and output (reports and plots label their
axes with them); like ``limits`` and ``description`` they do not enter the canonical form.

``limits`` say what a sensor or an actuator command can physically read: a sample outside
them is implausible and refused where samples enter the runtime
(:mod:`fd_monitor.core.plausibility`), like a NaN. A channel without limits may read any
value of magnitude <= MAX_MAGNITUDE. Limits describe the instruments, not the dynamics,
so they do not enter the plant's canonical form (its SHA-256).

The optional keys ``switching``, ``lpv``, ``A_rho``, ``B_rho`` and a process fault's ``E`` or
per-mode ``F`` enter the plant's canonical form (its SHA-256) only when they are given, so
the identity of a plant file without them does not depend on their existence.

Semantics: in mode ``q`` a continuous-time linear mode is ``dx/dt = A x + B u + D w + offset``
(discretised exactly with zero-order hold on u and w, see :mod:`fd_monitor.core.plant`); a
discrete-time one is ``x_{k+1} = A x_k + B u_k + D w_k + offset``; a nonlinear one is
``x_{k+1} = model(x_k, u_k, params) + D w_k``. Outputs are ``y_k = C x_k + E w_k + v_k`` plus
sensor faults. The modelling uncertainty ``eta_k`` (``|eta_i| <= uncertainty_i`` of the
current mode) is added to ``x_{k+1}``. Guards are checked at every sample on ``x_{k+1}``
(autonomous) or ``u_k`` (controlled); the first guard of the current mode that holds fires.

Every validation error names the file, the key path and what was expected.
"""

from __future__ import annotations

__all__ = ["FAULT_KINDS", "GUARD_OPS", "MAX_MAGNITUDE", "MODE_KEYS", "SAMPLE_TIME_RANGE",
           "SUPPORTED_FORMAT_VERSIONS", "TIME_KINDS", "TOP_KEYS"]

SUPPORTED_FORMAT_VERSIONS = (1,)
#: Comparison operators of a guard condition.
GUARD_OPS = ("<", "<=", ">", ">=", "==")
FAULT_KINDS = ("sensor_bias", "actuator", "state_jump", "process", "parameter")
TIME_KINDS = ("continuous", "discrete")
#: Keys of a plant file's top level and of one mode.
TOP_KEYS = {
    "format_version", "name", "description", "time", "sample_time", "states", "inputs",
    "outputs", "disturbances", "bounds", "shared", "modes", "guards", "faults", "initial",
    "switching", "lpv", "limits", "envelope", "units",
}
MODE_KEYS = {
    "dynamics", "time", "A", "B", "C", "D", "E", "offset", "uncertainty", "model", "params",
    "description", "A_rho", "B_rho",
}
#: Largest magnitude of a number in a plant file: beyond, products in the simulation and
#: the designs overflow float64 (1e308) or lose every digit.
MAX_MAGNITUDE = 1.0e15
#: Sample times accepted, s (1 MHz .. 1e6 s).
SAMPLE_TIME_RANGE = (1.0e-6, 1.0e6)
