"""Euler-Bernoulli finite elements of a slender beam, affine in its update parameters.

Hermite cubic elements with two degrees of freedom per node (deflection w, m,
and slope dw/dx, rad). The model is written as

    K(alpha) = K0 + sum_i alpha_i K_i,   M(alpha) = M0 + sum_i alpha_i M_i,

with alpha = (Young's modulus E in Pa, density rho in kg/m^3, flexure
stiffnesses k_1, k_2 in N/m), so it can be updated (methods.md, section 5):
E multiplies the bending stiffness, rho the distributed mass, each k_i a spring
to the world at a flexure position; lumped masses (actuator moving parts) are
in M0.

References
----------
M. Petyt, Introduction to Finite Element Vibration Analysis, 2nd ed., 2010,
ch. 3 (beam element stiffness and consistent mass matrices).
M.I. Friswell, J.E. Mottershead, Finite Element Model Updating in Structural
Dynamics, 1995 (parameterized K, M).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.linalg

from workbench.core.errors import InputError

__all__ = [
    "PARAMETER_NAMES",
    "FEModel",
    "element_matrices",
    "point_vector",
    "parameter_matrices",
    "assemble",
    "solve_modes",
]

PARAMETER_NAMES = (
    "youngs_modulus_pa",
    "density_kgm3",
    "flexure_stiffness_1_npm",
    "flexure_stiffness_2_npm",
)


def element_matrices(le: float) -> tuple[np.ndarray, np.ndarray]:
    """Element stiffness per unit EI and consistent mass per unit rho A, both (4, 4).

    Parameters
    ----------
    le : float
        Element length, m.

    Returns
    -------
    k : (4, 4) array, 1/m^3 (times EI in N m^2 gives N/m)
    m : (4, 4) array, m (times rho A in kg/m gives kg)
    """
    L = le
    k = (
        np.array(
            [
                [12, 6 * L, -12, 6 * L],
                [6 * L, 4 * L**2, -6 * L, 2 * L**2],
                [-12, -6 * L, 12, -6 * L],
                [6 * L, 2 * L**2, -6 * L, 4 * L**2],
            ]
        )
        / L**3
    )
    m = (
        np.array(
            [
                [156, 22 * L, 54, -13 * L],
                [22 * L, 4 * L**2, 13 * L, -3 * L**2],
                [54, 13 * L, 156, -22 * L],
                [-13 * L, -3 * L**2, -22 * L, 4 * L**2],
            ]
        )
        * L
        / 420
    )
    return k, m


def point_vector(x_m: float, *, length_m: float, n_elements: int) -> np.ndarray:
    """Row (n_dof,) giving the deflection at ``x_m`` from the nodal DOFs (Hermite interpolation).

    Its transpose is the consistent nodal load of a unit point force at ``x_m``.
    """
    if not (0.0 <= x_m <= length_m):
        raise InputError(f"x_m: expected a position in [0, {length_m}] m, got {x_m!r}")
    le = length_m / n_elements
    e = min(int(x_m // le), n_elements - 1)
    xi = (x_m - e * le) / le
    N = np.array(
        [
            1 - 3 * xi**2 + 2 * xi**3,
            le * (xi - 2 * xi**2 + xi**3),
            3 * xi**2 - 2 * xi**3,
            le * (-(xi**2) + xi**3),
        ]
    )
    row = np.zeros(2 * (n_elements + 1))
    row[2 * e : 2 * e + 4] = N
    return row


@dataclass(frozen=True, eq=False)
class FEModel:
    """Parameter matrices of an FE beam: K(alpha) = K0 + sum alpha_i K_i, M likewise.

    Parameters
    ----------
    K0, M0 : (n_dof, n_dof) arrays
        Parameter-independent parts (N/m, kg).
    K_i, M_i : (n_par, n_dof, n_dof) arrays
        Derivatives with respect to each parameter of ``PARAMETER_NAMES``.
    length_m : float
    n_elements : int
    """

    K0: np.ndarray
    M0: np.ndarray
    K_i: np.ndarray
    M_i: np.ndarray
    length_m: float
    n_elements: int

    @property
    def n_dof(self) -> int:
        return self.K0.shape[0]

    def point(self, x_m: float) -> np.ndarray:
        """Deflection row (n_dof,) at ``x_m`` (m)."""
        return point_vector(x_m, length_m=self.length_m, n_elements=self.n_elements)


def parameter_matrices(
    *,
    length_m: float,
    width_m: float,
    thickness_m: float,
    n_elements: int,
    flexure_positions_m: tuple[float, float] = (),
    lumped_masses: tuple[tuple[float, float], ...] = (),
    in_plane: bool = False,
) -> FEModel:
    """Assemble the parameter matrices of a uniform beam.

    Parameters
    ----------
    length_m, width_m, thickness_m : float
        Beam dimensions, m. Out of plane, the beam bends about its thin
        direction, I = width thickness^3 / 12; in plane (``in_plane=True``)
        about its wide direction, I = thickness width^3 / 12.
    n_elements : int
        Number of equal Hermite elements.
    flexure_positions_m : (2,) tuple or ()
        Positions of the two springs to the world (wire flexures), m.
        () = free-free (the flexure matrices are zero).
    lumped_masses : tuple of (position_m, mass_kg)
        Point masses on the beam (actuator moving parts), in M0.
    in_plane : bool
        Bending in the plane of the beam's width.

    Returns
    -------
    FEModel
    """
    if int(n_elements) != n_elements or n_elements < 1:
        raise InputError(f"n_elements: expected an integer >= 1, got {n_elements!r}")
    if min(length_m, width_m, thickness_m) <= 0:
        raise InputError(
            f"beam dimensions: expected > 0 m, got {(length_m, width_m, thickness_m)!r}"
        )
    n = 2 * (n_elements + 1)
    I = width_m * thickness_m**3 / 12 if not in_plane else thickness_m * width_m**3 / 12
    A = width_m * thickness_m
    ke, me = element_matrices(length_m / n_elements)
    KE = np.zeros((n, n))
    MR = np.zeros((n, n))
    for e in range(n_elements):
        s = slice(2 * e, 2 * e + 4)
        KE[s, s] += I * ke
        MR[s, s] += A * me
    M0 = np.zeros((n, n))
    for x, mass in lumped_masses:
        r = point_vector(x, length_m=length_m, n_elements=n_elements)
        M0 += mass * np.outer(r, r)
    Kf = [np.zeros((n, n)), np.zeros((n, n))]
    if len(flexure_positions_m) not in (0, 2):
        raise InputError(
            f"flexure_positions_m: expected 2 positions or (), got {flexure_positions_m!r}"
        )
    for i, x in enumerate(flexure_positions_m):
        r = point_vector(x, length_m=length_m, n_elements=n_elements)
        Kf[i] = np.outer(r, r)
    zero = np.zeros((n, n))
    return FEModel(
        K0=zero.copy(),
        M0=M0,
        K_i=np.array([KE, zero, Kf[0], Kf[1]]),
        M_i=np.array([zero, MR, zero, zero]),
        length_m=float(length_m),
        n_elements=int(n_elements),
    )


def assemble(model: FEModel, alpha) -> tuple[np.ndarray, np.ndarray]:
    """K(alpha), M(alpha) for parameters ``alpha`` (4,) in the order of ``PARAMETER_NAMES``."""
    a = np.asarray(alpha, float)
    if a.shape != (model.K_i.shape[0],):
        raise InputError(
            f"alpha: expected {model.K_i.shape[0]} parameters {PARAMETER_NAMES}, got {a!r}"
        )
    K = model.K0 + np.einsum("i,ijk->jk", a, model.K_i)
    M = model.M0 + np.einsum("i,ijk->jk", a, model.M_i)
    return K, M


def solve_modes(K: np.ndarray, M: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Natural frequencies and mass-normalized mode shapes of K phi = w^2 M phi.

    Returns
    -------
    freq_hz : (n_dof,) array
        Ascending, Hz (tiny negative eigenvalues of rigid modes clipped to 0).
    Phi : (n_dof, n_dof) array
        Columns are modes with Phi^T M Phi = I, Phi^T K Phi = diag(w^2).
    """
    lam, Phi = scipy.linalg.eigh(K, M)
    return np.sqrt(np.clip(lam, 0.0, None)) / (2 * np.pi), Phi
