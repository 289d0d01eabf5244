"""The fluid scene by neural posterior estimation (the ``sbi`` package), beside the decoder's
recalibrated intervals (issue 25 §4).

NPE learns the posterior of the scene's own parameters, ``θ = (volume fraction,
temperature °C)``, under its own prior (uniform in both: ``sbi.utils.BoxUniform``), from
``(θ, x)`` pairs that :meth:`wtml.scenes.fluid.FluidScene.simulate` draws: the trainer never
sees the simulator (the style of ``sbi``'s own trainers). ``x`` is what the fluid decoder's
net reads: Zm through each record's calibrated T, ``sign(Zm) log(1 + |Zm| / z)`` per
frequency, Re and Im (:func:`features`, numpy, float64). Its coverage is measured two ways on
fresh records of the scene:

- TARP (Lemos et al. 2023, ``sbi.diagnostics.run_tarp``): the expected coverage of the joint
  posterior of θ at every credibility level, and its area to the diagonal (0: calibrated,
  < 0: too narrow) with the KS p-value;
- the decoder's measure: the central 68.27 % and 95 % credible intervals of ln η and ρ (the
  posterior's samples of θ through the glycerol–water law, :func:`wtml.physics.fluids.
  glycerol_water`), the share of records whose truth they hold, per range of the truth
  (the rows ``wtml bench coverage`` sets beside the decoder's on the same records).

Needs the optional extra ``[sbi]`` (``pip install -c constraints.txt -e '.[sbi]'``).
"""

from __future__ import annotations

import time
import warnings

import numpy as np
import torch

from wtml.decoders.recalibration import NOMINAL
from wtml.physics.fluids import glycerol_water
from wtml.physics.twoport import zm_from_ze

POSTERIOR_SAMPLES = 400
"""Posterior samples per test record (credible intervals and TARP)."""
TARP_RECORDS = 500
"""Test records in the TARP curve."""


class NoTracking:
    """An ``sbi`` tracker that records nothing (``sbi``'s default writes TensorBoard files
    into the working folder); the trainer's own ``summary`` keeps the epochs and losses."""

    log_dir = None

    def log_metric(self, name: str, value: float, step: int | None = None) -> None:
        """Not kept."""

    def log_metrics(self, metrics: dict[str, float], step: int | None = None) -> None:
        """Not kept."""

    def log_params(self, params: dict) -> None:
        """Not kept."""

    def add_figure(self, name: str, figure, step: int | None = None) -> None:
        """Not kept."""

    def flush(self) -> None:
        """Nothing is buffered."""


def features(ze: np.ndarray, t: np.ndarray, z_scale: float) -> np.ndarray:
    """``x`` of a record: ``sign(Zm) log(1 + |Zm| / z_scale)`` of Re and Im Zm, Zm through
    each record's calibrated T; ``ze`` complex ``(n, n_freq)`` Ω, ``t`` ``(n, n_freq, 2,
    2)``, ``z_scale`` N·s/m -> ``(n, 2 n_freq)`` float32."""
    zm = zm_from_ze(t, ze)
    parts = np.concatenate([zm.real, zm.imag], -1)
    return (np.sign(parts) * np.log1p(np.abs(parts) / z_scale)).astype(np.float32)


def theta_of(records: dict) -> np.ndarray:
    """θ of records of the fluid scene: ``(volume fraction, temperature °C)``, ``(n, 2)``."""
    return np.stack([records["volume_fraction"], records["temperature_c"]], 1).astype(
        np.float32)


def credible_hits(samples: np.ndarray, truth: np.ndarray) -> np.ndarray:
    """Whether the central 68.27 % and 95 % intervals of posterior ``samples`` ``(S, n)``
    hold each ``truth`` ``(n,)``: ``(n, 2)`` float (1 or 0)."""
    out = []
    for level in NOMINAL:
        lo, hi = np.quantile(samples, [(1 - level) / 2, (1 + level) / 2], axis=0)
        out.append((truth >= lo) & (truth <= hi))
    return np.stack(out, 1).astype(float)


def run_npe(scene, test: dict, *, simulations: int = 20000, seed: int = 0,
            max_epochs: int = 200, threads: int = 2) -> dict:
    """Train NPE on ``simulations`` fresh records of ``scene`` and score it on ``test``
    (records of the scene, e.g. the coverage bench's fresh ones).

    Returns:
        ``{"rows": {"eta": [row], "rho": [row]}`` (the coverage bench's ``extra`` rows:
        :func:`credible_hits` on ``test``), ``"report"`` (markdown lines) and ``"summary"``
        (TARP's area and KS p-value, the curve, the training and sampling times).
    """
    from sbi.diagnostics import check_tarp, run_tarp
    from sbi.inference import NPE
    from sbi.utils import BoxUniform

    torch.set_num_threads(threads)
    torch.manual_seed(seed)
    z_scale = 0.01 * scene.reference_zm()
    r = scene.fluid
    prior = BoxUniform(low=torch.tensor([r.volume_fraction[0], r.temperature_c[0]]),
                       high=torch.tensor([r.volume_fraction[1], r.temperature_c[1]]))
    train = scene.simulate(simulations, np.random.default_rng([seed, 31]))
    start = time.perf_counter()
    inference = NPE(prior=prior, density_estimator="zuko_nsf", show_progress_bars=False,
                    tracker=NoTracking())
    inference.append_simulations(torch.from_numpy(theta_of(train)),
                                 torch.from_numpy(features(train["ze"], train["t"], z_scale)))
    with warnings.catch_warnings():
        # sbi's own note that max_epochs stopped it: the summary says so (converged: false)
        warnings.filterwarnings("ignore", message="Maximum number of epochs")
        estimator = inference.train(max_num_epochs=max_epochs, training_batch_size=256)
    trained_s = time.perf_counter() - start
    epochs = inference.summary["epochs_trained"][-1]
    converged = epochs < max_epochs
    posterior = inference.build_posterior(estimator)
    x = torch.from_numpy(features(test["ze"], test["t"], z_scale))
    start = time.perf_counter()
    theta = posterior.sample_batched((POSTERIOR_SAMPLES,), x=x, show_progress_bars=False,
                                     max_sampling_batch_size=max(1, 100_000 // len(x))
                                     ).numpy().astype(float)
    sampled_s = time.perf_counter() - start
    eta, rho = glycerol_water(np.clip(theta[..., 0], 0.0, 1.0), theta[..., 1])
    rows = {}
    for name, samples, truth in (("eta", np.log(eta), np.log(test["eta"])),
                                 ("rho", rho, test["rho"])):
        rows[name] = [{"name": "fresh records of the trained scene", "kind": "in family",
                       "label": f"sbi NPE ({simulations} simulations): central credible",
                       "truth": test[name], "hits": credible_hits(samples, truth),
                       "flagged": None}]
    k = min(TARP_RECORDS, len(x))
    with warnings.catch_warnings():
        # TARP samples with sbi's default batch, which sbi caps to its memory limit
        warnings.filterwarnings("ignore", message="Capping max_sampling_batch_size")
        ecp, alpha = run_tarp(torch.from_numpy(theta_of(test)[:k]), x[:k], posterior,
                              num_posterior_samples=POSTERIOR_SAMPLES,
                              show_progress_bar=False)
    atc, ks = check_tarp(ecp, alpha)
    curve = {f"{a:.2f}": float(e) for a, e in zip(alpha.numpy(), ecp.numpy(), strict=True)
             if abs(a * 20 - round(a * 20)) < 1e-6}
    report = [
        "## sbi: neural posterior estimation on the fluid scene", "",
        f"NPE (sbi, a neural spline flow, zuko) on {simulations} simulations of the scene, θ = "
        f"(volume fraction, temperature) under its uniform prior, x the decoder's features "
        f"(signed-log Zm through each record's T); trained {trained_s:.0f} s ({epochs} "
        f"epochs, {'converged' if converged else 'stopped at max_epochs'}), "
        f"{POSTERIOR_SAMPLES} posterior samples for each of {len(x)} records in "
        f"{sampled_s:.1f} s. Its central credible intervals of ln η and ρ are the rows "
        f"'sbi NPE' in the fluid tables above, on the same records as the decoder's "
        f"'fresh records' rows.", "",
        f"TARP on {k} records (joint θ): area to the diagonal {float(atc):+.3f} (0: "
        f"calibrated; < 0 too narrow, > 0 too wide), KS p-value {float(ks):.3f}; expected "
        "coverage at credibility 0.25 / 0.50 / 0.68 / 0.95: "
        + " / ".join(f"{_at(alpha, ecp, a):.3f}" for a in (0.25, 0.5, 0.6827, 0.95)) + ".",
        ""]
    summary = {"simulations": simulations, "epochs": int(epochs), "converged": converged,
               "train_s": trained_s,
               "sample_s": sampled_s, "test_records": len(x), "tarp_records": k,
               "tarp_atc": float(atc), "tarp_ks_p": float(ks), "tarp_curve": curve}
    return {"rows": rows, "report": report, "summary": summary}


def _at(alpha: torch.Tensor, ecp: torch.Tensor, level: float) -> float:
    """The TARP curve's expected coverage at credibility ``level`` (interpolated)."""
    return float(np.interp(level, alpha.numpy(), ecp.numpy()))
