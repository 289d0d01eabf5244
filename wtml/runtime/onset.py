"""Onset models on a device: export, reading records, and contacts from the graphs' outputs.

Both graphs (``model.onnx``: the decoder; ``classical.onnx``: the thesis's pipeline) take
``e`` (V) and ``i`` (A), float32 ``(batch, n_samples)`` at the trained sampling rate, and
return ``gap`` (m), ``sigma`` (m; NaN for the classical path and out of domain), ``contact``
(``(batch, n_frames)``: a probability per probe frame for the decoder, a 0/1 state per sample
for the classical path), ``in_domain`` and ``domain_score``. The metadata says how frames map
to time (``frame_s``, ``onset_offset_s``, ``detach_offset_s``, ``merge_s``), so every device
turns ``contact`` into intervals the same way (:func:`contacts_from`).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import torch

from wtml import __version__
from wtml.baselines.onset_classical import ThesisOnset
from wtml.decoders.domain import Gated
from wtml.decoders.onset import frame_period
from wtml.runtime.export import _export, domain_metadata
from wtml.runtime.predict import InputError
from wtml.scenes import config_hash
from wtml.scenes.onset import intervals

ONSET_INPUTS = ("e", "i")
ONSET_OUTPUTS = ("gap", "sigma", "contact")
FRESH_RECORDS = 64
"""Fresh records of the scene on which the exported decoder's false-alarm rate is measured."""


def thesis_pipeline(scene) -> ThesisOnset:
    """The classical path for ``scene``: calibrated T at the probe and HUE(0), threshold at
    half of ``k_ref/ωH``."""
    model = scene.transducer()
    wh = 2 * np.pi * scene.drive.probe_hz
    return ThesisOnset(scene.acquisition.sample_rate_hz, scene.drive.probe_hz,
                       model.transduction_matrix(np.array([wh]))[0],
                       model.static_tip_displacement_per_volt(),
                       0.5 * scene.reference_stiffness() / wh)


@torch.no_grad()
def export_onset(module, scene, out: Path) -> dict[str, Path]:
    """Write the onset decoder and the thesis pipeline, each with the decoder's domain gate,
    to ``out/model.onnx`` and ``out/classical.onnx``."""
    decoder = Gated(module.net, module.gate, (1,)).eval()
    fresh = scene.simulate(FRESH_RECORDS, np.random.default_rng([scene.seed, 10**6 + 1]))
    inside = decoder(torch.tensor(fresh["e"]), torch.tensor(fresh["i"]))[-2]
    domain = domain_metadata(scene, float(1 - inside.float().mean()), FRESH_RECORDS)
    rate = scene.acquisition.sample_rate_hz
    period = frame_period(scene)
    merge = scene.merge_periods / scene.drive.probe_hz
    on_off = [float(x) for x in module.offsets]
    meta = {"wtml_version": __version__, "task": "onset",
            "inputs": json.dumps(list(ONSET_INPUTS)), "outputs": json.dumps(list(ONSET_OUTPUTS)),
            "units": json.dumps({"gap": "m", "sigma": "m", "contact": "1", "e": "V", "i": "A"}),
            "frequency_hz": json.dumps([scene.drive.probe_hz]),
            "sample_rate_hz": json.dumps(rate), "n_samples": json.dumps(scene.n_samples),
            "merge_s": json.dumps(merge),
            "scene": json.dumps(module.scene, sort_keys=True), "scene_hash": config_hash(scene),
            "domain": json.dumps(domain)}
    paths = {"decoder": out / "model.onnx", "classical": out / "classical.onnx"}
    frames = {"frame_s": json.dumps(period / rate), "onset_offset_s": json.dumps(on_off[0]),
              "detach_offset_s": json.dumps(on_off[1])}
    samples = {"frame_s": json.dumps(1 / rate), "onset_offset_s": "0.0",
               "detach_offset_s": "0.0"}
    _export(decoder, scene.n_samples, paths["decoder"],
            meta | frames | {"kind": "decoder", "label": "decoder"}, ONSET_INPUTS)
    classical = Gated(thesis_pipeline(scene), module.gate.inputs_only()).eval()
    _export(classical, scene.n_samples, paths["classical"],
            meta | samples | {"kind": "classical", "label": "thesis pipeline"}, ONSET_INPUTS)
    return paths


def contacts_from(contact: np.ndarray, metadata: dict) -> tuple[np.ndarray, np.ndarray]:
    """Onset and detachment times (s) of each record's contacts from a graph's ``contact``
    output ``(n, n_frames)`` and its metadata; each ``(n, max_contacts)``, NaN-padded."""
    frame_s = json.loads(metadata["frame_s"])
    max_count = json.loads(metadata["scene"]).get("max_contacts", 8)
    start, end = intervals(contact > 0.5, 1 / frame_s, json.loads(metadata["merge_s"]),
                           max_count)
    # intervals() gives frame boundaries; the contact starts/ends at a fixed phase in a frame
    onset = start + json.loads(metadata["onset_offset_s"])
    detach = end - frame_s + json.loads(metadata["detach_offset_s"])
    return onset, detach


def read_record(path: str | Path, sample_rate_hz: float, n_samples: int) -> np.ndarray:
    """``e`` and ``i`` of a ``rec.npz`` as float32 ``(2, n, n_samples)`` at the trained rate.

    The file holds ``e`` (V) and ``i`` (A), each ``(n_samples,)`` or ``(n_records,
    n_samples)``, and ``sample_rate_hz``. Another rate is resampled (polyphase, when the two
    rates have a ratio of small whole numbers) or refused; the duration must match the
    trained record's.

    Raises:
        InputError: missing keys, mismatched shapes, NaN, an unusable rate or length.
    """
    from fractions import Fraction

    from scipy.signal import resample_poly

    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: no such input file")
    try:
        with np.load(path, allow_pickle=False) as data:
            missing = {"e", "i", "sample_rate_hz"} - set(data.files)
            if missing:
                raise InputError(f"{path}: an onset record needs 'e' (V), 'i' (A) and "
                                 f"'sample_rate_hz'; missing {sorted(missing)}")
            e, i = np.atleast_2d(data["e"]).astype(float), np.atleast_2d(data["i"]).astype(float)
            rate = float(data["sample_rate_hz"])
    except InputError:
        raise
    except (OSError, ValueError, EOFError, KeyError) as err:
        raise InputError(f"{path}: not a readable .npz of numeric arrays "
                         f"({type(err).__name__}); write it with numpy.savez") from None
    if e.shape != i.shape or e.ndim != 2:
        raise InputError(f"{path}: e and i must have the same shape (n_samples,) or "
                         f"(n_records, n_samples); got {e.shape} and {i.shape}")
    if not np.isfinite(rate) or rate <= 0:
        raise InputError(f"{path}: sample_rate_hz must be > 0, got {rate}")
    if not (np.isfinite(e).all() and np.isfinite(i).all()):
        raise InputError(f"{path}: e or i holds NaN or inf")
    if rate != sample_rate_hz:
        ratio = Fraction(sample_rate_hz / rate).limit_denominator(1000)
        if abs(float(ratio) - sample_rate_hz / rate) > 1e-9 * sample_rate_hz / rate:
            raise InputError(f"{path}: recorded at {rate:g} Hz; the model was trained at "
                             f"{sample_rate_hz:g} Hz and the ratio is not a ratio of whole "
                             "numbers up to 1000: resample it first")
        e = resample_poly(e, ratio.numerator, ratio.denominator, axis=1)
        i = resample_poly(i, ratio.numerator, ratio.denominator, axis=1)
    if e.shape[1] != n_samples:
        raise InputError(f"{path}: {e.shape[1]} samples at {sample_rate_hz:g} Hz "
                         f"({e.shape[1] / sample_rate_hz:g} s); the model takes records of "
                         f"{n_samples} ({n_samples / sample_rate_hz:g} s)")
    return np.stack([e, i]).astype(np.float32)


def predict_records(model_dir: str | Path, input_path: str | Path) -> list[dict]:
    """One row per contact (and one per record without any) for the decoder and the
    classical path: ``record``, ``method``, ``contact``, ``onset (s)``, ``detachment (s)``,
    ``gap (m)``, ``sigma (m)``, ``in_domain``, ``domain_score``, ``flags``."""
    from wtml.runtime.predict import impossible, load_export

    decoder, classical = load_export(model_dir)
    meta = decoder.metadata
    x = read_record(input_path, json.loads(meta["sample_rate_hz"]),
                    json.loads(meta["n_samples"]))
    rows = []
    for label, model in (("decoder", decoder), ("classical", classical)):
        pred = model.run(x[0], x[1])
        onset, detach = contacts_from(pred["contact"], model.metadata)
        odd = impossible(model, pred)["gap"]
        for r in range(x.shape[1]):
            flags = []
            if not pred["in_domain"][r]:
                flags.append("outside the trained domain" if pred["domain_score"][r] > 1
                             else "answer outside the trained range")
            if odd[r] and np.isfinite(pred["gap"][r]):
                flags.append("gap physically impossible")
            base = {"record": r, "method": label, "gap (m)": float(pred["gap"][r]),
                    "sigma (m)": float(pred["sigma"][r]),
                    "in_domain": bool(pred["in_domain"][r]),
                    "domain_score": float(pred["domain_score"][r]), "flags": "; ".join(flags)}
            found = np.flatnonzero(np.isfinite(onset[r]))
            for k in found if len(found) else [None]:
                rows.append({"record": r, "method": label,
                             "contact": -1 if k is None else int(k),
                             "onset (s)": float("nan") if k is None else float(onset[r, k]),
                             "detachment (s)": float("nan") if k is None else float(detach[r, k]),
                             **{key: v for key, v in base.items()
                                if key not in ("record", "method")}})
    return rows
