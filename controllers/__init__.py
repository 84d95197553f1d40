"""Feedback controllers for the experiments and the control-design studies.

Every controller is an immutable design with explicit state, the verbs shared
with plants and observers::

    ctrl = tune_pid(mass, crossover_hz=100.0, fs=5000.0)   # design (frozen)
    state = ctrl.init()
    u_c, state = ctrl.step(state, y_k)                   # controller output at sample k
    ctrl.statespace()                                    # the same law as a discrete StateSpace

Sign convention: the controller output is added to the excitation at the plant
input, ``u = r + u_c``, and ``u_c = -K(z) y`` (negative feedback, set point 0);
the loop gain is ``L = G K``.
"""

from controllers.pid import ControllerState, DecentralizedController, PidChannel, tune_pid

__all__ = ["ControllerState", "DecentralizedController", "PidChannel", "tune_pid"]
