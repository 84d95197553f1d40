"""The 6-DOF short-stroke wafer stage of seed 000 as a physical model.

A chuck of 20 kg, driven by 8 Lorentz actuators (4 planar, 4 vertical) through
a gain-balancing matrix, measured by a 9-axis interferometer whose readings are
decoupled to the 6 DOF x, y, z, Rx, Ry, Rz about the centre of gravity.

Physics, in order of construction:

1. Rigid body: mass m and principal inertias J about the centre of gravity
   (origin). A point p moves by d = t + theta x p (small rotations).
2. Actuators a = 1..8 at p_a with force direction n_a: the wrench on the body
   is Gamma f, Gamma[:, a] = [n_a; p_a x n_a] (6 x 8). The machine's
   gain-balancing matrix is W = pinv(Gamma) (8 x 6), so the plant input
   F = (Fx, Fy, Fz, Tx, Ty, Tz) gives actuator forces f = W F, and
   Gamma W = I decouples the rigid body.
3. Interferometer axes i = 1..9 at p_i along e_i read e_i . d(p_i); for the
   rigid body r = M_s q with M_s[i] = [e_i, p_i x e_i] (9 x 6). The machine
   decouples with T = pinv(M_s) (6 x 9), T M_s = I.
4. Flexible modes: out-of-plane deformation fields w(x, y) of the chuck, a
   plate of thickness h, with Kirchhoff kinematics u = -z dw/dx,
   v = -z dw/dy. The fields are made mass-orthogonal to the rigid-body motions
   and to each other (Gram-Schmidt in the mass inner product on a grid of the
   plate) and mass-normalized. Mode 1 (913.8 Hz, 0.0091) is the torsion of the
   chuck, w ~ x y; mode 2 (1032 Hz, 0.0095) its saddle bending,
   w ~ x^2 - y^2; small asymmetric terms (the chuck is not symmetric: mirror
   blocks, a cable side) make them show a little in the planar DOFs.
5. Modal participation: b_k = (n_a . phi_k(p_a))_a W (input, per DOF force),
   c_k = T (e_i . phi_k(p_i))_i (output); rigid modes have b = c = e_j / sqrt(m_j).

References
----------
Seed 000 (wafer stage: 9-axis interferometer, 0.15 nm resolution, 8 motors,
6 DOF, 5 kHz, modes 913.8 Hz and 1032 Hz, Table 1 damping 0.0091 and 0.0095).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from workbench.core.errors import InputError

from .effects import Effects
from .mechanical import MechanicalPlant, check_field_names, replace_effects
from .modal import ModalSet

__all__ = [
    "StageConfig",
    "wafer_stage",
    "stage_geometry",
    "frame_rotation_crosstalk",
    "INPUT_NAMES",
    "OUTPUT_NAMES",
]

INPUT_NAMES = ("Fx", "Fy", "Fz", "Tx", "Ty", "Tz")
OUTPUT_NAMES = ("x", "y", "z", "Rx", "Ry", "Rz")

#: Actuator points (m, about the centre of gravity) and force directions.
#: X1, X2 drive x under the chuck at y ~ +-0.16 m; Y1, Y2 drive y at x ~ +-0.18 m;
#: the planar motors act 20-25 mm below the centre of gravity; Z1..Z4 near the
#: corners. The layout is not exactly symmetric (mirror blocks, cable side), so
#: the balanced DOF commands excite the flexible modes in several DOFs.
ACTUATOR_POSITIONS_M = (
    (0.01, 0.16, -0.02),
    (-0.01, -0.15, -0.025),
    (0.18, 0.01, -0.02),
    (-0.17, -0.01, -0.025),
    (0.17, 0.15, -0.03),
    (-0.15, 0.16, -0.03),
    (-0.17, -0.13, -0.03),
    (0.16, -0.15, -0.03),
)
ACTUATOR_DIRECTIONS = ((1, 0, 0),) * 2 + ((0, 1, 0),) * 2 + ((0, 0, 1),) * 4

#: Interferometer axes: 3 on the x mirror (x, Rz, Ry), 3 on the y mirror
#: (y, Rz, Rx), 3 vertical axes on z mirrors (z, Rx, Ry).
SENSOR_POSITIONS_M = (
    (0.22, 0.12, 0.0),
    (0.22, -0.12, 0.0),
    (0.22, 0.0, -0.05),
    (0.12, 0.20, 0.0),
    (-0.12, 0.20, 0.0),
    (0.0, 0.20, -0.05),
    (0.15, 0.13, -0.03),
    (-0.15, 0.13, -0.03),
    (0.02, -0.16, -0.03),
)
SENSOR_DIRECTIONS = ((1, 0, 0),) * 3 + ((0, 1, 0),) * 3 + ((0, 0, 1),) * 3


@dataclass(frozen=True)
class StageConfig:
    """Machine parameters of the wafer stage (the nominal machine).

    Parameters
    ----------
    mass_kg : float
        Moving mass of the short-stroke chuck, kg.
    inertia_kgm2 : (3,) tuple
        Principal inertias Jxx, Jyy, Jzz about the centre of gravity, kg m^2.
    plate_m : (3,) tuple
        Length, width, thickness of the plate that carries the mass for the
        deformation shapes (modal mass of the flexible modes), m.
    flex_freq_hz, flex_damping : tuples
        Flexible modes below Nyquist: torsion and saddle bending, Hz and -.
    residual_freq_hz : tuple
        Higher chuck modes (above Nyquist, switched on by
        ``Effects.residual_max_hz``), Hz.
    residual_damping : float
        Their damping ratio, -.
    fs : float
        Sampling frequency, Hz.
    noise_std : float
        White noise of each interferometer axis, m.
    quantization : float
        Interferometer resolution, m.
    """

    mass_kg: float = 20.0
    inertia_kgm2: tuple[float, float, float] = (0.38, 0.46, 0.58)
    plate_m: tuple[float, float, float] = (0.44, 0.40, 0.06)
    flex_freq_hz: tuple[float, ...] = (913.8, 1032.0)
    flex_damping: tuple[float, ...] = (0.0091, 0.0095)
    residual_freq_hz: tuple[float, ...] = (2650.0, 3400.0, 4700.0, 6100.0)
    residual_damping: float = 0.01
    fs: float = 5000.0
    noise_std: float = 0.5e-9
    quantization: float = 0.15e-9

    def __post_init__(self):
        if not self.mass_kg > 0 or len(self.inertia_kgm2) != 3 or min(self.inertia_kgm2) <= 0:
            raise InputError(
                f"StageConfig: expected mass_kg > 0 and three inertias > 0, "
                f"got {self.mass_kg!r}, {self.inertia_kgm2!r}"
            )
        Jx, Jy, Jz = self.inertia_kgm2
        if Jx + Jy < Jz or Jy + Jz < Jx or Jz + Jx < Jy:
            raise InputError(
                f"StageConfig.inertia_kgm2: principal inertias must satisfy the triangle "
                f"inequalities (Jx + Jy >= Jz, ...), got {self.inertia_kgm2!r}"
            )
        if len(self.flex_freq_hz) != len(self.flex_damping) or len(self.flex_freq_hz) > 2:
            raise InputError(
                "StageConfig: flex_freq_hz and flex_damping need equal lengths (at most 2 modes), "
                f"got {self.flex_freq_hz!r} and {self.flex_damping!r}"
            )
        if len(self.residual_freq_hz) > 4:
            raise InputError(
                f"StageConfig.residual_freq_hz: at most 4 modes, got {self.residual_freq_hz!r}"
            )


def _rigid_rows(points: np.ndarray, dirs: np.ndarray) -> np.ndarray:
    """[e, p x e] per point: reading of e . d(p) for the rigid motion (t, theta), (n, 6)."""
    return np.hstack([dirs, np.cross(points, dirs)])


def stage_geometry() -> dict[str, np.ndarray]:
    """Actuator and sensor geometry, and the machine's balancing and decoupling matrices.

    Returns
    -------
    dict with
        ``Gamma`` (6, 8): wrench about the centre of gravity per actuator force, (N, N m)/N.
        ``W`` (8, 6): gain-balancing matrix, actuator force per DOF command.
        ``M_s`` (9, 6): interferometer reading per DOF displacement, m/(m, rad).
        ``T`` (6, 9): decoupling, DOF per interferometer reading.
    """
    pa = np.array(ACTUATOR_POSITIONS_M, float)
    na = np.array(ACTUATOR_DIRECTIONS, float)
    ps = np.array(SENSOR_POSITIONS_M, float)
    es = np.array(SENSOR_DIRECTIONS, float)
    Gamma = _rigid_rows(pa, na).T
    M_s = _rigid_rows(ps, es)
    return {"Gamma": Gamma, "W": np.linalg.pinv(Gamma), "M_s": M_s, "T": np.linalg.pinv(M_s)}


def _deformation_fields(plate_m) -> list:
    """Out-of-plane shape functions w(xi, eta) and their gradients, xi = 2x/L, eta = 2y/B.

    Two control-relevant shapes (torsion, saddle) then four higher ones.
    """

    # each entry: (w, dw/dxi, dw/deta) as functions of (xi, eta)
    def torsion(x, y):
        return x * y + 0.08 * x**2 + 0.05 * y, y + 0.16 * x, x + 0.05

    def saddle(x, y):
        return x**2 - y**2 + 0.10 * x * y + 0.06 * x, 2 * x + 0.10 * y + 0.06, -2 * y + 0.10 * x

    def torsion2(x, y):
        return x * y * (x**2 + y**2), 3 * x**2 * y + y**3, x**3 + 3 * x * y**2

    def drum(x, y):
        return x**2 + y**2 + 0.1 * x, 2 * x + 0.1, 2 * y

    def bend_x(x, y):
        return x**3 - 0.6 * x + 0.1 * y, 3 * x**2 - 0.6, 0.1

    def bend_y(x, y):
        return y**3 - 0.6 * y, 0 * x, 3 * y**2 - 0.6

    return [torsion, saddle, torsion2, drum, bend_x, bend_y]


def _field_values(shape, points: np.ndarray, plate_m) -> np.ndarray:
    """3-D displacement (n, 3) of ``shape`` at points (n, 3), Kirchhoff kinematics, m per unit."""
    L, B, _ = plate_m
    xi, eta, z = 2 * points[:, 0] / L, 2 * points[:, 1] / B, points[:, 2]
    w, dw_dxi, dw_deta = (np.broadcast_to(v, xi.shape) for v in shape(xi, eta))
    # u = -z dw/dx, v = -z dw/dy (plane sections stay normal to the mid-plane)
    return np.stack([-z * dw_dxi * 2 / L, -z * dw_deta * 2 / B, w], axis=1)


def _rigid_values(points: np.ndarray) -> np.ndarray:
    """Displacement fields (6, n, 3) of the unit rigid motions t = e_j, theta = e_j."""
    out = np.zeros((6, points.shape[0], 3))
    for j in range(3):
        out[j, :, j] = 1.0
        e = np.zeros(3)
        e[j] = 1.0
        out[3 + j] = np.cross(e, points)
    return out


def _mode_shapes(cfg: StageConfig, n_flex: int):
    """Mass-orthonormal flexible mode shapes as a function of points.

    Returns a callable ``phi(points) -> (n_flex, n, 3)`` (m/sqrt(kg)).
    """
    L, B, h = cfg.plate_m
    g = (np.arange(16) + 0.5) / 16
    gz = (np.arange(4) + 0.5) / 4
    X, Y, Z = np.meshgrid((g - 0.5) * L, (g - 0.5) * B, (gz - 0.5) * h, indexing="ij")
    grid = np.stack([X.ravel(), Y.ravel(), Z.ravel()], axis=1)
    dm = cfg.mass_kg / grid.shape[0]
    shapes = _deformation_fields(cfg.plate_m)[:n_flex]

    def raw(points):
        rig = _rigid_values(points)
        fl = np.array([_field_values(s, points, cfg.plate_m) for s in shapes])
        return np.concatenate([rig, fl])  # (6 + n_flex, n, 3)

    F = raw(grid)
    G = dm * np.einsum("ipd,jpd->ij", F, F)  # mass Gram matrix
    Lc = np.linalg.cholesky(G)
    Linv = np.linalg.inv(Lc)  # rows: Gram-Schmidt in order, rigid first

    def phi(points):
        return np.einsum("ij,jpd->ipd", Linv, raw(np.atleast_2d(points)))[6:]

    return phi


def _modal_sets(cfg: StageConfig) -> tuple[ModalSet, ModalSet]:
    geo = stage_geometry()
    n_fl, n_res = len(cfg.flex_freq_hz), len(cfg.residual_freq_hz)
    # the residual shapes sit after the two control-relevant ones
    phi = _mode_shapes(cfg, 2 + n_res)
    pa = np.array(ACTUATOR_POSITIONS_M, float)
    na = np.array(ACTUATOR_DIRECTIONS, float)
    ps = np.array(SENSOR_POSITIONS_M, float)
    es = np.array(SENSOR_DIRECTIONS, float)
    at_act = np.einsum("kpd,pd->kp", phi(pa), na)  # (n_modes, 8)
    at_sen = np.einsum("kpd,pd->kp", phi(ps), es)  # (n_modes, 9)
    b_fl = at_act @ geo["W"]  # (n_modes, 6) modal force per DOF command
    c_fl = at_sen @ geo["T"].T  # (n_modes, 6) DOF output per modal displacement
    m_dof = np.array([cfg.mass_kg] * 3 + list(cfg.inertia_kgm2))
    rig = np.diag(1.0 / np.sqrt(m_dof))
    idx_fl = np.arange(n_fl)
    nominal = ModalSet(
        np.concatenate([np.zeros(6), cfg.flex_freq_hz]),
        np.concatenate([np.zeros(6), cfg.flex_damping]),
        np.vstack([rig, b_fl[idx_fl]]),
        np.vstack([rig, c_fl[idx_fl]]),
        ("rigid",) * 6 + ("flexible",) * n_fl,
    )
    idx_res = 2 + np.arange(n_res)
    residual = ModalSet(
        np.array(cfg.residual_freq_hz, float),
        np.full(n_res, cfg.residual_damping),
        b_fl[idx_res].reshape(n_res, 6),
        c_fl[idx_res].reshape(n_res, 6),
        ("residual",) * n_res,
    )
    return nominal, residual


def frame_rotation_crosstalk(angles_rad) -> np.ndarray:
    """Crosstalk matrix (6, 6) of a small rotation of a measurement (or actuation) frame.

    Parameters
    ----------
    angles_rad : (3,) sequence
        Small rotation (about x, y, z) of the frame in which the DOFs are
        measured, rad.

    Returns
    -------
    (6, 6) array
        X such that the misaligned frame reads (I + X) [t; theta]: translations
        and rotations are both rotated, t' = t - omega x t.

    Examples
    --------
    >>> X = frame_rotation_crosstalk([0.0, 0.0, 1e-3])
    >>> float(X[0, 1]), float(X[1, 0])
    (0.001, -0.001)
    """
    w = np.asarray(angles_rad, float).reshape(3)
    skew = np.array([[0, -w[2], w[1]], [w[2], 0, -w[0]], [-w[1], w[0], 0]])
    X = np.zeros((6, 6))
    X[:3, :3] = -skew
    X[3:, 3:] = -skew
    return X


#: The nominal machine's effects: the one-sample computation delay of the 5 kHz loop.
NOMINAL_STAGE_EFFECTS = Effects(delay_s=2e-4)


def wafer_stage(
    *, config: StageConfig | None = None, effects: Effects | None = None, **changes: Any
):
    """The 6-DOF wafer stage plant.

    Parameters
    ----------
    config : StageConfig, optional
        Machine parameters; default the nominal machine.
    effects : Effects, optional
        Base effects; default ``Effects(delay_s=2e-4)`` (one sample of
        computation delay, every other effect off).
    **changes
        ``Effects`` fields to change on the base, e.g. ``sensor_cutoff_hz=2000.0``.
        An unknown name is an error.

    Returns
    -------
    MechanicalPlant
        Inputs Fx, Fy, Fz (N), Tx, Ty, Tz (N m); outputs x, y, z (m), Rx, Ry, Rz (rad).

    Examples
    --------
    >>> plant = wafer_stage(delay_s=0.0)
    >>> plant.n_u, plant.n_y, plant.fs
    (6, 6, 5000.0)
    """
    cfg = StageConfig() if config is None else config
    base = NOMINAL_STAGE_EFFECTS if effects is None else effects
    eff = replace_effects(base, changes)
    nominal, residual = _modal_sets(cfg)
    geo = stage_geometry()
    return MechanicalPlant(
        name="wafer_stage",
        fs=float(cfg.fs),
        input_names=INPUT_NAMES,
        output_names=OUTPUT_NAMES,
        nominal_modes=nominal,
        residual_modes=residual,
        effects=eff,
        raw_map=geo["M_s"],
        decouple=geo["T"],
        noise_std=np.full(9, cfg.noise_std),
        quantization=float(cfg.quantization),
    )


def stage_config(**fields: Any) -> StageConfig:
    """A :class:`StageConfig` with some fields changed; unknown names are an error."""
    check_field_names(StageConfig, fields, "StageConfig")
    return StageConfig(**fields)
