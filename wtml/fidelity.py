"""``wtml fidelity``: every reproduction of a thesis number that wtml has, in one report.

Sections: the presets' resonances (``wtml presets``); the calibration walkthrough's errors
(Tables 4.3–4.4, ``wtml walkthrough``); the glycerol–water properties against Tables 6.1–6.2;
the onset slice's Figure 5.22 (the thesis's own pipeline, ``classical.onnx`` of the onset
export, on 15 wall positions × 3 records: measured against actual location, R²); and texture
(thesis §4.5–4.6): the
friction law's fit to Table 4.10, the RMS tip speed per grade at the nominal set-up against
Table 4.10 (within 10 %; with a viscous span, also on each law's line moved to its top c),
|F| and |V| against grain size with their line's R² (Figures
4.28–4.29: > 0.99), Re Zm rising and Im Zm small (Figures 4.30–4.31), and the kinetic-signature
table: the spectral peaks of e(t) and i(t) per grade (Table 4.11) beside the v/d frequencies
and the transducer's modes with its tip free and held.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import torch
from scipy.linalg import eigh
from scipy.signal import find_peaks, welch

from wtml.physics.beam_presets import build
from wtml.scenes.texture import (
    TABLE_4_10_RMS_SPEED,
    THESIS_GRADES,
    TextureScene,
    fit_friction_law,
    nominal_response,
)

TABLE_4_11_PEAKS_HZ = (36, 360, 1070, 2080, 3440, 5110, 7110, 9390)
"""The thesis's spectral peaks, the same for every specimen (Table 4.11), Hz."""


def r_squared(x: np.ndarray, y: np.ndarray, degree: int = 1) -> float:
    """R² of a least-squares polynomial of ``degree`` through ``(x, y)``."""
    fit = np.polyval(np.polyfit(x, y, degree), x)
    return float(1 - np.sum((y - fit) ** 2) / np.sum((y - y.mean()) ** 2))


def held_tip_modes(preset: str = "macro", count: int = 14) -> np.ndarray:
    """Natural frequencies (Hz) of the beam with its tip held (tip displacement pinned)."""
    k, m, theta = build(preset).matrices()
    keep = [j for j in range(len(theta)) if j != len(theta) - 2]
    w2 = eigh(k.real[np.ix_(keep, keep)], m[np.ix_(keep, keep)], eigvals_only=True)
    return np.sqrt(w2[:count]) / (2 * np.pi)


def spectral_peaks(x: np.ndarray, rate: float, count: int = 8, top_hz: float = 10e3
                   ) -> np.ndarray:
    """The ``count`` most prominent peaks (Hz, ascending) of the Welch spectrum of ``x`` below
    ``top_hz``, on a log scale (prominence in decades)."""
    f, p = welch(x - x.mean(), fs=rate, nperseg=min(len(x), 8192))
    sel = (f > 5) & (f < top_hz)
    logp = np.log10(p[sel] + 1e-300)
    idx, props = find_peaks(logp, prominence=0.3)
    best = idx[np.argsort(props["prominences"])[::-1][:count]]
    return np.sort(f[sel][best])


def texture_fidelity(scene: TextureScene) -> dict:
    """The texture section's numbers (see the module docstring)."""
    sizes = np.array(list(THESIS_GRADES.values()))
    fit = fit_friction_law(scene)
    nom = nominal_response(scene)
    rate = nom["rate"]
    speed = np.array(list(TABLE_4_10_RMS_SPEED.values()))
    peaks_e = [spectral_peaks(x, rate) for x in nom["e"]]
    peaks_i = [spectral_peaks(x, rate) for x in nom["i"]]
    return {"sizes": sizes, "fit": fit, "rms_speed": nom["rms_speed"], "table_speed": speed,
            "span_speed": span_speeds(scene),
            "force": np.abs(nom["force"]), "velocity": np.abs(nom["velocity"]),
            "zm": nom["zm"], "r2_force": r_squared(sizes, np.abs(nom["force"])),
            "r2_velocity": r_squared(sizes, np.abs(nom["velocity"])),
            "r2_zm_quadratic": r_squared(sizes, nom["zm"].real, 2),
            "v_over_d": speed / (sizes * 1e-6), "peaks_e": peaks_e, "peaks_i": peaks_i,
            "free_modes": scene.transducer().omega_n / (2 * np.pi),
            "held_modes": held_tip_modes(scene.device)}


def span_speeds(scene: TextureScene) -> dict[str, np.ndarray]:
    """With ``friction.viscous_span``: per law of the mixture, the RMS tip speeds (m/s, per
    thesis grade) at the nominal set-up at the span's top c, on the law's line moved for it
    (:meth:`~wtml.scenes.texture.TextureScene.mu`): what the declared shifts keep of Table
    4.10. Empty without a span."""
    f = scene.friction
    if f.viscous_span == 0:
        return {}
    sizes = np.array(list(THESIS_GRADES.values()))
    top = f.viscous + f.viscous_span
    at_top = replace(scene, friction=replace(f, viscous=top, viscous_span=0.0))
    return {law: nominal_response(at_top, mu=scene.mu(sizes, law, top), law=law)["rms_speed"]
            for law, weight in f.law.items() if weight > 0}


def format_texture(r: dict) -> str:
    names = list(THESIS_GRADES)
    f = r["fit"]
    lines = ["## Texture (thesis §4.5-4.6), nominal set-up: 10 V, 36 Hz, 3.3e-4 N, 10°", "",
             f"Friction law fitted to Table 4.10: μ(d) = {f['intercept']:.3f} + "
             f"{f['slope']:.4f}·d/µm (line through the per-grade fit, R² {f['r2']:.4f}); "
             "per grade " + ", ".join(f"{m:.3f}" for m in f["mu_per_grade"]), "",
             "| grade | d (µm) | RMS tip speed (m/s) | Table 4.10 | error | |F| (N) | |V| (m/s) "
             "| Re Zm (N·s/m) | Im Zm (N·s/m) |", "|---|---|---|---|---|---|---|---|---|"]
    for k, n in enumerate(names):
        err = r["rms_speed"][k] / r["table_speed"][k] - 1
        lines.append(f"| {n} | {r['sizes'][k]:.1f} | {r['rms_speed'][k]:.3f} | "
                     f"{r['table_speed'][k]:.3f} | {100 * err:+.1f} % | {r['force'][k]:.3e} | "
                     f"{r['velocity'][k]:.3f} | {r['zm'][k].real:.3e} | {r['zm'][k].imag:.2e} |")
    worst = np.max(np.abs(r["rms_speed"] / r["table_speed"] - 1))
    zm = r["zm"]
    lines += ["", f"RMS speed within 10 % of Table 4.10: {'yes' if worst <= 0.1 else 'NO'} "
              f"(worst {100 * worst:.1f} %)",
              f"|F| vs d: line R² {r['r2_force']:.4f} (thesis 0.9906; > 0.99: "
              f"{'yes' if r['r2_force'] > 0.99 else 'NO'}); "
              f"|V| vs d: line R² {r['r2_velocity']:.4f} (thesis 0.9938; > 0.99: "
              f"{'yes' if r['r2_velocity'] > 0.99 else 'NO'})",
              *(f"At the viscous span's top, {law}'s moved line: RMS speed within 10 % of "
                f"Table 4.10: {'yes' if w <= 0.1 else 'NO'} (worst {100 * w:.1f} %)"
                for law, w in ((law, np.max(np.abs(v / r["table_speed"] - 1)))
                               for law, v in r["span_speed"].items())),
              f"Re Zm rises with d: {'yes' if np.all(np.diff(zm.real) > 0) else 'NO'} "
              f"(quadratic R² {r['r2_zm_quadratic']:.4f}); |Im Zm|/Re Zm at most "
              f"{np.max(np.abs(zm.imag) / zm.real):.2f}", "",
              "### Kinetic signature (Table 4.11): spectral peaks, Hz", "",
              "| grade | v/d (Table 4.10 speeds) | peaks of e(t) | peaks of i(t) |",
              "|---|---|---|---|"]
    for k, n in enumerate(names):
        lines.append(f"| {n} | {r['v_over_d'][k]:.0f} | "
                     f"{', '.join(f'{p:.0f}' for p in r['peaks_e'][k]) or '-'} | "
                     f"{', '.join(f'{p:.0f}' for p in r['peaks_i'][k])} |")
    common = _shared(r["peaks_i"])
    near_vd = [any(abs(p / r["v_over_d"][k] - 1) < 0.05 for p in r["peaks_i"][k])
               for k in range(len(names))]
    lines += ["", f"Thesis (Table 4.11), every grade: {', '.join(map(str, TABLE_4_11_PEAKS_HZ))}",
              "Modes, tip free: " + ", ".join(f"{x:.0f}" for x in r["free_modes"]
                                             if x < 10e3),
              "Modes, tip held: " + ", ".join(f"{x:.0f}" for x in r["held_modes"]
                                             if x < 10e3),
              f"Peaks of i(t) shared by all five grades (within 3 %): "
              f"{', '.join(f'{p:.0f}' for p in common) or 'none'}; "
              f"grades with a peak within 5 % of their v/d: {sum(near_vd)} of {len(names)}"]
    return "\n".join(lines)


def _shared(peaks: list[np.ndarray], tol: float = 0.03) -> list[float]:
    """The peaks of the first list that every other list has within ``tol`` (relative)."""
    return [p for p in peaks[0]
            if all(np.any(np.abs(q / p - 1) < tol) for q in peaks[1:])]


def format_tables_6_1_6_2() -> str:
    """The glycerol–water models at 25 °C against the thesis's literature columns."""
    from wtml.physics.fluids import TABLES_6_1_6_2 as lit
    from wtml.physics.fluids import glycerol_water

    eta, rho = glycerol_water(lit["cv"], 25.0)
    lines = ["## Glycerol-water at 25 °C (Tables 6.1-6.2, literature columns)", "",
             "| glycerol (vol) | η Table 6.1 (Pa·s) | η wtml | error | ρ Table 6.2 (kg/m³) | "
             "ρ wtml | error |", "|---|---|---|---|---|---|---|"]
    for k, cv in enumerate(lit["cv"]):
        lines.append(f"| {100 * cv:.1f} % | {lit['eta'][k]:.3g} | {eta[k]:.4g} | "
                     f"{100 * (eta[k] / lit['eta'][k] - 1):+.2f} % | {lit['rho'][k]:.0f} | "
                     f"{rho[k]:.1f} | {100 * (rho[k] / lit['rho'][k] - 1):+.2f} % |")
    worst = (np.max(np.abs(eta / lit["eta"] - 1)), np.max(np.abs(rho / lit["rho"] - 1)))
    lines += ["", f"worst: η {100 * worst[0]:.2f} % (Cheng 2008), ρ {100 * worst[1]:.2f} % "
              "(Volk & Kähler 2018; the table prints three digits)"]
    return "\n".join(lines)


@torch.no_grad()
def figure_5_22(scene, repeats: int = 3, seed: int = 0) -> dict:
    """The thesis's pipeline on 15 wall positions across the onset scene's reach, ``repeats``
    records each: ``actual`` and ``measured`` gap (m), the line's ``r2`` and ``slope``, and
    the ``rmse`` (m)."""
    from wtml.exporters.onset import record_inputs, thesis_pipeline

    positions = np.repeat(np.linspace(*scene.gap_range_m(), 15), repeats)
    rec = scene.simulate(len(positions), np.random.default_rng([scene.seed, seed, 522]),
                         gaps=positions)
    gap = thesis_pipeline(scene).eval()(*(torch.tensor(x) for x in record_inputs(rec)))[0]
    gap = gap.double().numpy()
    ok = np.isfinite(gap)
    slope = np.polyfit(positions[ok], gap[ok], 1)[0]
    return {"actual": positions, "measured": gap, "found": int(ok.sum()),
            "r2": r_squared(positions[ok], gap[ok]), "slope": float(slope),
            "rmse": float(np.sqrt(np.mean((gap[ok] - positions[ok]) ** 2)))}


def format_figure_5_22(r: dict) -> str:
    n = len(r["actual"])
    return "\n".join([
        "## Onset: Figure 5.22, the thesis's pipeline (measured against actual location)", "",
        f"15 wall positions × {n // 15} records, {1e6 * r['actual'].min():.1f}-"
        f"{1e6 * r['actual'].max():.1f} µm; contacts found in {r['found']} of {n}",
        f"R² {r['r2']:.4f} (thesis 0.9981), slope {r['slope']:.4f}, RMSE "
        f"{1e6 * r['rmse']:.3f} µm (thesis: uncertainty 0.27 µm)"])


def report(scene: TextureScene | None = None, onset=None) -> str:
    """The whole fidelity report (markdown): ``scene`` the texture scene, ``onset`` the onset
    scene (defaults: their configs' defaults)."""
    from wtml.physics.beam_presets import fidelity_table, format_fidelity
    from wtml.scenes.onset import OnsetScene
    from wtml.walkthrough import format_report, run_walkthrough

    scene = scene or TextureScene()
    onset = onset or OnsetScene()
    return "\n".join(["# wtml fidelity: the thesis's numbers as wtml reproduces them", "",
                      "## Presets (thesis §3.5, §5.1, §6.5)", "",
                      format_fidelity(fidelity_table()), "",
                      "## Calibration walkthrough (Tables 4.3-4.4)", "",
                      format_report(run_walkthrough(), noise=2e-4, repeats=5), "",
                      format_tables_6_1_6_2(), "",
                      format_figure_5_22(figure_5_22(onset)), "",
                      format_texture(texture_fidelity(scene))])
