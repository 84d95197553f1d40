"""Explanations a control engineer accepts: the signature seen, in numbers, and the fit."""

from __future__ import annotations

import numpy as np

from workbench.diagnosis.effects import MIN_DAMPING

__all__ = ["damping_floor_note", "explain"]

#: a lag whose every cutoff is this many times the band's top leaves no roll-off in it
FAST_LAG = 100.0
#: a runner-up within this share of a finding's error "fits nearly as closely"
ALIKE = 0.01


def _hz(f) -> str:
    """``12.5 Hz``, or ``12.5, 13.2, 15.1 Hz`` for several frequencies."""
    if isinstance(f, list | tuple | np.ndarray):
        return ", ".join(f"{x:.4g}" for x in f) + " Hz"
    return f"{f:.4g} Hz"


def _chan(ins, outs, n_u, n_y) -> str:
    if len(ins) == n_u and len(outs) == n_y:
        return f"all {n_y * n_u} channels"
    return f"inputs {list(ins)} x outputs {list(outs)}"


def _modes_pattern(p: dict, f_hi: float) -> str:
    """What a mismatch of several modes shares (``pattern``), and which modes in the band
    (up to ``f_hi``, Hz) move on their own: '' for one mode."""
    modes = p.get("modes") or []
    if len(modes) < 2:
        return ""
    pattern = p.get("pattern") or {}
    text = f"; {len(modes)} modes moved"
    scale = pattern.get("freq_scale")
    if scale is not None:
        which = pattern.get("of_modes_hz")
        who = (
            "every mode's frequency"
            if which is None
            else f"the frequencies of {len(which)} of them ({_hz(min(which))} to "
            f"{_hz(max(which))} in the model)"
        )
        text += (
            f": {who} scaled by one factor, {scale:.4g} ({100 * (scale - 1):+.2f} %), the "
            f"stiffness-to-mass ratio {scale**2:.4g} times the model's, as a wrong Young's "
            "modulus or density gives"
        )
        if which is not None:
            own = [modes[j] for j in own_modes(modes, which, f_hi)]
            if own:
                moved = modes_moved(own, sep=", ")
                text += f"; the others move each on its own ({moved}): another cause"
    if pattern.get("damping_scale") is not None:
        text += f"; every damping scaled by {pattern['damping_scale']:.3g}"
    return text


def own_modes(modes: list[dict], share: list[float], f_hi: float) -> list[int]:
    """The indices of ``modes`` (a mismatch's, each with ``model_freq_hz``) in the band (up to
    ``f_hi``, Hz) that move each on its own: not among the model frequencies ``share`` of the
    modes a pattern's factor moves."""
    return [
        j
        for j, m in enumerate(modes)
        if m["model_freq_hz"] <= f_hi
        and not any(abs(m["model_freq_hz"] - w) <= 1e-9 * w for w in share)
    ]


def modes_moved(modes: list[dict], *, damping: str = "", sep: str = "; ") -> str:
    """``2.526 -> 2.807 Hz (+11.13 %)`` for each mode, joined by ``sep``; ``damping``: ""
    none, "new" its fitted damping (``, damping 0.0302``), "both" the model's and the
    fitted (``, damping 0.01 -> 0.0302``)."""

    def one(m: dict) -> str:
        text = (
            f"{m['model_freq_hz']:.4g} -> {m['freq_hz']:.4g} Hz "
            f"({100 * (m['freq_hz'] / m['model_freq_hz'] - 1):+.2f} %"
        )
        if damping == "new":
            text += f", damping {m['damping']:.3g}"
        elif damping == "both":
            text += f", damping {m['model_damping']:.3g} -> {m['damping']:.3g}"
        return text + ")"

    return sep.join(one(m) for m in modes)


def explain(effect: str, ev: dict) -> str:
    """One paragraph for ``effect`` from the evidence dictionary ``ev``.

    ``ev`` holds at least error_before, error_after, band_hz, inputs, outputs,
    n_u, n_y, parameters, kind ('frf' or 'time') and optionally noise_floor,
    alternative (the runner-up effect and its error), late (a residual compliance whose
    static part answers the previous sample's input).
    """
    p = ev["parameters"]
    lo, hi = ev["band_hz"]
    where = _chan(ev["inputs"], ev["outputs"], ev["n_u"], ev["n_y"])
    fall = f"the error falls from {ev['error_before']:.4g} to {ev['error_after']:.4g}"
    if ev.get("noise_floor"):
        fall += f" (noise floor {ev['noise_floor']:.4g})"
    alt = ev.get("alternative")
    if not alt:
        tail = "."
    elif alt[1] <= ev["error_after"]:
        # ranked by BIC: a runner-up at least as close has more parameters
        tail = f"; {alt[0]} fits as closely ({alt[1]:.4g}) but with more parameters."
    elif alt[1] <= (1 + ALIKE) * ev["error_after"]:
        tail = (
            f"; {alt[0]} fits nearly as closely ({alt[1]:.4g}): the record hardly tells them "
            "apart, and the likelihood for the parameters each takes prefers this one."
        )
    else:
        tail = f"; the next best explanation, {alt[0]}, only reaches {alt[1]:.4g}."
    if effect == "time_delay":
        tau = p["delay_s"]
        fs = ev.get("fs")
        samples = f", {tau * fs:.2f} samples at {fs:g} Hz" if fs else ""
        if "phase_slope_deg_per_hz" in ev:
            sig = (
                f"phase error grows linearly with frequency, {ev['phase_slope_deg_per_hz']:.4g} "
                "deg/Hz over "
                f"{lo:.4g}-{hi:.4g} Hz on {ev.get('n_channels_used', 'all')} channels, median "
                "magnitude error "
                f"{ev['magnitude_db']:.2g} dB"
            )
        else:
            sig = "the measured response lags the simulated one by the same time on every channel"
        return f"{sig}: a delay of {tau * 1e6:.4g} us{samples}; {fall}{tail}"
    if effect == "missing_mode":
        return (
            f"local resonance/anti-resonance pattern at {_hz(p['freq_hz'])} that no mode of the "
            "model "
            f"explains, on {where}; a mode added there with damping {p['damping']:.3g} and a "
            "residue of "
            f"rank one (singular value ratio {ev.get('rank_one_ratio', float('nan')):.2g}) fits "
            f"it; {fall}{tail}"
        )
    if effect == "modal_mismatch":
        shift = 100 * (p["freq_hz"] / p["model_freq_hz"] - 1)
        return (
            f"the model's mode at {_hz(p['model_freq_hz'])} (damping "
            f"{p.get('model_damping', 0):.3g}) shows in "
            f"the data at {_hz(p['freq_hz'])} ({shift:+.2f} %) with damping {p['damping']:.3g}: "
            "shifted peak "
            f"on {where}, residues unchanged{_modes_pattern(p, hi)}; {fall}{tail}"
        )
    if effect == "residual_compliance":
        M = np.asarray(p["matrix"])
        # on a sampled record the static part may answer the previous sample's input
        how = (
            "a constant compliance matrix, one sample late as modes far above Nyquist answer "
            "the held input, fits it"
            if ev.get("late")
            else "a constant compliance matrix added to D fits it"
        )
        return (
            f"frequency-independent offset of the response, largest {np.max(np.abs(M)):.3g} m/N, "
            "strongest "
            f"below the first truncated mode and moving the anti-resonances, on {where} "
            f"({lo:.4g}-{hi:.4g} Hz); {how}; {fall}{tail}"
        )
    if effect in ("actuator_dynamics", "sensor_dynamics"):
        side = "inputs (columns)" if effect == "actuator_dynamics" else "outputs (rows)"
        cuts = [c for c in p["cutoff_hz"] if c is not None]
        rng = f"{min(cuts):.4g}-{max(cuts):.4g} Hz" if cuts else "n/a"
        if cuts and len(cuts) == len(p["cutoff_hz"]) and min(cuts) == max(cuts):
            # one cutoff for every channel (the common lag): a scalar factor on the response
            own, other = ("input", "output")[:: 1 if effect == "actuator_dynamics" else -1]
            side = (
                f"inputs and outputs alike (one lag on every {own} is the same factor on the "
                f"response as that lag on every {other})"
            )
            rng = f"{cuts[0]:.4g} Hz, one for all"
        if cuts and min(cuts) > FAST_LAG * hi:
            # no roll-off in the band: only the phase, about hi / cutoff rad at its top
            return (
                f"a phase lag growing with frequency on whole {side}, with no roll-off in the "
                f"band: first-order lags with cutoffs {rng} on {where}, more than {FAST_LAG:g}x "
                f"the band's top (a phase of at most {hi / min(cuts):.2g} rad at {hi:.4g} Hz, "
                "which this record resolves): a sub-sample timing, or a misfit of another term "
                f"absorbed, rather than an actuator's or a sensor's bandwidth; {fall}{tail}"
            )
        return (
            f"magnitude roll-off with phase lag that acts on whole {side}, not on single channels: "
            "first-order "
            f"lags with cutoffs {rng} on {where}; a pure delay would keep the magnitude flat; "
            f"{fall}{tail}"
        )
    if effect == "suspension_stiffness" and "model_freq_hz" in p:
        # the model's own suspension, its springs set anew (SuspensionSprings)
        moved = modes_moved(p["modes"], damping="new")
        turn = np.abs(np.asarray(p["coupling"]) - np.eye(len(p["modes"]))).max()
        return (
            f"the suspension's modes move and change shape: its springs are not the model's "
            f"({moved}; the modes' shapes turned within the suspended motions by up to "
            f"{turn:.3g}, residues summing to the model's: the same mass), visible "
            f"{lo:.4g}-{hi:.4g} Hz on {where}; {fall}{tail}"
        )
    if effect == "suspension_stiffness":
        modes = p.get("modes") or []
        held = [m["freq_hz"] for m in modes if m.get("resolved", True)]
        free = [m for m in modes if not m.get("resolved", True)]
        # a DOF the spring does not hold: its fitted frequency is not resolved (far below the
        # band, or undetermined), and its rigid line stays in the band
        rest = (
            f"; {len(free)} rigid-body DOF(s) stay free (fitted springs at "
            f"{_hz([m['freq_hz'] for m in free])}, which the data do not resolve)"
            if free and held
            else ""
        )
        return (
            f"the rigid-body 1/w^2 line flattens at low frequency: the rigid-body modes are "
            "suspension modes at "
            f"{_hz(held or [m['freq_hz'] for m in modes] or p['freq_hz'])} "
            f"with damping {p['damping']:.3g}, visible {lo:.4g}-{hi:.4g} Hz on "
            f"{where}{rest}; {fall}{tail}"
        )
    if effect == "crosstalk":
        M = np.asarray(p["matrix"]) - np.eye(len(p["matrix"]))
        return (
            f"static coupling into off-diagonal channels, a constant share of the response of the "
            "other "
            f"{p['side']} (largest {np.max(np.abs(M)):.3g}), i.e. misaligned sensors or actuators, "
            f"on {where}; "
            f"{fall}{tail}"
        )
    if effect == "nonlinearity" and ev.get("unrepeated"):
        # the periods differ beyond the noise while their mean carries nothing on the
        # unexcited lines: what is not linear does not repeat
        return (
            f"the record's periods do not repeat: their spread about the mean period is "
            f"{ev['f_stat']:.3g} times (in power) its estimate as white noise, while the "
            f"{ev['n_lines']} lines the multisine leaves empty carry nothing periodic. The "
            "response to a periodic input is not periodic, which a linear time-invariant "
            f"plant does not give once its transient has settled; about {100 * p['level']:.3g} "
            "% of the output power (the spread beyond the noise) does not repeat."
        )
    if effect == "nonlinearity" and not ev["n_lines"]:
        # no distortion measured on unexcited lines: the evidence is the residual no linear
        # effect removes, and the fitted element (its numbers follow in the finding's note)
        # (a record without periods measures no period-synchronous residual: f_stat 0)
        if ev.get("why"):
            lead = ev["why"]
        elif ev["f_stat"] > 0:
            lead = (
                f"a period-synchronous residual {ev['f_stat']:.3g} times its noise, left by the "
                "linear model"
            )
        else:
            lead = (
                "a residual of the model as given (a record without periods: no noise "
                "estimate from them)"
            )
        return (
            f"{lead}, which no linear effect of the vocabulary explains as well as a port "
            "nonlinearity: the response is not linear in the input; about "
            f"{100 * p['level']:.3g} % of the output power is not explained by a linear model."
        )
    if effect == "nonlinearity":
        return (
            f"periodic output power on {ev['n_lines']} lines the multisine leaves empty, "
            f"{ev['f_stat']:.3g} times the noise there ({lo:.4g}-{hi:.4g} Hz): the response is not "
            "linear in "
            f"the input; about {100 * p['level']:.3g} % of the output power is not explained by a "
            "linear model."
        )
    if effect == "none":
        return ev["reason"]
    return fall


def damping_floor_note(params: dict, params_std: dict) -> str:
    """A sentence for damping ratios that ended at the search's floor
    (``MIN_DAMPING``, :data:`workbench.diagnosis.effects.MIN_DAMPING`), or "".

    There the record resolves an upper bound only, about the std: a DaISy CD-player record
    fitted a mode at 0.413 Hz with damping 1e-6 +- 0.0024 (no line in the output spectrum
    there), and an undamped suspension on flexures is also reported so."""
    at_floor = 1.001 * MIN_DAMPING
    z = params.get("damping")
    if isinstance(z, float) and z <= at_floor:
        sd = params_std.get("damping")
        bound = f"below about {sd:.2g} (its std)" if isinstance(sd, float) and sd > 0 else "low"
        return (
            f" Its damping ended at the search's floor ({MIN_DAMPING:g}): the record resolves "
            f"only that it is {bound}, not its value."
        )
    low = [
        m["freq_hz"]
        for m in params.get("modes", [])
        if isinstance(m, dict) and isinstance(m.get("damping"), float) and m["damping"] <= at_floor
    ]
    if low:
        where = _hz(low)
        return (
            f" The damping of the mode(s) at {where} ended at the search's floor "
            f"({MIN_DAMPING:g}): the record resolves only that it is low, not its value."
        )
    return ""
