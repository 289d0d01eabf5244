"""Identification on one synthetic example (wtml.physics.identify): a hidden micro device,
its free sweep written as CSV and .s1p and read back, fitted; then an unidentifiable request.

    OMP_NUM_THREADS=1 python examples/identify_demo.py [out_folder]
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np

from wtml.physics.beam_presets import build
from wtml.physics.identify import (
    IdentificationError,
    contact_ze,
    fit_device,
    format_resonance_table,
    free_ze,
    nominal_values,
    with_segment_losses,
)
from wtml.physics.measured import (
    ContactSweep,
    Measurements,
    Sweep,
    read_sweep,
    write_csv,
    write_s1p,
)
from wtml.signals.noise import complex_noise


def micro(factors):
    return build("micro", factors=factors)


def main(out: Path) -> None:
    out.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(0)
    truth = {"bimorph.length": 1.08, "coupling": 0.92, "loss_factor": 1.12, "tan_delta": 0.90}
    free = {"bimorph.length": (0.8, 1.2), "coupling": (0.8, 1.2), "loss_factor": (0.5, 2.0),
            "tan_delta": (0.5, 2.0)}
    true = with_segment_losses(micro(truth), {"whisker": 0.035})
    f = np.geomspace(250, 3000, 300)
    ze = complex_noise(free_ze(true, 2 * np.pi * f), 1e-4, rng)
    csv_path = write_csv(out / "free.csv", f, ze, form="ma")
    s1p_path = write_s1p(out / "free.s1p", f, ze)
    sweep = read_sweep(csv_path, sigma=1e-4)
    print(f"read {csv_path} and {s1p_path}: max |Δ| between them "
          f"{np.max(np.abs(read_sweep(s1p_path).ze / sweep.ze - 1)):.1e}")
    nominal = nominal_values("micro")
    fit = fit_device(micro, free, Measurements(sweep), nominal=nominal)
    print("\nTruth: the micro preset with these factors, its whisker's loss factor 0.035 "
          "(the bimorph's 0.0224): a loss model the fit (one loss factor) does not have;\n"
          "free sweep 250–3000 Hz, 300 points, noise 1e-4 relative.")
    print("| parameter | truth | fit | SE | (fit-truth)/SE | fit SI | SE SI |")
    print("|---|---|---|---|---|---|---|")
    rep = fit.report()
    for name, p in rep["parameters"].items():
        si = p["si"]
        print(f"| {name} | {truth[name]:.4f} | {p['factor']:.5f} | {p['standard_error']:.2g} | "
              f"{(p['factor'] - truth[name]) / p['standard_error']:+.2f} | "
              f"{si['value']:.5g} {si['unit']} | {si['standard_error']:.2g} {si['unit']} |")
    print(f"reduced χ² {fit.reduced_chi2:.1f}; cost {fit.cost:.1f}; residual rms "
          f"{rep['residual_rms']}")
    print()
    print(format_resonance_table(fit.table))
    print("notes:", fit.notes)
    (out / "report.json").write_text(json.dumps(rep, indent=1, allow_nan=False))
    print(f"wrote {fit.plot(out / 'bode.png')} and {out / 'report.json'}")

    whisker = {"bimorph.length": 1.05, "whisker.length": 1.06, "whisker.modulus": 0.93}
    narrow = np.geomspace(200, 1000, 200)
    tr = micro(whisker)
    m = Measurements(Sweep(narrow, complex_noise(free_ze(tr, 2 * np.pi * narrow), 1e-3, rng),
                           sigma=1e-3))
    ask = {"bimorph.length": (0.8, 1.2), "whisker.length": (0.8, 1.2),
           "whisker.modulus": (0.8, 1.2), "whisker.thickness": (0.8, 1.2)}
    print("\nUnidentifiable request (sweep 200–1000 Hz at 1e-3, the whisker's length, modulus "
          "and thickness free):")
    try:
        fit_device(micro, ask, m, vector_fit=False)
    except IdentificationError as err:
        print("refused:", err)
    pins = tuple(ContactSweep(d, Sweep(narrow, complex_noise(
        contact_ze(tr, 2 * np.pi * narrow, d), 1e-3, rng), sigma=1e-3))
        for d in (0.5e-3, 1.5e-3, 2.5e-3))
    ask = {"bimorph.length": (0.8, 1.2), "whisker.length": (0.8, 1.2),
           "whisker.modulus": (0.8, 1.2)}
    fit = fit_device(micro, ask, Measurements(m.free, contacts=pins), vector_fit=False)
    print("with three rigid pins at 0.5, 1.5, 2.5 mm from the tip (thickness held):")
    for name in ask:
        print(f"  {name}: truth {whisker[name]:.4f} fit {fit.factors[name]:.5f} "
              f"SE {fit.standard_errors[name]:.2g}")


if __name__ == "__main__":
    main(Path(sys.argv[1]) if len(sys.argv) > 1 else Path("runs/identify_demo"))
