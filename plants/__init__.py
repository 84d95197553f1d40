"""The true systems the workbench is tested against.

Every plant is a simulator of the machine, not of our model of it: physical
effects (delays, extra modes, actuator and sensor dynamics, suspension,
crosstalk, nonlinearities, noise, quantization) are fields of its frozen
configuration. Identification and diagnosis code never reads those fields;
it sees only what an experiment records (see ``workbench.experiments``).

Every plant follows :class:`plants.base.Plant`::

    plant.fs, plant.n_u, plant.n_y, plant.input_names, plant.output_names
    plant.linear_model()      -> control.StateSpace (continuous, true linear part, no delay)
    plant.delay_s             -> total input delay, s
    plant.frf(freq_hz)        -> (n_f, n_y, n_u) true linear FRF with the delay
    plant.simulate(u, rng=)   -> y (N, n_y): open loop from rest, with every effect
    plant.init(rng) -> state; plant.step(state, u_k) -> (y_k, state)   (closed loop)
"""
