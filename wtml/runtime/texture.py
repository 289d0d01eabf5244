"""The texture task on a device: ``wtml predict`` on records (the export:
:mod:`wtml.exporters.texture`).

Both graphs take ``e`` (V) and ``i`` (A), float32 ``(batch, window)`` at the scene's rate,
and the user's calibrated T of their device at the scene's ``calibration_hz`` as ``t_re, t_im``
``(batch, K, 4)`` (t11, t12, t21, t22; the metadata's ``calibration_hz`` and ``references``
say so, and ``wtml predict --calibration cal.npz`` reads it), and return ``grain`` (m),
``log_sigma`` (std of ln grain; NaN out of domain, 0 for the classical path) and
``probabilities`` ``(batch, 5)`` over the thesis's grades, then ``in_domain`` and
``domain_score``. A longer record is cut into whole windows; its answer is
the windows' mean log-probabilities and mean ln grain.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from wtml.physics.twoport import flat_parts
from wtml.runtime.instruments import RecordingProfile
from wtml.runtime.predict import impossible, load_export, read_calibration, rows_per_run
from wtml.runtime.recordings import read_record


def windows(x: np.ndarray, window: int) -> tuple[np.ndarray, np.ndarray]:
    """Cut ``(c, n_records, n)`` records (c channels: e and i, or one of them) into whole
    windows: ``(c, n_windows, window)`` and each window's record index."""
    per = x.shape[2] // window
    if per < 1:
        raise ValueError(f"records of {x.shape[2]} samples are shorter than the model's window "
                         f"({window} samples)")
    cut = x[:, :, :per * window].reshape(len(x), x.shape[1] * per, window)
    return cut, np.repeat(np.arange(x.shape[1]), per)


def pool(pred: dict[str, np.ndarray], owner: np.ndarray, n: int) -> dict[str, np.ndarray]:
    """Per record: mean log-probabilities (renormalised), mean ln grain, all windows in
    domain."""
    with np.errstate(divide="ignore", invalid="ignore"):  # a grain <= 0 pools to NaN, flagged
        return _pool(pred, owner, n)


def _pool(pred: dict[str, np.ndarray], owner: np.ndarray, n: int) -> dict[str, np.ndarray]:
    logp = np.log(np.clip(pred["probabilities"], 1e-12, 1.0))
    out = {"probabilities": np.zeros((n, logp.shape[1])), "grain": np.zeros(n),
           "in_domain": np.zeros(n, bool), "domain_score": np.zeros(n)}
    for r in range(n):
        sel = owner == r
        lp = logp[sel].mean(0)
        p = np.exp(lp - lp.max())
        out["probabilities"][r] = p / p.sum()
        out["grain"][r] = np.exp(np.mean(np.log(pred["grain"][sel])))
        out["in_domain"][r] = bool(pred["in_domain"][sel].all())
        out["domain_score"][r] = float(pred["domain_score"][sel].max())
    return out


def run_windows(model, e: np.ndarray, i: np.ndarray, t: np.ndarray) -> dict[str, np.ndarray]:
    """``model`` (an :class:`~wtml.runtime.predict.OnnxModel` of this task) on windows e, i
    ``(n, window)`` through the calibrated T ``t`` (complex ``(n, K, 2, 2)``)."""
    return model.run(e, i, *flat_parts(t))


def window_batches(x: np.ndarray, window: int, batch: int):
    """Whole windows of ``(2, n_records, n)`` records, ``batch`` at a time (every record's
    windows in order, record after record): yields ``(2, b, window)`` copies and each
    window's record index, so that the windows of a long recording never exist all at once."""
    per = x.shape[2] // window
    if per < 1:
        raise ValueError(f"records of {x.shape[2]} samples are shorter than the model's window "
                         f"({window} samples)")
    total = x.shape[1] * per
    span = np.arange(window)
    for start in range(0, total, batch):
        record, k = np.divmod(np.arange(start, min(start + batch, total)), per)
        yield x[:, record[:, None], k[:, None] * window + span], record


def predict_records(model_dir: str | Path, input_path: str | Path, *,
                    calibration: str | Path | None = None,
                    profile: RecordingProfile | None = None) -> list[dict]:
    """One row per record and method: grade probabilities, the likeliest grade, grain size
    (µm), ``in_domain``, ``domain_score`` and flags. ``calibration``: the device's calibrated
    T at the export's ``calibration_hz`` (npz with ``frequency_hz`` and ``t``, complex ``(K,
    2, 2)`` or one per record ``(n, K, 2, 2)``), which the graph needs (:class:`InputError`
    without it, never a default device). A long recording's windows run in batches of
    :data:`wtml.runtime.predict.RUN_BYTES`: memory grows with the recording, not with its
    number of windows. ``profile``: how to read an instrument's recording
    (:mod:`wtml.runtime.instruments`)."""
    decoder, classical = load_export(model_dir)
    meta = decoder.meta
    window = meta.n_samples
    freq = np.array(meta.calibration_hz)
    x = read_record(input_path, meta.sample_rate_hz, window, at_least=True,
                    profile=profile)
    t = read_calibration(calibration, freq, x.shape[1], "texture")
    batch = rows_per_run(8 * window)
    names = list(meta.classes)
    rows = []
    for label, model in (("decoder", decoder), ("classical", classical)):
        parts, owners = [], []
        for cut, owner in window_batches(x, window, batch):
            parts.append(run_windows(model, cut[0], cut[1], t[owner]))
            owners.append(owner)
        pred = pool({k: np.concatenate([p[k] for p in parts]) for k in parts[0]},
                    np.concatenate(owners), x.shape[1])
        odd = impossible(model, {"grain": pred["grain"]})["grain"]
        for r in range(x.shape[1]):
            p = pred["probabilities"][r]
            flags = [] if pred["in_domain"][r] else ["outside the trained domain"]
            if odd[r]:
                flags.append("grain physically impossible")
            rows.append({"record": r, "method": label, "grade": names[int(np.argmax(p))],
                         **{f"p({n})": float(v) for n, v in zip(names, p, strict=True)},
                         "grain (um)": float(pred["grain"][r] * 1e6),
                         "in_domain": bool(pred["in_domain"][r]),
                         "domain_score": float(pred["domain_score"][r]),
                         "flags": "; ".join(flags)})
    return rows
