"""Recordings of ``e`` (V) and ``i`` (A) read for the time-domain exports (onset, texture):
the file's format found from its suffix, its samples scaled to volts and amperes, its rate
checked against the model's and, where the two differ by a ratio of small whole numbers,
resampled (scipy, imported only then).

Formats: ``.npz`` (:func:`open_npz`: ``e``, ``i`` and ``sample_rate_hz``, already in V and
A), and those instruments write (:mod:`wtml.runtime.instruments`: LabVIEW TDMS, WAV, CSV,
read through a :class:`~wtml.runtime.instruments.RecordingProfile`). A reader only opens the
file and states what it holds (:class:`~wtml.runtime.instruments.Recording`); every sample is
read after the memory the work will take has been checked (:func:`read_record`).
"""

from __future__ import annotations

from collections.abc import Callable
from fractions import Fraction
from pathlib import Path

import numpy as np

from wtml.files import (
    check_array,
    check_header,
    npz_headers,
    read_npz,
    regular_file,
    scalar,
    within_ceiling,
)
from wtml.runtime.instruments import READERS, Recording, RecordingProfile
from wtml.runtime.predict import ROW_BYTES, InputError, float32_range

RECORD_FORMATS = (".npz", *READERS)
"""The suffixes :func:`read_record` reads."""


def open_npz(path: Path, profile: RecordingProfile | None) -> Recording:
    """An ``.npz`` record: ``e`` (V) and ``i`` (A), each ``(n_samples,)`` or ``(n_records,
    n_samples)``, real, and ``sample_rate_hz`` (one number); headers only until loaded. It
    holds volts and amperes already: a profile is refused."""
    if profile is not None and profile.given():
        raise InputError(f"{path}: an .npz record holds e in V and i in A at its own "
                         f"sample_rate_hz; a recording profile or scale options apply to "
                         f"{', '.join(READERS)} files only")
    where = str(path)
    heads = npz_headers(path, what="record")
    missing = {"e", "i", "sample_rate_hz"} - set(heads)
    if missing:
        raise InputError(f"{path}: a record needs 'e' (V), 'i' (A) and "
                         f"'sample_rate_hz'; missing {sorted(missing)}")
    for key in ("e", "i"):
        check_header(where, key, *heads[key], ndim=(1, 2))
    shape = heads["e"][0]
    if shape != heads["i"][0]:
        raise InputError(f"{path}: e and i must have the same shape (n_samples,) or "
                         f"(n_records, n_samples); got {shape} and {heads['i'][0]}")
    rate = scalar(where, "sample_rate_hz", read_npz(path, keys=("sample_rate_hz",))[
        "sample_rate_hz"], low=1e-3, high=1e12)

    def load(key: str) -> np.ndarray:
        x = check_array(where, key, read_npz(path, keys=(key,))[key], ndim=(1, 2))
        return np.atleast_2d(x)

    return Recording(where, (1, *shape) if len(shape) == 1 else tuple(shape),
                     heads["e"][1].itemsize, rate, load)


def open_recording(path: str | Path, profile: RecordingProfile | None = None) -> Recording:
    """The recording in ``path``, read by its suffix's reader (:data:`RECORD_FORMATS`).

    Raises:
        InputError: a missing or irregular file, an unknown suffix, or what the reader finds
            missing or inconsistent (one line naming the file and the key).
    """
    path = regular_file(path, what="input file")
    suffix = path.suffix.lower()
    if suffix == ".npz":
        return open_npz(path, profile)
    if suffix not in READERS:
        raise InputError(f"{path}: a recording must be one of {', '.join(RECORD_FORMATS)} (see "
                         "wtml predict --help)")
    return READERS[suffix](path, profile or RecordingProfile())


def record_cost(n: int, n_in: int, n_out: int, itemsize: int) -> int:
    """Bytes that reading ``n`` records of ``n_in`` samples per channel (stored with
    ``itemsize`` bytes a sample) and resampling them to ``n_out`` take at their peak: the
    float32 answer ``(2, n, n_out)``, then per channel the loaded array, its float64 copy, and
    the resampled array with scipy's working copy of it."""
    return 8 * n * n_out + n * n_in * (itemsize + 8) + 16 * n * n_out * (n_out != n_in)


def resampling(where: str, rate: float, sample_rate_hz: float) -> tuple[int, int]:
    """``(up, down)``: the whole numbers (up to 1000) whose ratio takes ``rate`` to
    ``sample_rate_hz`` (``(1, 1)`` when they are equal).

    Raises:
        InputError: no such ratio (naming both rates).
    """
    if rate == sample_rate_hz:
        return 1, 1
    ratio = Fraction(sample_rate_hz / rate).limit_denominator(1000)
    if abs(float(ratio) - sample_rate_hz / rate) > 1e-9 * sample_rate_hz / rate:
        raise InputError(f"{where}: recorded at {rate:g} Hz; the model was trained at "
                         f"{sample_rate_hz:g} Hz and the ratio is not a ratio of whole "
                         "numbers up to 1000: resample it first")
    return ratio.numerator, ratio.denominator


def resample(x: np.ndarray, up: int, down: int, where: str) -> np.ndarray:
    """``x`` ``(n, n_in)`` resampled by ``up / down`` along its last axis (polyphase: scipy,
    which the runtime needs only here).

    Raises:
        InputError: scipy is not installed (naming the extra that brings it).
    """
    try:
        from scipy.signal import resample_poly
    except ImportError:
        raise InputError(f"{where}: resampling to the model's rate needs scipy, which this "
                         "install lacks: pip install 'wtml[resample]', or record at the "
                         "model's rate") from None
    return resample_poly(x, up, down, axis=1)


def read_record(path: str | Path, sample_rate_hz: float, n_samples: int, *,
                at_least: bool = False, rows_per_record: int = 2,
                work_per_sample: int = 0, profile: RecordingProfile | None = None,
                length_check: Callable[[str, int], object] | None = None) -> np.ndarray:
    """``e`` and ``i`` of a recording (:func:`open_recording`; ``profile``: how to read an
    instrument's file) as float32 ``(2, n, n_samples)`` at the trained rate (``at_least``: any
    length from ``n_samples`` up, for models fed windows; ``length_check(where, n_out)``:
    the caller's own rule for the length at the trained rate, raising :class:`InputError`,
    applied before any sample is read).

    Another rate is resampled (polyphase, when the two rates have a ratio of small whole
    numbers) or refused; the duration must match the trained record's (or reach it,
    ``at_least``). Everything is checked from what the reader found before any sample is
    read, the work's memory (:func:`record_cost`, ``rows_per_record`` rows of the answer per
    record and ``work_per_sample`` bytes per sample of what the caller makes of the records)
    against :data:`wtml.files.MEMORY_CEILING` included.

    Raises:
        InputError: missing keys or channels, mismatched arrays, no records, NaN, an unusable
            rate or length, more memory than the ceiling.
    """
    rec = open_recording(path, profile)
    n, n_in = rec.shape
    if n == 0 or n_in == 0:
        raise InputError(f"{rec.where}: holds no records (e and i have shape {rec.shape}); "
                         "give (n_samples,) or (n_records, n_samples) with both at least 1")
    up, down = resampling(rec.where, rec.rate, sample_rate_hz)
    n_out = -(-n_in * up // down)
    if n_out < n_samples if at_least else n_out != n_samples:
        raise InputError(f"{rec.where}: {n_out} samples at {sample_rate_hz:g} Hz "
                         f"({n_out / sample_rate_hz:g} s); the model takes records of "
                         f"{'at least ' if at_least else ''}{n_samples} "
                         f"({n_samples / sample_rate_hz:g} s)")
    if length_check is not None:
        length_check(rec.where, n_out)
    need = (record_cost(n, n_in, n_out, rec.itemsize)
            + rows_per_record * n * ROW_BYTES + work_per_sample * n * n_out)
    within_ceiling(f"{rec.where}: e and i {rec.shape} at {rec.rate:g} Hz", need,
                   f"reading {n} record(s)" + (f" resampled to {sample_rate_hz:g} Hz "
                                               f"({n_out} samples each)" if up != down else ""))
    out = np.empty((2, n, n_out), np.float32)
    for k, key in enumerate(("e", "i")):
        x = rec.load(key)
        if x.shape != (n, n_in):
            raise InputError(f"{rec.where}: '{key}' holds {x.shape} samples, not the "
                             f"{(n, n_in)} its header said")
        if not np.isfinite(x).all():
            first = np.unravel_index(np.flatnonzero(~np.isfinite(x))[0], x.shape)
            raise InputError(f"{rec.where}: '{key}' is NaN or inf at index "
                             f"{tuple(map(int, first))}")
        if up != down:
            x = resample(x, up, down, rec.where)
        float32_range(rec.where, key, x)
        out[k] = x[:, :n_out]
        del x
    return out
