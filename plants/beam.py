"""The overactuated flexible beam of seed 001: 3 voice coils, 5 probes, on wire flexures.

A steel beam of 500 x 20 x 2 mm (structural steel, E = 210 GPa,
rho = 7850 kg/m^3) hangs on wire flexures that leave two rigid-body DOF
(out-of-plane translation and rotation); their stiffness makes these two
suspension modes of a few Hz. The beam bends about its thin direction
(I = b h^3 / 12), which puts 7 flexible modes and the 2 suspension modes below
the Nyquist frequency of 1024 Hz (fs = 2048 Hz). The moving part of each voice
coil (20 g) is a point mass on the beam. Sensor 1 is collocated with actuator 1.

Modes come from the FE model of :mod:`plants.beam_fe` (Hermite cubic elements):
mass-normalized mode shapes Phi give b_k = Phi_k(actuators) and
c_k = Phi_k(sensors). The nominal machine has the out-of-plane modes below
Nyquist; the ones above are its residual modes (``Effects.residual_max_hz``).

In-plane bending (about the wide direction, 10 x stiffer) is seen when a
sensor or an actuator is tilted by an angle gamma: the probe reads
cos(gamma) w + sin(gamma) v, the coil pushes cos(gamma) F out of plane and
sin(gamma) F in plane. In plane the wire flexures are stiff
(``inplane_support_npm``). Those modes are not in the nominal description
(kind 'extra'); seed 001 saw them at 572 Hz and 649 Hz through a tilted sensor.

Damping (modal, proportional): suspension modes ``suspension_damping``;
flexible modes z = damping_base + damping_slope f / 1 kHz, capped at 0.02.

References
----------
Seed 001, section 7.1 (beam 2 x 20 x 500 mm, 3 actuators, 5 sensors, 2048 Hz,
sensor 1 collocated with actuator 1, in-plane mode seen by a tilted sensor).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any

import numpy as np

from workbench.core.errors import InputError

from . import beam_fe
from .effects import Effects
from .mechanical import MechanicalPlant, chain_statespace, check_field_names, replace_effects
from .modal import LinearChain, ModalSet

__all__ = [
    "BeamConfig",
    "beam",
    "beam_prior_config",
    "beam_prior_model",
    "beam_fe_model",
    "beam_modes",
    "beam_fe_file",
]


@dataclass(frozen=True)
class BeamConfig:
    """Machine parameters of the beam (the true machine by default).

    Parameters
    ----------
    length_m, width_m, thickness_m : float
        Beam dimensions, m.
    youngs_modulus_pa : float
        Young's modulus, Pa.
    density_kgm3 : float
        Density, kg/m^3.
    flexure_positions_m : (2,) tuple
        Positions of the two vertical wire-flexure pairs along the beam, m.
    flexure_stiffness_npm : (2,) tuple
        Their out-of-plane stiffness, N/m.
    inplane_support_npm : float
        In-plane stiffness of each flexure support, N/m.
    actuator_positions_m : (3,) tuple
        Voice coil positions, m.
    actuator_mass_kg : float
        Moving mass of each voice coil on the beam, kg.
    sensor_positions_m : (5,) tuple
        Probe positions, m (sensor 1 at actuator 1).
    sensor_tilt_rad, actuator_tilt_rad : tuples
        Tilt of each probe (5) and coil (3) towards the in-plane direction, rad.
        The coils are mounted to within about 1 degree (default), so a tilted
        probe sees the in-plane modes; the probes are aligned by default.
    n_elements : int
        FE elements.
    suspension_damping, damping_base, damping_slope : float
        Modal damping model, - (slope per kHz).
    fs : float
        Sampling frequency, Hz.
    noise_std : float
        White noise of each probe, m.
    quantization : float
        Probe read-out resolution, m.
    """

    length_m: float = 0.5
    width_m: float = 0.02
    thickness_m: float = 0.002
    youngs_modulus_pa: float = 210e9
    density_kgm3: float = 7850.0
    flexure_positions_m: tuple[float, float] = (0.1, 0.4)
    flexure_stiffness_npm: tuple[float, float] = (30.0, 45.0)
    inplane_support_npm: float = 2e4
    actuator_positions_m: tuple[float, float, float] = (0.05, 0.25, 0.45)
    actuator_mass_kg: float = 0.02
    sensor_positions_m: tuple[float, ...] = (0.05, 0.16, 0.27, 0.37, 0.48)
    sensor_tilt_rad: tuple[float, ...] = (0.0, 0.0, 0.0, 0.0, 0.0)
    actuator_tilt_rad: tuple[float, ...] = (0.015, -0.01, 0.02)
    n_elements: int = 50
    suspension_damping: float = 0.02
    damping_base: float = 0.005
    damping_slope: float = 0.01
    fs: float = 2048.0
    noise_std: float = 10e-9
    quantization: float = 5e-9

    def __post_init__(self):
        for name in ("flexure_positions_m", "flexure_stiffness_npm", "actuator_positions_m"):
            object.__setattr__(self, name, tuple(float(v) for v in getattr(self, name)))
        for name in ("sensor_positions_m", "sensor_tilt_rad", "actuator_tilt_rad"):
            object.__setattr__(self, name, tuple(float(v) for v in getattr(self, name)))
        if len(self.flexure_positions_m) != 2 or len(self.flexure_stiffness_npm) != 2:
            raise InputError("BeamConfig: expected two flexure positions and two stiffnesses")
        if len(self.sensor_tilt_rad) != len(self.sensor_positions_m):
            raise InputError(
                f"BeamConfig.sensor_tilt_rad: expected {len(self.sensor_positions_m)} angles, "
                f"got {len(self.sensor_tilt_rad)}"
            )
        if len(self.actuator_tilt_rad) != len(self.actuator_positions_m):
            raise InputError(
                f"BeamConfig.actuator_tilt_rad: expected {len(self.actuator_positions_m)} angles, "
                f"got {len(self.actuator_tilt_rad)}"
            )
        for x in self.flexure_positions_m + self.actuator_positions_m + self.sensor_positions_m:
            if not 0.0 <= x <= self.length_m:
                raise InputError(
                    f"BeamConfig: position {x!r} m is off the beam [0, {self.length_m}] m"
                )
        if min(self.youngs_modulus_pa, self.density_kgm3, *self.flexure_stiffness_npm) <= 0:
            raise InputError(
                "BeamConfig: Young's modulus, density and flexure stiffnesses must be > 0"
            )

    @property
    def alpha(self) -> np.ndarray:
        """Update parameters (E, rho, k_1, k_2) in the order of ``beam_fe.PARAMETER_NAMES``."""
        return np.array([self.youngs_modulus_pa, self.density_kgm3, *self.flexure_stiffness_npm])


def beam_fe_model(config: BeamConfig | None = None, *, in_plane: bool = False) -> beam_fe.FEModel:
    """Parameter matrices K_i, M_i of the beam (out of plane by default), for model updating."""
    cfg = BeamConfig() if config is None else config
    return beam_fe.parameter_matrices(
        length_m=cfg.length_m,
        width_m=cfg.width_m,
        thickness_m=cfg.thickness_m,
        n_elements=cfg.n_elements,
        flexure_positions_m=cfg.flexure_positions_m,
        lumped_masses=tuple((x, cfg.actuator_mass_kg) for x in cfg.actuator_positions_m),
        in_plane=in_plane,
    )


def beam_fe_file(config: BeamConfig | None = None, *, damping: float = 0.01):
    """The beam's out-of-plane FE model as a spec-4 :class:`workbench.fe.model.FEModel`.

    ``config`` supplies the parameters written as ``alpha`` (the true machine by
    default; pass :func:`beam_prior_config` for the nominal/prior file). Inputs
    F1..F3 at the actuators, outputs s1..s5 at the sensors (tilt not modelled:
    the file is the out-of-plane model), ``damping`` for every mode.
    """
    from workbench.fe.model import fe_from_arrays

    cfg = BeamConfig() if config is None else config
    fe = beam_fe_model(cfg)
    B = np.array([fe.point(x) for x in cfg.actuator_positions_m]).T
    C = np.array([fe.point(x) for x in cfg.sensor_positions_m])
    names = [f"F{i + 1}" for i in range(B.shape[1])], [f"s{i + 1}" for i in range(C.shape[0])]
    return fe_from_arrays(
        {
            "kind": np.array("fe"),
            "K0": fe.K0,
            "M0": fe.M0,
            "K_i": fe.K_i,
            "M_i": fe.M_i,
            "alpha": cfg.alpha,
            "parameter_names": np.array(beam_fe.PARAMETER_NAMES),
            "B": B,
            "C": C,
            "damping": np.array(float(damping)),
            "input_names": np.array(names[0]),
            "output_names": np.array(names[1]),
        },
        src="beam FE model",
    )


def _damping(cfg: BeamConfig, f: np.ndarray, n_susp: int) -> np.ndarray:
    z = np.minimum(cfg.damping_base + cfg.damping_slope * f / 1000.0, 0.02)
    z[:n_susp] = cfg.suspension_damping
    return z


def beam_modes(config: BeamConfig | None = None, *, in_plane: bool = False) -> ModalSet:
    """All FE modes of the beam at its actuators (b) and sensors (c), without tilt.

    Returns
    -------
    ModalSet
        freq_hz ascending; the first two are the suspension modes
        (kind 'suspension'), the others 'flexible'.
    """
    cfg = BeamConfig() if config is None else config
    fe = beam_fe_model(cfg, in_plane=in_plane)
    alpha = cfg.alpha.copy()
    if in_plane:
        alpha[2:] = cfg.inplane_support_npm
    K, M = beam_fe.assemble(fe, alpha)
    f, Phi = beam_fe.solve_modes(K, M)
    Pa = np.array([fe.point(x) for x in cfg.actuator_positions_m])  # (n_a, n_dof)
    Ps = np.array([fe.point(x) for x in cfg.sensor_positions_m])
    b = (Pa @ Phi).T  # (n_modes, n_a)
    c = (Ps @ Phi).T
    kind = ("suspension",) * 2 + ("flexible",) * (f.size - 2)
    return ModalSet(f, _damping(cfg, f, 2), b, c, kind)


def beam(*, config: BeamConfig | None = None, effects: Effects | None = None, **changes: Any):
    """The overactuated beam plant.

    Parameters
    ----------
    config : BeamConfig, optional
        Machine parameters; default the true machine.
    effects : Effects, optional
        Base effects; default all off (no delay).
    **changes
        ``Effects`` fields to change on the base; an unknown name is an error.

    Returns
    -------
    MechanicalPlant
        Inputs F1, F2, F3 (N); outputs s1..s5 (m).

    Examples
    --------
    >>> plant = beam()
    >>> plant.n_u, plant.n_y, plant.fs
    (3, 5, 2048.0)
    """
    cfg = BeamConfig() if config is None else config
    eff = replace_effects(Effects() if effects is None else effects, changes)
    modes = beam_modes(cfg)
    ca, sa = np.cos(cfg.actuator_tilt_rad), np.sin(cfg.actuator_tilt_rad)
    cs, ss = np.cos(cfg.sensor_tilt_rad), np.sin(cfg.sensor_tilt_rad)
    out = dataclasses.replace(modes, b=modes.b * ca, c=modes.c * cs)
    nyq = cfg.fs / 2
    inherent = None
    if np.any(sa) and np.any(ss):
        ip = beam_modes(cfg, in_plane=True)
        inherent = ModalSet(ip.freq_hz, ip.damping, ip.b * sa, ip.c * ss, ("extra",) * ip.n_modes)
    n_y = len(cfg.sensor_positions_m)
    return MechanicalPlant(
        name="beam",
        fs=float(cfg.fs),
        input_names=tuple(f"F{i + 1}" for i in range(len(cfg.actuator_positions_m))),
        output_names=tuple(f"s{i + 1}" for i in range(n_y)),
        nominal_modes=out.select(out.freq_hz < nyq),
        residual_modes=dataclasses.replace(
            out.select(out.freq_hz >= nyq), kind=("residual",) * int(np.sum(out.freq_hz >= nyq))
        ),
        effects=eff,
        raw_map=np.eye(n_y),
        decouple=np.eye(n_y),
        noise_std=np.full(n_y, cfg.noise_std),
        quantization=float(cfg.quantization),
        inherent_modes=inherent,
    )


#: How the prior FE model is wrong: stiffer, as FE models of real setups are
#: (seed 001, section 7.5: the non-updated model overestimates the eigenfrequencies).
PRIOR_YOUNGS_MODULUS_FACTOR = 1.08
PRIOR_FLEXURE_STIFFNESS_FACTOR = 1.3


def beam_prior_config(config: BeamConfig | None = None) -> BeamConfig:
    """The prior (design) FE configuration: E +8 %, flexures +30 % stiffer than ``config``."""
    cfg = BeamConfig() if config is None else config
    return dataclasses.replace(
        cfg,
        youngs_modulus_pa=cfg.youngs_modulus_pa * PRIOR_YOUNGS_MODULUS_FACTOR,
        flexure_stiffness_npm=tuple(
            k * PRIOR_FLEXURE_STIFFNESS_FACTOR for k in cfg.flexure_stiffness_npm
        ),
    )


def beam_prior_model(config: BeamConfig | None = None, *, max_freq_hz: float | None = None):
    """Modal state-space model of the prior FE beam, continuous, no delay.

    Parameters
    ----------
    config : BeamConfig, optional
        The true machine whose prior is wanted (default the default beam).
    max_freq_hz : float, optional
        Keep modes up to this frequency, Hz; default Nyquist.

    Returns
    -------
    control.StateSpace
        Inputs F1..F3 (N), outputs s1..s5 (m); states (q_k, dq_k/dt) per mode.
    """
    prior = beam_prior_config(config)
    limit = prior.fs / 2 if max_freq_hz is None else float(max_freq_hz)
    modes = beam_modes(prior)
    n_a, n_s = len(prior.actuator_positions_m), len(prior.sensor_positions_m)
    return chain_statespace(
        LinearChain(modes.select(modes.freq_hz < limit)),
        [f"F{i + 1}" for i in range(n_a)],
        [f"s{i + 1}" for i in range(n_s)],
    )


def beam_config(**fields: Any) -> BeamConfig:
    """A :class:`BeamConfig` with some fields changed; unknown names are an error."""
    check_field_names(BeamConfig, fields, "BeamConfig")
    return BeamConfig(**fields)
