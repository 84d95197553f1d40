"""Independent closed-loop multisine records of a plant, for checking ``identify --refine``.

Made without :mod:`workbench.experiments` or :mod:`workbench.sim`: the plant is
a black box behind its ``init`` / ``step`` API (:class:`plants.base.Plant`,
noise and quantization as the plant has them), the controller is a
:class:`controllers.pid.DecentralizedController` stepped sample by sample, and
the multisine is built here from its DFT lines.

Loop, set point 0, ``r`` added at the plant input, recorded ``u = r + K e``::

    arrangement "loop":        u[k] = r[k] + K0 e[k]         (controller without delay)
                               plant input u[k - 1]          (1-sample delay in the loop)
    arrangement "controller":  u[k] = r[k] + K1 e[k - 1]     (1-sample delay in the controller)
                               plant input u[k]

``e = -y``. In both the plant itself is configured without its own delay; so
``u -> y`` has one sample of delay beyond the ZOH in "loop" and none in
"controller". The loop's total delay (and so the closed loop) is the same.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from controllers.pid import tune_pid
from workbench.io.formats import TimeData

ARRANGEMENTS = ("loop", "controller")


@dataclass(frozen=True)
class ClosedLoopRecord:
    """A record and what made it.

    Attributes
    ----------
    data : TimeData
        ``u`` (N, n_u) N, ``y`` (N, n_y) m, ``r`` (N, n_u) N, ``period`` set.
    input_delay : int
        Samples of delay from the recorded ``u`` to ``y`` beyond the ZOH.
    lines : (n_l,) int array
        Excited DFT lines of one period.
    """

    data: TimeData
    input_delay: int
    lines: np.ndarray


def _configured(plant, *, delay_s: float, noise_free: bool):
    """The plant with its own input delay set (and noise off): a MechanicalPlant's effects,
    a LinearPlant's fields."""
    if hasattr(plant, "with_effects"):
        plant = plant.with_effects(delay_s=delay_s)
        return plant.with_effects(noise_std=0.0, quantization=0.0) if noise_free else plant
    changes = {"delay_s": delay_s}
    if noise_free:
        changes.update(noise_std=0.0, quantization=0.0)
    return dataclasses.replace(plant, **changes)


def effective_masses(plant, crossover_hz: float) -> np.ndarray:
    """``1 / ((2 pi fc)^2 |G_jj(fc)|)`` per input from the plant's FRF, kg (kg m^2)."""
    G = plant.frf(np.array([crossover_hz]))[0]
    return 1.0 / ((2 * np.pi * crossover_hz) ** 2 * np.abs(np.diag(G)))


def multisine(
    rng: np.random.Generator, *, n_u: int, period: int, lines: np.ndarray, rms: np.ndarray
) -> np.ndarray:
    """One period (period, n_u) of independent random-phase flat multisines on ``lines``."""
    X = np.zeros((period // 2 + 1, n_u), complex)
    X[lines] = np.exp(2j * np.pi * rng.uniform(size=(len(lines), n_u)))
    x = np.fft.irfft(X, n=period, axis=0)
    return x * (np.asarray(rms, float) / x.std(axis=0))


def closed_loop_record(
    plant,
    rng: np.random.Generator,
    *,
    arrangement: str,
    n_samples: int = 10_000,
    period: int = 2000,
    band_hz: tuple[float, float] = (5.0, 1500.0),
    crossover_hz: float = 100.0,
    accel_rms: float = 0.3,
    plant_delay_samples: int = 0,
    noise_free: bool = False,
) -> ClosedLoopRecord:
    """Closed-loop periodic record of ``plant`` (square), delay placed by ``arrangement``.

    Parameters
    ----------
    plant : plants.base.Plant
        Square plant; configured here with ``plant_delay_samples`` of input delay.
    rng : numpy.random.Generator
        Phases of the multisine and the plant's measurement noise.
    arrangement : {"loop", "controller"}
        Where the one-sample computation delay sits (module docstring).
    n_samples, period : int
        Record length and period, samples.
    band_hz : (float, float)
        Excited band (every DFT line in it), Hz.
    crossover_hz : float
        Crossover of the lead-lag PID per loop, Hz.
    accel_rms : float
        r rms per input over the effective mass, m/s^2.
    plant_delay_samples : int
        Input delay the plant itself is configured with, samples (0: the
        computation delay is the only one).
    noise_free : bool
        Switch the plant's noise and quantization off (the same ``r``).
    """
    if arrangement not in ARRANGEMENTS:
        raise ValueError(f"arrangement: expected one of {ARRANGEMENTS}, got {arrangement!r}")
    plant = _configured(plant, delay_s=plant_delay_samples / plant.fs, noise_free=noise_free)
    fs, n_u = plant.fs, plant.n_u
    mass = effective_masses(plant, crossover_hz)
    ctrl_delay = 1 if arrangement == "controller" else 0
    K = tune_pid(mass, crossover_hz=crossover_hz, fs=fs, delay_samples=ctrl_delay)
    df = fs / period
    lines = np.arange(int(np.ceil(band_hz[0] / df)), int(np.floor(band_hz[1] / df)) + 1)
    r = np.tile(
        multisine(rng, n_u=n_u, period=period, lines=lines, rms=accel_rms * mass),
        (n_samples // period, 1),
    )
    u = np.zeros_like(r)
    y = np.zeros((n_samples, plant.n_y))
    ps, cs = plant.init(rng), K.init()
    u_prev = np.zeros(n_u)
    for k in range(n_samples):
        if arrangement == "controller":
            u[k] = r[k] + K.output(cs)  # from e up to k - 1
            y[k], ps = plant.step(ps, u[k])
            _, cs = K.step(cs, -y[k])
        else:
            y[k], ps = plant.step(ps, u_prev)  # y[k] does not depend on the input at k
            v, cs = K.step(cs, -y[k])
            u[k] = r[k] + v
            u_prev = u[k]
    data = TimeData(
        fs=fs,
        u=u,
        y=y,
        r=r,
        period=period,
        loop="closed",
        input_names=plant.input_names,
        output_names=plant.output_names,
    )
    return ClosedLoopRecord(
        data=data, input_delay=plant_delay_samples + 1 - ctrl_delay, lines=lines
    )
