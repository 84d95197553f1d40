"""Feedback controllers for the experiments and the control-design studies.

Every controller implements :class:`controllers.protocol.Controller`: an
immutable design with explicit state, the verbs shared with plants and
observers::

    K = tune_pid(mass, crossover_hz=100.0, fs=5000.0)   # design (frozen)
    state = K.init()
    u, state = K.step(state, e_k)                      # e = r - y -> plant input at sample k
    K.statespace()                                     # the same law, discrete StateSpace e -> u

    workbench.sim.closed_loop(plant, K, r=..., d=..., rng=...)   # any plant, any Controller

Designs on a model (each result holds a Controller)::

    tune_pid_notch(model, fs, ms_max=2.0)            # decentralized PID + notches
    tune_modal_sf(model, ms_max=2.0, fs=fs)          # modal state feedback + observer
    tune_hinf(model, ms_max=2.0, fs=fs).controller   # per-DOF mixed-sensitivity H-inf (Riccati)
    design_mpc(model, fs, u_max=F_max)               # constrained MPC + Kalman (not linear)

Sign convention (spec section 5): ``u = K e`` with ``e = r - y``; an excitation
``d`` adds at the plant input, ``u = d + K e``; the loop gain is ``L = G K``.
:class:`StateSpaceController` wraps any discrete StateSpace or spec-5 controller file.
"""

from controllers.hinf import (
    HinfDesign,
    HinfReport,
    design_hinf_mixed,
    hinf_lmi,
    hinf_riccati,
    mixed_sensitivity,
    tune_hinf,
    weight,
)
from controllers.modal_sf import ModalSFDesign, design_modal_sf
from controllers.mpc import LinearMPC, MPCController, design_mpc
from controllers.pid import DecentralizedController, PidChannel, tune_pid
from controllers.pid_notch import (
    DecentralizedPidNotch,
    PidNotchChannel,
    PidNotchReport,
    tune_pid_notch,
)
from controllers.protocol import (
    Controller,
    ControllerState,
    StateSpaceController,
    StrictlyProper,
)

__all__ = [
    "Controller",
    "ControllerState",
    "DecentralizedController",
    "DecentralizedPidNotch",
    "HinfDesign",
    "HinfReport",
    "LinearMPC",
    "MPCController",
    "ModalSFDesign",
    "PidChannel",
    "PidNotchChannel",
    "PidNotchReport",
    "StateSpaceController",
    "StrictlyProper",
    "design_hinf_mixed",
    "design_mpc",
    "design_modal_sf",
    "hinf_lmi",
    "hinf_riccati",
    "mixed_sensitivity",
    "tune_pid",
    "tune_hinf",
    "tune_pid_notch",
    "weight",
]
