"""Recordings as instruments write them: LabVIEW TDMS, WAV and CSV.

Each reader (:data:`READERS`, by suffix) opens a file, finds the two channels (``e``, the
voltage across the transducer; ``i``, its current, usually recorded as the voltage of an I-V
converter), checks that they have equal lengths, a numeric type and one sampling rate, and
states what it found (:class:`Recording`) before any sample is read:
:func:`wtml.runtime.recordings.read_record` checks the length, the rate against the model's
and the memory the work will take, then loads each channel in V and A.

How to read a file (its group and channel names, the scale of each channel, the full scale of
integer samples, a rate the file does not state) is a :class:`RecordingProfile`, from a small
YAML file and command-line options (:func:`load_profile`). Nothing is assumed where a file
leaves a quantity open: integer samples need the interface's full scale, a current recorded
as a voltage needs the converter's scale, and a rate stated twice (by the file and the
profile) must agree. Every refusal is one line naming the file and the key.

Imports the standard library, numpy, :mod:`wtml.files` and :mod:`wtml.schema` only, and
npTDMS (the ``tdms`` extra) when a ``.tdms`` file is read.
"""

from __future__ import annotations

import csv
import logging
import struct
from array import array
from collections.abc import Callable, Iterator, Mapping
from contextlib import contextmanager
from dataclasses import dataclass, fields
from pathlib import Path
from typing import Any

import numpy as np

from wtml.files import CSV_MAX_BYTES, FileError, regular_file
from wtml.schema import SchemaError, bounded, build, read_yaml

RATE_RANGE = (1e-3, 1e12)
"""Hz: the sampling rates a recording may have."""
RATE_AGREEMENT = 1e-9
"""The largest relative difference between two statements of one sampling rate (the file's
channels, the file and the profile)."""
TIME_TOLERANCE = 0.25
"""Sample spacings: how far a CSV's times may lie from a uniform grid. Their printed digits'
rounding moves them (7 significant digits of 2 s at 27 kHz: up to 1.3 % of a spacing); a
missing or repeated row moves them by a whole spacing."""
_WAV_GUID_TAIL = bytes.fromhex("000000001000800000aa00389b71")
"""Bytes 2-15 of a WAVE_FORMAT_EXTENSIBLE subformat GUID (bytes 0-1: the format tag)."""


class RecordingError(FileError):
    """An instrument's recording that cannot be read as it is, or a profile that does not fit
    it (the message names the file and the key, and says what to give)."""


@dataclass(frozen=True)
class Recording:
    """What a reader found in a file before reading its samples.

    Attributes:
        where: the file, as messages name it.
        shape: ``(n_records, n_samples)`` of each channel.
        itemsize: bytes per stored sample (for the memory check).
        rate: samples per second (Hz).
        load: ``"e"`` or ``"i"`` -> that channel, float64 ``(n_records, n_samples)``, in V
            and A (scaled as the profile says).
    """

    where: str
    shape: tuple[int, int]
    itemsize: int
    rate: float
    load: Callable[[str], np.ndarray]


@dataclass(frozen=True)
class RecordingProfile:
    """How to read an instrument's recording (all None: the format's defaults).

    Attributes:
        group: the TDMS group holding both channels (default: the file's only group).
        e_channel: ``e``'s TDMS channel or CSV column (default ``"e"``), or WAV channel index
            as text (default ``"0"``).
        i_channel: ``i``'s, likewise (defaults ``"i"`` and ``"1"``).
        e_scale: V of ``e`` per recorded V (a probe's or divider's ratio; default 1).
        i_scale: A of ``i`` per recorded V: the inverse of the I-V converter's transimpedance.
            Required for WAV and integer samples (a voltage then); default 1 for float TDMS
            and CSV, which may hold amperes already.
        full_scale_v: V at the integer full scale of the interface: a signed ``b``-bit count
            ``c`` is ``c / 2**(b-1) * full_scale_v`` volts, an unsigned one (8-bit WAV)
            ``(c - 2**(b-1)) / 2**(b-1) * full_scale_v``. Required for integer samples,
            refused for floats.
        sample_rate_hz: the rate (Hz) for a file that states none (a CSV with a sample
            column, a TDMS without ``wf_increment``); where the file states one, it must agree.
    """

    group: str | None = None
    e_channel: str | None = None
    i_channel: str | None = None
    e_scale: float | None = bounded(1e-12, 1e12, default=None)
    i_scale: float | None = bounded(1e-12, 1e12, default=None)
    full_scale_v: float | None = bounded(1e-9, 1e6, default=None)
    sample_rate_hz: float | None = bounded(*RATE_RANGE, default=None)

    def given(self) -> bool:
        """Whether any key is set."""
        return any(getattr(self, f.name) is not None for f in fields(self))


_NAMES = ("group", "e_channel", "i_channel")
"""The profile's keys that name something: a number in YAML (``e_channel: 0``) is its text."""


def _as_names(data: Any) -> Any:
    """``data`` with the whole numbers of the naming keys as text (non-mappings as they are,
    for :func:`wtml.schema.build` to refuse)."""
    if not isinstance(data, Mapping):
        return data
    return {k: str(v) if k in _NAMES and isinstance(v, int) and not isinstance(v, bool) else v
            for k, v in data.items()}


def load_profile(path: str | Path | None = None, **overrides: Any) -> RecordingProfile | None:
    """The recording profile in YAML file ``path`` (keys: :class:`RecordingProfile`'s),
    with each of ``overrides`` (the same names: command-line options) that is not None in place
    of the file's; None when neither gives anything.

    Raises:
        SchemaError: an unknown key, a value of the wrong type or out of its range (naming the
            file or the options, the key and the allowed range).
        FileError: the file is missing, not a regular file or too large.
    """
    given = {k: v for k, v in overrides.items() if v is not None}
    if path is None and not given:
        return None
    data: Any = {}
    if path is not None:
        data = _as_names(read_yaml(path, what="recording profile"))
        try:
            build(RecordingProfile, data)
        except SchemaError as err:
            raise SchemaError(f"{path}: {err}") from None
    try:
        return build(RecordingProfile, {**data, **_as_names(given)})
    except SchemaError as err:
        raise SchemaError(f"recording profile options: {err}") from None


def _no_group(where: str, profile: RecordingProfile, what: str) -> None:
    """Refuse a profile's TDMS ``group`` for a file without groups (``what``: its kind)."""
    if profile.group is not None:
        raise RecordingError(f"{where}: group {profile.group!r}: {what} has no groups (the "
                             "key is for TDMS files); remove it")


def _channels(where: str, profile: RecordingProfile, e: str, i: str) -> tuple[str, str]:
    """The names of ``e``'s and ``i``'s channels: the profile's, else the format's defaults
    ``e`` and ``i``; never one channel for both."""
    names = (profile.e_channel if profile.e_channel is not None else e,
             profile.i_channel if profile.i_channel is not None else i)
    if names[0] == names[1]:
        raise RecordingError(f"{where}: e_channel and i_channel both name {names[0]!r}; e and "
                             "i are two channels")
    return names


def _scales(where: str, profile: RecordingProfile, stored: str, kind: str, bits: int, *,
            current_in_volts: str | None = None) -> tuple[float, dict[str, float]]:
    """``(offset, {"e": V per unit, "i": A per unit})``: a stored sample ``x`` of a channel
    is ``(x - offset) * unit``.

    Args:
        stored: the samples as messages name them (``"16-bit integers"``).
        kind: ``"i"`` signed or ``"u"`` unsigned integers (counts: :attr:`RecordingProfile.
            full_scale_v` needed), ``"f"`` floats (volts or amperes as recorded).
        bits: bits per sample (integers).
        current_in_volts: why the current channel holds a voltage even as floats (a WAV), or
            None; integers always do. Either way ``i_scale`` is then required.

    Raises:
        RecordingError: integers without ``full_scale_v``, floats with it, or no ``i_scale``
            where the current is a voltage.
    """
    offset, volts = 0.0, 1.0
    if kind in "iu":
        if profile.full_scale_v is None:
            raise RecordingError(f"{where}: stores {stored}; give full_scale_v (the volts at "
                                 "full scale of the interface) in the profile or "
                                 "--full-scale-v: never assumed")
        volts = profile.full_scale_v / 2 ** (bits - 1)
        offset = 2.0 ** (bits - 1) if kind == "u" else 0.0
        current_in_volts = current_in_volts or "integer samples are the interface's volts"
    elif profile.full_scale_v is not None:
        raise RecordingError(f"{where}: stores {stored}, read as they are; full_scale_v "
                             "scales integer samples only: leave it out (e_scale and i_scale "
                             "scale floats)")
    if current_in_volts and profile.i_scale is None:
        raise RecordingError(f"{where}: the current is recorded as the I-V converter's voltage "
                             f"({current_in_volts}); give i_scale (A per V, the inverse of its "
                             "transimpedance) in the profile or --i-scale: never assumed")
    e_scale = 1.0 if profile.e_scale is None else profile.e_scale
    i_scale = 1.0 if profile.i_scale is None else profile.i_scale
    return offset, {"e": volts * e_scale, "i": volts * i_scale}


def _scaled(x: np.ndarray, offset: float, unit: float) -> np.ndarray:
    """Stored samples ``x`` ``(n_samples,)`` as float64 ``(1, n_samples)`` in V or A (a
    signalling NaN quietly NaN: :func:`~wtml.runtime.recordings.read_record` names it)."""
    with np.errstate(invalid="ignore"):
        x = np.asarray(x, np.float64)
    if offset:
        x = x - offset
    return (x * unit)[None, :]


def _in_range(where: str, rate: float, what: str) -> float:
    """``rate`` (Hz) if it is within :data:`RATE_RANGE`, else a refusal naming ``what``."""
    if not RATE_RANGE[0] <= rate <= RATE_RANGE[1]:
        raise RecordingError(f"{where}: {what} gives a sampling rate of {rate:g} Hz; allowed: "
                             f"[{RATE_RANGE[0]:g}, {RATE_RANGE[1]:g}]")
    return rate


def _shortest(x: float, rel: float) -> float:
    """The number with the fewest significant digits within ``rel`` (relative) of ``x``: a
    rate as the instrument was set (48000), not as a reciprocal's rounding left it."""
    for digits in range(1, 18):
        r = float(f"{x:.{digits}g}")
        if abs(r - x) <= rel * abs(x):
            return r
    return x


def _rate(where: str, own: float | None, profile: RecordingProfile, source: str) -> float:
    """The sampling rate (Hz): the file's own (``source`` names where it comes from), which a
    profile's ``sample_rate_hz`` must agree with, else the profile's.

    Raises:
        RecordingError: no rate anywhere, one out of :data:`RATE_RANGE`, or two that differ
            by more than :data:`RATE_AGREEMENT`.
    """
    given = profile.sample_rate_hz
    if own is None:
        if given is None:
            raise RecordingError(f"{where}: states no sampling rate ({source}); give "
                                 "sample_rate_hz (Hz) in the profile or --sample-rate")
        return given
    _in_range(where, own, source)
    if given is not None and abs(own - given) > RATE_AGREEMENT * max(own, given):
        raise RecordingError(f"{where}: recorded at {own:.10g} Hz ({source}), but the "
                             f"profile's sample_rate_hz is {given:.10g} Hz: remove it or "
                             "correct it")
    return own


# ---------------------------------------------------------------------------------- TDMS


def _increment(where: str, channel: Any) -> float | None:
    """The rate (Hz) a TDMS channel's ``wf_increment`` (s) states, or None without one."""
    inc = channel.properties.get("wf_increment")
    if inc is None:
        return None
    try:
        inc = float(inc)
    except (TypeError, ValueError):
        inc = float("nan")
    if not 0 < inc < float("inf"):
        raise RecordingError(f"{where}: channel {channel.name!r} has wf_increment {inc!r}; "
                             "it must be the sample spacing, a number of seconds > 0")
    return _shortest(1 / inc, 1e-12)


@contextmanager
def _quiet(log_manager: Any) -> Iterator[None]:
    """npTDMS's console warnings held back (a damaged file is refused in one line instead)."""
    level = log_manager.log_level
    log_manager.set_level(logging.CRITICAL)
    try:
        yield
    finally:
        log_manager.set_level(level)


def read_tdms(path: Path, profile: RecordingProfile) -> Recording:
    """A LabVIEW TDMS recording (NI acquisition, npTDMS): ``e`` and ``i`` are two channels
    (``e_channel``, ``i_channel``; default ``"e"``, ``"i"``) of one group (``group``; default
    the file's only one), of equal length and one numeric type, at the rate their
    ``wf_increment`` states (else the profile's ``sample_rate_hz``). Channels with NI scaling
    properties are read scaled (floats); raw integer channels need ``full_scale_v``. Only the
    metadata is read until :attr:`Recording.load`.

    Raises:
        RecordingError: npTDMS missing, a damaged or truncated file (its last segment
            incomplete), a missing group or channel (listing those there are), unequal
            lengths, non-numeric or differently stored channels, an unstated or
            contradicted rate, a scale missing or out of place.
    """
    try:
        from nptdms import TdmsFile
        from nptdms.log import log_manager
    except ImportError:
        raise RecordingError(f"{path}: reading .tdms needs npTDMS: pip install "
                             "'wtml[tdms]'") from None
    where = str(path)
    try:
        with _quiet(log_manager):
            tdms = TdmsFile.read_metadata(path)
    except Exception as err:  # npTDMS raises ValueError, KeyError, struct.error, ... alike
        raise RecordingError(f"{path}: not a readable TDMS file ({type(err).__name__}: "
                             f"{' '.join(str(err).split())[:100]})") from None
    if tdms.file_status.incomplete_final_segment:
        raise RecordingError(f"{path}: truncated: its last segment holds less than its "
                             "metadata states (a recording stopped while it was written)")
    groups = {g.name: g for g in tdms.groups()}
    if profile.group is not None:
        if profile.group not in groups:
            raise RecordingError(f"{path}: no group {profile.group!r}; its groups: "
                                 f"{sorted(groups)}")
        group = groups[profile.group]
    elif len(groups) != 1:
        raise RecordingError(f"{path}: holds {len(groups)} groups {sorted(groups)}; give group "
                             "in the profile (or --group)")
    else:
        group = next(iter(groups.values()))
    found = {c.name: c for c in group.channels()}
    names = _channels(where, profile, "e", "i")
    for key, name in zip(("e", "i"), names, strict=True):
        if name not in found:
            raise RecordingError(f"{path}: group {group.name!r} has no channel {name!r} for "
                                 f"{key}; its channels: {sorted(found)} (give e_channel and "
                                 "i_channel)")
    e, i = found[names[0]], found[names[1]]
    if len(e) != len(i):
        raise RecordingError(f"{path}: channels {e.name!r} (e) and {i.name!r} (i) hold "
                             f"{len(e)} and {len(i)} samples; e and i must have equal length")
    dtype = e.dtype
    if dtype.kind not in "iuf" or i.dtype != dtype:
        raise RecordingError(f"{path}: channels {e.name!r} (e) and {i.name!r} (i) hold "
                             f"{e.dtype} and {i.dtype} data; both must be integers or floats, "
                             "stored alike")
    kind = "floats" if dtype.kind == "f" else "integers"
    offset, unit = _scales(where, profile, f"{8 * dtype.itemsize}-bit {kind}", dtype.kind,
                           8 * dtype.itemsize)
    e_rate, i_rate = _increment(where, e), _increment(where, i)
    if e_rate and i_rate and abs(e_rate - i_rate) > RATE_AGREEMENT * max(e_rate, i_rate):
        raise RecordingError(f"{path}: channels {e.name!r} (e) and {i.name!r} (i) have "
                             f"wf_increment for {e_rate:.10g} and {i_rate:.10g} Hz; e and i "
                             "must be sampled alike")
    rate = _rate(where, e_rate or i_rate, profile,
                 f"channel wf_increment in group {group.name!r}")

    def load(key: str) -> np.ndarray:
        name = names[key == "i"]
        try:
            with _quiet(log_manager), TdmsFile.open(path) as opened:
                x = opened[group.name][name][:]
        except Exception as err:  # as above: a file damaged past its metadata
            raise RecordingError(f"{path}: channel {name!r} cannot be read "
                                 f"({type(err).__name__}: "
                                 f"{' '.join(str(err).split())[:100]})") from None
        return _scaled(x, offset, unit[key])

    return Recording(where, (1, len(e)), dtype.itemsize, rate, load)


# ----------------------------------------------------------------------------------- WAV


@dataclass(frozen=True)
class _WavHeader:
    """A WAV file's format and where its samples lie (bytes from the file's start)."""

    tag: int
    """1: PCM integers, 3: IEEE floats (an extensible file's subformat)."""
    n_channels: int
    rate: int
    bits: int
    block_align: int
    data_offset: int
    data_bytes: int


def _wav_format(path: Path, body: bytes) -> tuple[int, int, int, int, int]:
    """``(tag, n_channels, rate, bits, block_align)`` of a ``fmt `` chunk's ``body``."""
    if len(body) < 16:
        raise RecordingError(f"{path}: garbled WAV header: its 'fmt ' chunk has {len(body)} "
                             "bytes, not the 16 or more of a format")
    tag, n_channels, rate, _, block_align, bits = struct.unpack("<HHIIHH", body[:16])
    if tag == 0xFFFE:  # WAVE_FORMAT_EXTENSIBLE: the format is the subformat GUID's
        if len(body) < 40 or body[26:40] != _WAV_GUID_TAIL:
            raise RecordingError(f"{path}: an extensible WAV whose subformat is not PCM or "
                                 "IEEE float (or a garbled header)")
        tag = int.from_bytes(body[24:26], "little")
    if (tag, bits) not in {(1, 8), (1, 16), (1, 24), (1, 32), (3, 32), (3, 64)}:
        raise RecordingError(f"{path}: a WAV of format {tag} with {bits}-bit samples; wtml "
                             "reads PCM integers of 8, 16, 24 or 32 bits and IEEE floats of "
                             "32 or 64 bits")
    if n_channels < 1 or rate < 1 or block_align != n_channels * bits // 8:
        raise RecordingError(f"{path}: garbled WAV header: {n_channels} channels of {bits} "
                             f"bits at {rate} Hz in frames of {block_align} bytes")
    return tag, n_channels, rate, bits, block_align


def _wav_header(path: Path) -> _WavHeader:
    """The format (``fmt `` chunk) and the samples' place (``data`` chunk) of a RIFF WAVE
    file, read without its samples.

    Raises:
        RecordingError: not RIFF WAVE, a chunk running past the end of the file (truncated),
            no format or no data, a format wtml does not read.
    """
    size = path.stat().st_size
    fmt = data = None
    with open(path, "rb") as fh:
        head = fh.read(12)
        if len(head) < 12 or head[:4] != b"RIFF" or head[8:] != b"WAVE":
            raise RecordingError(f"{path}: not a WAV file (no RIFF WAVE header)")
        pos = 12
        while pos + 8 <= size and (fmt is None or data is None):
            fh.seek(pos)
            cid, n = struct.unpack("<4sI", fh.read(8))
            if pos + 8 + n > size:
                raise RecordingError(f"{path}: truncated: its {cid.decode('latin-1')!r} chunk "
                                     f"states {n} bytes but {size - pos - 8} follow")
            if cid == b"fmt ":
                fmt = _wav_format(path, fh.read(min(n, 1024)))
            elif cid == b"data":
                data = (pos + 8, n)
            pos += 8 + n + n % 2
    if fmt is None or data is None:
        raise RecordingError(f"{path}: garbled or truncated WAV: no "
                             f"{'fmt ' if fmt is None else 'data'!r} chunk")
    if data[1] % fmt[4]:
        raise RecordingError(f"{path}: truncated: its data chunk has {data[1]} bytes, not a "
                             f"whole number of {fmt[4]}-byte frames")
    return _WavHeader(*fmt, *data)


def _wav_index(where: str, key: str, name: str, n_channels: int) -> int:
    """The channel index ``name`` (text: ``"0"``, ``"1"``, ...) gives ``key``."""
    if not (name.isdigit() and int(name) < n_channels):
        raise RecordingError(f"{where}: {key}_channel {name!r}: a WAV channel is an index from "
                             f"0 to {n_channels - 1}")
    return int(name)


def read_wav(path: Path, profile: RecordingProfile) -> Recording:
    """A WAV recording (a sound card's): two channels, ``e`` (default channel 0) and ``i``
    (default 1; ``e_channel``/``i_channel`` pick among more), PCM integers of 8 (unsigned),
    16, 24 or 32 bits or IEEE floats of 32 or 64 bits (format tags 1, 3 and extensible), at
    the header's rate. Both channels are voltages: ``i_scale`` is required, and ``full_scale_v``
    for integers. The samples are read (memory-mapped) only by :attr:`Recording.load`.

    Raises:
        RecordingError: a truncated or garbled header, another format, not two channels, a
            rate the profile contradicts, a scale missing or out of place.
    """
    where = str(path)
    _no_group(where, profile, "a WAV")
    head = _wav_header(path)
    n_ch = head.n_channels
    if n_ch != 2 and (profile.e_channel is None or profile.i_channel is None):
        pick = f": give e_channel and i_channel (0 to {n_ch - 1})" if n_ch > 2 else ""
        raise RecordingError(f"{path}: holds {n_ch} channel(s); a recording needs two, e and "
                             f"i{pick}")
    names = _channels(where, profile, "0", "1")
    column = {key: _wav_index(where, key, name, n_ch)
              for key, name in zip(("e", "i"), names, strict=True)}
    kind = "f" if head.tag == 3 else "u" if head.bits == 8 else "i"
    offset, unit = _scales(where, profile, f"{head.bits}-bit "
                           f"{'floats' if kind == 'f' else 'integers'}", kind, head.bits,
                           current_in_volts="a WAV holds voltages")
    rate = _rate(where, float(head.rate), profile, "WAV header")
    n = head.data_bytes // head.block_align
    packed = head.bits == 24
    dtype = np.dtype(np.uint8 if packed else f"<{kind}{head.bits // 8}")

    def load(key: str) -> np.ndarray:
        c = column[key]
        frames = np.memmap(path, dtype, "r", offset=head.data_offset,
                           shape=(n, head.block_align if packed else n_ch))
        if packed:  # 3 little-endian bytes: into the top of an int32, shifted back signed
            word = np.zeros((n, 4), np.uint8)
            word[:, 1:] = frames[:, 3 * c:3 * c + 3]
            x = word.view("<i4")[:, 0] >> 8
        else:
            x = frames[:, c]
        out = _scaled(x, offset, unit[key])
        del frames
        return out

    return Recording(where, (1, n), 4 if packed else dtype.itemsize, rate, load)


# ----------------------------------------------------------------------------------- CSV


def _uniform_rate(where: str, t: np.ndarray, lines: np.ndarray, column: str,
                  given: float | None) -> float:
    """The sampling rate (Hz) of times ``t`` (s) ``(n,)`` read from ``lines`` of a CSV: the
    profile's (``given``), where the times lie on its grid, else theirs, to the digits their
    rounding allows. Each time must lie within :data:`TIME_TOLERANCE` spacings of a uniform
    grid (a missing or repeated row is named by its line)."""
    bad = np.flatnonzero(~np.isfinite(t))
    if bad.size:
        raise RecordingError(f"{where}: line {lines[bad[0]]}: {column} is {t[bad[0]]}; times "
                             "must be finite")
    n = len(t)
    if n < 2:
        if given is None:
            raise RecordingError(f"{where}: one row: its {column} column states no rate; give "
                                 "sample_rate_hz (Hz) in the profile or --sample-rate")
        return given
    step = (t[-1] - t[0]) / (n - 1)
    if not step > 0:
        raise RecordingError(f"{where}: the {column} column must increase, from line "
                             f"{lines[0]} to line {lines[-1]}")
    spacings = np.diff(t) / step
    off = np.flatnonzero(np.abs(spacings - 1) > 2 * TIME_TOLERANCE)
    if off.size:
        raise RecordingError(f"{where}: line {lines[off[0] + 1]}: {column} is "
                             f"{spacings[off[0]]:.4g} sample spacings after the line before, "
                             "not 1: the times must be uniform (a row missing or repeated?)")
    k = np.arange(n)
    if given is not None:
        residual = t - k / given
        drift = (residual.max() - residual.min()) / 2 * given
        if drift > TIME_TOLERANCE:
            raise RecordingError(f"{where}: its {column} column gives {1 / step:.10g} Hz, but "
                                 f"the profile's sample_rate_hz is {given:.10g} Hz (the times "
                                 f"leave its grid by {drift:.3g} sample spacings): remove it "
                                 "or correct it")
        return given
    residual = np.abs(t - t[0] - k * step)
    worst = int(np.argmax(residual))
    if residual[worst] > TIME_TOLERANCE * step:
        raise RecordingError(f"{where}: line {lines[worst]}: the times drift from a uniform "
                             f"grid by {residual[worst] / step:.3g} sample spacings (at most "
                             f"{TIME_TOLERANCE:g} allowed)")
    rate = _in_range(where, 1 / step, f"its {column} column")
    return _shortest(rate, max(2 * residual[worst] / (t[-1] - t[0]), 1e-12))


def read_csv_record(path: Path, profile: RecordingProfile) -> Recording:
    """A CSV of samples (an oscilloscope's export, up to :data:`wtml.files.CSV_MAX_BYTES`): a header
    row naming the columns, then one row per sample: ``time_s`` (or ``time``, seconds; uniform)
    or ``sample`` (0, 1, 2, ...: the profile's ``sample_rate_hz`` is then required), and the
    ``e`` and ``i`` columns (``e_channel``/``i_channel``; default ``"e"``, ``"i"``), decimal
    numbers in V and A as recorded (``e_scale``/``i_scale``). Other columns are ignored. The
    file is small: it is parsed here, and each channel is scaled by :attr:`Recording.load`.

    Raises:
        RecordingError: too large, not UTF-8 CSV, no header or no rows, a missing or
            repeated column, a row of another width, a cell that is not a number (naming its
            line and column), times that are not uniform or a rate stated nowhere or twice.
    """
    path = regular_file(path, what="CSV recording", max_bytes=CSV_MAX_BYTES)
    where = str(path)
    _no_group(where, profile, "a CSV")
    names = _channels(where, profile, "e", "i")
    offset, unit = _scales(where, profile, "decimal numbers", "f", 64)
    values = (array("d"), array("d"), array("d"))
    lines = array("q")
    try:
        with open(path, newline="", encoding="utf-8-sig") as fh:
            reader = csv.reader(fh)
            header = [h.strip() for h in next(reader, [])]
            twice = sorted({h for h in header if header.count(h) > 1})
            if twice:
                raise RecordingError(f"{path}: column {twice[0]!r} appears twice in the header")
            index = [h for h in ("time_s", "time", "sample") if h in header]
            if len(index) != 1:
                raise RecordingError(f"{path}: a CSV recording starts with a header naming one "
                                     "index column, time_s (or time, in s) or sample, and e "
                                     f"and i; its header: {header[:20]}")
            for key, name in zip(("e", "i"), names, strict=True):
                if name not in header:
                    raise RecordingError(f"{path}: no column {name!r} for {key}; its columns: "
                                         f"{header[:20]} (give e_channel and i_channel)")
            cols = [header.index(h) for h in (index[0], *names)]
            for row in reader:
                if not any(cell.strip() for cell in row):
                    continue
                if len(row) != len(header):
                    raise RecordingError(f"{path}: line {reader.line_num} has {len(row)} "
                                         f"cells; the header has {len(header)}")
                for column, c in zip(values, cols, strict=True):
                    try:
                        column.append(float(row[c]))
                    except ValueError:
                        raise RecordingError(f"{path}: line {reader.line_num}, column "
                                             f"{header[c]!r}: {row[c].strip()[:40]!r} is not "
                                             "a number") from None
                lines.append(reader.line_num)
    except UnicodeDecodeError:
        raise RecordingError(f"{path}: not UTF-8 text; a CSV recording is text") from None
    except csv.Error as err:
        raise RecordingError(f"{path}: not a readable CSV ({err})") from None
    if not lines:
        raise RecordingError(f"{path}: a header but no rows of samples")
    t, e, i = (np.frombuffer(v, np.float64) for v in values)
    at = np.frombuffer(lines, np.int64)
    if index[0] != "sample":
        rate = _uniform_rate(where, t, at, index[0], profile.sample_rate_hz)
    elif profile.sample_rate_hz is None:
        raise RecordingError(f"{path}: a sample column states no rate; give sample_rate_hz "
                             "(Hz) in the profile or --sample-rate")
    else:
        bad = np.flatnonzero(t != np.arange(len(t)))
        if bad.size:
            raise RecordingError(f"{path}: line {at[bad[0]]}: sample {t[bad[0]]:g}; the "
                                 "sample column counts 0, 1, 2, ... without a gap")
        rate = profile.sample_rate_hz
    channel = {"e": e, "i": i}

    def load(key: str) -> np.ndarray:
        return _scaled(channel[key], offset, unit[key])

    return Recording(where, (1, len(t)), 8, rate, load)


READERS: dict[str, Callable[[Path, RecordingProfile], Recording]] = {
    ".tdms": read_tdms, ".wav": read_wav, ".csv": read_csv_record}
"""Each instrument format's reader by suffix."""
