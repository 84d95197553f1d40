"""Simulated experiments on any :class:`plants.base.Plant`, open or closed loop.

Data flow::

    signals.multisine(...) -> Multisine --.
    signals.white_noise / step_signal ----+--> run_multisine / run_noise / run_step
                                                  (plant, controller=None or K, rng)
                                                      |
            MultisineExperiment (R, n_exp, P, period, n_ch) arrays   or   TimeData
                    .to_time_data() -> TimeData (spec 1a, experiments concatenated, `period` set)

Closed loop (``controller`` given, any :class:`controllers.Controller`): the
excitation ``r`` enters at the plant input, ``u = r + K e`` with the set point 0,
``e = -y``; the controller sees the measured ``y`` (noise included); any
computation delay of the plant is the plant's own (``plant.delay_s``), the
controller's own is ``controller.delay_samples``. Every run starts at rest and
is reproducible from its ``rng``. The loop runs in :func:`workbench.sim.closed_loop`.

Two ways to simulate a closed loop, picked by ``method="auto"``:

- ``"linear"``: when the plant is linear with additive output noise (checked
  by superposition on a probe of the actual excitation, with a fixed seed:
  ``simulate(u) - simulate(0) == ZOH response of plant.linear_model()`` to
  1e-6), the loop is one discrete LTI system driven by ``r`` and the plant's
  noise ``v = plant.simulate(0)``: a 6x6 wafer stage, 10,000 samples, takes
  a few tens of milliseconds.
- ``"step"``: otherwise, ``plant.step`` and ``controller.step`` sample by
  sample (needs a controller without direct feedthrough, such as
  ``delay_samples >= 1``).

Multi-experiment multisines: ``run_multisine`` applies realization r,
experiment e (r-major order) one after the other in a single run, ``n_periods``
periods each; the first period of each block holds the switching transient and
is dropped by the estimator (``frf_estimation.frf_multisine(n_transient=1)``).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

import numpy as np

from controllers.pid import DecentralizedController, tune_pid
from controllers.protocol import Controller
from workbench import sim
from workbench.core.errors import InputError
from workbench.io.formats import TimeData
from workbench.signals.excitation import Multisine, as_rng, multisine, step_signal, white_noise

__all__ = [
    "MultisineExperiment",
    "simulate_open_loop",
    "simulate_closed_loop",
    "run_multisine",
    "run_noise",
    "run_step",
    "effective_mass",
    "default_controller",
    "wafer_stage_closed_loop_record",
    "ExperimentConfig",
    "run_experiment",
]


@dataclass(frozen=True)
class MultisineExperiment:
    """A periodic multisine experiment with its structure kept.

    Parameters
    ----------
    design : Multisine
        The excitation (lines, amplitudes, realizations R, experiments n_exp).
    u : (R, n_exp, P, period, n_u) array
        Applied plant input, N.
    y : (R, n_exp, P, period, n_y) array
        Measured output, m.
    r : (R, n_exp, P, period, n_u) array or None
        Excitation at the plant input (closed loop); None in open loop (u is it).
    loop : {"open", "closed"}
    """

    design: Multisine
    u: np.ndarray
    y: np.ndarray
    r: np.ndarray | None = None
    loop: str = "open"
    input_names: tuple[str, ...] = field(default=())
    output_names: tuple[str, ...] = field(default=())

    def __post_init__(self):
        d = self.design
        want = (d.n_realizations, d.n_exp)
        for name in ("u", "y", "r"):
            a = getattr(self, name)
            if a is None:
                continue
            a = np.array(a, float)
            if a.ndim != 5 or a.shape[:2] != want or a.shape[3] != d.period:
                raise InputError(
                    f"{name}: expected shape {want} + (P, {d.period}, n_ch), got {a.shape}"
                )
            a.setflags(write=False)
            object.__setattr__(self, name, a)
        if self.u.shape[:4] != self.y.shape[:4] or (
            self.r is not None and self.r.shape != self.u.shape
        ):
            raise InputError(f"u, y, r: shapes disagree: {self.u.shape}, {self.y.shape}")
        if self.loop not in ("open", "closed"):
            raise InputError(f"loop: expected 'open' or 'closed', got {self.loop!r}")

    @property
    def fs(self) -> float:
        return self.design.fs

    @property
    def period(self) -> int:
        return self.design.period

    @property
    def n_periods(self) -> int:
        return self.u.shape[2]

    def to_time_data(self) -> TimeData:
        """The record as one TimeData (spec 1a): blocks concatenated, r-major, ``period`` set."""

        def flat(a):
            return None if a is None else a.reshape(-1, a.shape[-1])

        return TimeData(
            fs=self.fs,
            u=flat(self.u),
            y=flat(self.y),
            r=flat(self.r),
            loop=self.loop,
            period=self.period,
            input_names=self.input_names,
            output_names=self.output_names,
        )


# ------------------------------------------------------------------ simulation
def simulate_open_loop(plant, u: np.ndarray, *, rng: np.random.Generator | int) -> np.ndarray:
    """Measured output (N, n_y) of ``plant`` to the input ``u`` (N, n_u), from rest."""
    u = _check_input(plant, u, "u")
    return np.asarray(plant.simulate(u, rng=as_rng(rng)), float)


def _check_input(plant, x, name: str) -> np.ndarray:
    x = np.asarray(x, float)
    if x.ndim != 2 or x.shape[1] != plant.n_u:
        raise InputError(
            f"{name}: expected shape (N, {plant.n_u}) for the plant's inputs, got {x.shape}"
        )
    return x


def simulate_closed_loop(
    plant,
    controller: Controller,
    r: np.ndarray,
    *,
    rng: np.random.Generator | int,
    method: Literal["auto", "linear", "step"] = "auto",
) -> tuple[np.ndarray, np.ndarray]:
    """Closed-loop response to the excitation ``r`` at the plant input, from rest.

    The loop itself is :func:`workbench.sim.closed_loop` (set point 0, so the
    controller sees e = -y; ``r`` here is its excitation ``d``).

    Parameters
    ----------
    plant : Plant
    controller : Controller
        Maps the control error (n_y) to the plant's n_u inputs, at the plant's fs.
    r : (N, n_u) array
        Excitation added at the plant input, N.
    rng : Generator or int
        Source of the plant's noise.
    method : {"auto", "linear", "step"}
        See the module docstring; ``"linear"`` skips the linearity probe.

    Returns
    -------
    u : (N, n_u) array
        Applied input, N.
    y : (N, n_y) array
        Measured output, m.
    """
    r = _check_input(plant, r, "r")
    return sim.closed_loop(plant, controller, d=r, rng=as_rng(rng), method=method)


def _run(plant, r, controller, rng, method):
    if controller is None:
        return r, simulate_open_loop(plant, r, rng=rng), None, "open"
    u, y = simulate_closed_loop(plant, controller, r, rng=rng, method=method)
    return u, y, r, "closed"


def _names(plant) -> dict:
    return dict(input_names=tuple(plant.input_names), output_names=tuple(plant.output_names))


# ----------------------------------------------------------------- experiments
def run_multisine(
    plant,
    design: Multisine,
    *,
    n_periods: int,
    controller: Controller | None = None,
    rng: np.random.Generator | int,
    method: Literal["auto", "linear", "step"] = "auto",
) -> MultisineExperiment:
    """Apply every experiment and realization of ``design``, ``n_periods`` periods each.

    Parameters
    ----------
    plant : Plant
    design : Multisine
        With ``n_ch == plant.n_u`` and ``fs == plant.fs``.
    n_periods : int
        Periods per block (the first is the transient, dropped by the estimator).
    controller : Controller, optional
        Closed loop when given.
    rng : Generator or int
    method : {"auto", "linear", "step"}
        Closed-loop simulation method.

    Returns
    -------
    MultisineExperiment
    """
    rng = as_rng(rng)
    if design.n_ch != plant.n_u:
        raise InputError(f"design: expected {plant.n_u} channels for the plant, got {design.n_ch}")
    if abs(design.fs - plant.fs) > 1e-9 * plant.fs:
        raise InputError(f"design: expected fs = {plant.fs:g} Hz like the plant, got {design.fs:g}")
    n_periods = int(n_periods)
    if n_periods < 1:
        raise InputError(f"n_periods: expected >= 1, got {n_periods}")
    sig = design.signal(n_periods)  # (R, n_exp, P*period, n_u)
    R, E = sig.shape[:2]
    r = sig.reshape(-1, plant.n_u)
    u, y, r_rec, loop = _run(plant, r, controller, rng, method)

    def shape(a):
        return None if a is None else a.reshape(R, E, n_periods, design.period, a.shape[-1])

    return MultisineExperiment(
        design=design, u=shape(u), y=shape(y), r=shape(r_rec), loop=loop, **_names(plant)
    )


def run_noise(
    plant,
    *,
    n_samples: int,
    rms: float | np.ndarray,
    band_hz: tuple[float, float] | None = None,
    controller: Controller | None = None,
    rng: np.random.Generator | int,
    method: Literal["auto", "linear", "step"] = "auto",
) -> TimeData:
    """White (or band-limited) Gaussian noise on every input, open or closed loop.

    ``rms`` per input in N (or N m); see :func:`workbench.signals.excitation.white_noise`.
    """
    rng = as_rng(rng)
    r = white_noise(n_samples, plant.n_u, fs=plant.fs, rms=rms, band_hz=band_hz, rng=rng)
    u, y, r_rec, loop = _run(plant, r, controller, rng, method)
    return TimeData(fs=plant.fs, u=u, y=y, r=r_rec, loop=loop, **_names(plant))


def run_step(
    plant,
    *,
    n_samples: int,
    amplitude: float | np.ndarray,
    start_sample: int = 0,
    controller: Controller | None = None,
    rng: np.random.Generator | int,
    method: Literal["auto", "linear", "step"] = "auto",
) -> TimeData:
    """Step of ``amplitude`` (per input, N) at ``start_sample``, open or closed loop."""
    rng = as_rng(rng)
    r = step_signal(n_samples, amplitude=amplitude, n_ch=plant.n_u, start_sample=start_sample)
    u, y, r_rec, loop = _run(plant, r, controller, rng, method)
    return TimeData(fs=plant.fs, u=u, y=y, r=r_rec, loop=loop, **_names(plant))


# ------------------------------------------------------------ wafer-stage record
def effective_mass(plant, freq_hz: float, *, sensor_index: tuple[int, ...] = ()) -> np.ndarray:
    """Rigid-body mass/inertia seen by each input at ``freq_hz``: 1 / (w^2 |G_ij|), shape (n_u,).

    ``sensor_index[j]`` is the output paired with input j (default j). Read from
    ``plant.frf``, the model a control engineer would tune on.
    """
    idx = tuple(range(plant.n_u)) if not sensor_index else tuple(sensor_index)
    G = plant.frf(np.array([float(freq_hz)]))[0]
    g = np.abs(G[list(idx), list(range(plant.n_u))])
    return 1.0 / ((2 * np.pi * freq_hz) ** 2 * g)


def default_controller(
    plant,
    *,
    crossover_hz: float,
    sensor_index: tuple[int, ...] = (),
    delay_samples: int = 1,
) -> DecentralizedController:
    """Decentralized lead-lag PID tuned on :func:`effective_mass` at ``crossover_hz``."""
    mass = effective_mass(plant, crossover_hz, sensor_index=sensor_index)
    return tune_pid(
        mass,
        crossover_hz=crossover_hz,
        fs=plant.fs,
        n_y=plant.n_y,
        sensor_index=sensor_index,
        delay_samples=delay_samples,
    )


def wafer_stage_closed_loop_record(
    plant,
    *,
    rng: np.random.Generator | int,
    controller: Controller | None = None,
    crossover_hz: float = 100.0,
    accel_rms: float = 0.3,
    band_hz: tuple[float, float] = (7.5, 1500.0),
    n_samples: int = 10_000,
    period: int = 2000,
    kind: Literal["full", "odd", "random_odd"] = "random_odd",
) -> TimeData:
    """The closed-loop wafer-stage record: 10,000 samples, period 2000, 5 periods.

    A random-odd multisine on all inputs at once (one experiment, independent
    random phases per input, the same lines), ``r`` rms per input =
    ``accel_rms`` x the effective mass (so 0.3 m/s^2 on 20 kg is 6 N rms, the
    level of the shared example record, giving sub-micrometre motion), under
    the decentralized PID of :func:`default_controller`.

    Parameters
    ----------
    plant : Plant
        Square plant (the 6x6 wafer stage at 5 kHz).
    rng : Generator or int
    controller : DecentralizedController, optional
        Default: ``default_controller(plant, crossover_hz=crossover_hz)``.
    crossover_hz : float
    accel_rms : float
        Rigid-body acceleration per input, m/s^2 or rad/s^2 rms.
    band_hz : (float, float)
        Excited band; 7.5 .. 1500 Hz at 2.5 Hz resolution as in the example.
    n_samples, period : int
        Record length and period, samples (n_samples a multiple of period).
    kind : {"full", "odd", "random_odd"}

    Returns
    -------
    TimeData
        ``loop="closed"``, ``r`` recorded, ``period`` set.
    """
    rng = as_rng(rng)
    if n_samples % period:
        raise InputError(f"n_samples: expected a multiple of period = {period}, got {n_samples}")
    if controller is None:
        controller = default_controller(plant, crossover_hz=crossover_hz)
    rms = accel_rms * effective_mass(plant, crossover_hz, sensor_index=controller.sensor_index)
    design = multisine(
        fs=plant.fs,
        period=period,
        band_hz=band_hz,
        n_ch=plant.n_u,
        rms=rms,
        kind=kind,
        n_exp=1,
        rng=rng,
    )
    exp = run_multisine(
        plant, design, n_periods=n_samples // period, controller=controller, rng=rng
    )
    return exp.to_time_data()


# ----------------------------------------------------------- configured runs
_KINDS = ("closed_loop_multisine", "open_loop_multisine", "noise", "step")


@dataclass(frozen=True)
class ExperimentConfig:
    """An experiment as a scenario's ``[experiment]`` table describes it.

    Parameters
    ----------
    kind : {"closed_loop_multisine", "open_loop_multisine", "noise", "step"}
    n_samples : int, optional
        Record length, samples. Multisines: default ``n_exp * R * periods *
        period``; if given it must be a multiple of ``n_exp * R * period``
        and sets ``periods``. Noise: default 65536. Step: default 5000.
    period : int, optional
        Multisine period, samples; default ``round(0.4 fs)`` (2.5 Hz lines).
    periods : int
        Periods per block, the first a transient (default 5).
    band_hz : (float, float), optional
        Excited band, Hz; default (3 fs / period, 0.3 fs) for multisines
        (7.5 .. 1500 Hz on the wafer stage), white noise otherwise.
    rms : float or list, optional
        Excitation rms (N) per input (noise, multisine) or step height (step);
        default ``accel_rms`` x the effective mass at ``crossover_hz``.
    accel_rms : float
        Rigid-body acceleration of the default level, m/s^2 (0.3, the level of
        the shared example record).
    lines : {"random_odd", "odd", "full"}
    design : {"independent", "orthogonal"}
    n_exp : int, optional
        Multisine experiments; default 1 for ``closed_loop_multisine`` (the
        paper's 10,000-sample record with all inputs excited at once, made for
        time-domain work) and n_u for ``open_loop_multisine``. The
        nonparametric FRF needs ``n_exp >= n_u``.
    n_realizations : int
    loop : {"open", "closed"}, optional
        For noise and step (multisines: from ``kind``); default open.
    crossover_hz : float, optional
        Of the default controller; default fs / 50 (100 Hz at 5 kHz).
    sensor_index : list of int, optional
        Output fed back by each input (non-square plants).
    seed : int, optional
        Overrides the caller's seed.
    """

    kind: str
    n_samples: int | None = None
    period: int | None = None
    periods: int = 5
    band_hz: tuple[float, float] | None = None
    rms: float | tuple[float, ...] | None = None
    accel_rms: float = 0.3
    lines: str = "random_odd"
    design: str = "independent"
    n_exp: int | None = None
    n_realizations: int = 1
    loop: str | None = None
    crossover_hz: float | None = None
    sensor_index: tuple[int, ...] = ()
    seed: int | None = None

    def __post_init__(self):
        if self.kind not in _KINDS:
            raise InputError(
                f"[experiment] key 'kind': expected one of {', '.join(_KINDS)}, got {self.kind!r}"
            )
        if self.loop not in (None, "open", "closed"):
            raise InputError(
                f"[experiment] key 'loop': expected 'open' or 'closed', got {self.loop!r}"
            )
        for name in ("n_samples", "period", "n_exp"):
            v = getattr(self, name)
            if v is not None and (not isinstance(v, (int, np.integer)) or v < 1):
                raise InputError(f"[experiment] key '{name}': expected an integer >= 1, got {v!r}")
        if self.band_hz is not None:
            object.__setattr__(self, "band_hz", tuple(float(b) for b in self.band_hz))
            if len(self.band_hz) != 2:
                raise InputError(
                    f"[experiment] key 'band_hz': expected [low, high], got {self.band_hz!r}"
                )
        if isinstance(self.rms, (list, tuple)):
            object.__setattr__(self, "rms", tuple(float(v) for v in self.rms))
        object.__setattr__(self, "sensor_index", tuple(int(i) for i in self.sensor_index))

    @classmethod
    def from_table(cls, table: dict) -> ExperimentConfig:
        """From a TOML ``[experiment]`` table; unknown keys are refused."""
        known = set(cls.__dataclass_fields__)
        extra = sorted(set(table) - known)
        if extra:
            raise InputError(
                f"[experiment] has unknown key '{extra[0]}'; "
                f"expected some of: {', '.join(sorted(known))}"
            )
        if "kind" not in table:
            raise InputError(f"[experiment]: missing key 'kind' (one of {', '.join(_KINDS)})")
        return cls(**table)


def run_experiment(plant, config: ExperimentConfig, *, rng: np.random.Generator | int) -> TimeData:
    """Run a configured experiment on ``plant``; the record in spec form (TimeData)."""
    rng = as_rng(config.seed if config.seed is not None else rng)
    fs = plant.fs
    fc = config.crossover_hz if config.crossover_hz is not None else fs / 50
    kind = config.kind
    closed = kind == "closed_loop_multisine" or (
        kind in ("noise", "step") and config.loop == "closed"
    )
    if closed and not config.sensor_index and plant.n_y != plant.n_u:
        raise InputError(
            f"[experiment] key 'sensor_index': a closed loop on a {plant.n_y}x{plant.n_u} plant "
            "needs "
            f"the output fed back by each of the {plant.n_u} inputs"
        )
    controller = (
        default_controller(plant, crossover_hz=fc, sensor_index=config.sensor_index)
        if closed
        else None
    )
    if config.rms is None:
        level = config.accel_rms * effective_mass(plant, fc, sensor_index=config.sensor_index)
    else:
        level = np.broadcast_to(np.asarray(config.rms, float), (plant.n_u,))
    if kind.endswith("multisine"):
        period = config.period or int(round(0.4 * fs))
        n_exp = config.n_exp or (1 if kind == "closed_loop_multisine" else plant.n_u)
        R = config.n_realizations
        periods = config.periods
        if config.n_samples is not None:
            if config.n_samples % (n_exp * R * period):
                raise InputError(
                    "[experiment] key 'n_samples': expected a multiple of "
                    "n_exp * n_realizations * "
                    f"period = {n_exp * R * period}, got {config.n_samples}"
                )
            periods = config.n_samples // (n_exp * R * period)
        band = config.band_hz or (3 * fs / period, 0.3 * fs)
        design = multisine(
            fs=fs,
            period=period,
            band_hz=band,
            n_ch=plant.n_u,
            rms=level,
            kind=config.lines,
            design=config.design,
            n_exp=n_exp,
            n_realizations=R,
            rng=rng,
        )
        exp = run_multisine(plant, design, n_periods=periods, controller=controller, rng=rng)
        return exp.to_time_data()
    if kind == "noise":
        return run_noise(
            plant,
            n_samples=config.n_samples or 65536,
            rms=level,
            band_hz=config.band_hz,
            controller=controller,
            rng=rng,
        )
    n = config.n_samples or 5000
    return run_step(
        plant, n_samples=n, amplitude=level, start_sample=n // 10, controller=controller, rng=rng
    )
