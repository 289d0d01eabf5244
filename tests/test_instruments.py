"""Recordings as instruments write them (wtml.runtime.instruments): LabVIEW TDMS, WAV and CSV
read into the same e (V) and i (A) as the .npz of the same signal, each scale stated, and one
line naming the file and the key for anything missing or inconsistent."""

import struct
import wave
from types import SimpleNamespace

import nptdms
import numpy as np
import pytest

from wtml.cli import main
from wtml.files import FileError
from wtml.runtime.instruments import (
    RecordingError,
    RecordingProfile,
    load_profile,
    read_csv_record,
    read_tdms,
    read_wav,
)
from wtml.runtime.recordings import read_record
from wtml.schema import SchemaError

RATE = 48000.0
N = 4800
R = 1e4
"""V/A: the I-V converter's transimpedance (the profile's i_scale is 1/R)."""
GUID_TAIL = bytes.fromhex("000000001000800000aa00389b71")



@pytest.fixture(scope="module")
def signal() -> tuple[np.ndarray, np.ndarray]:
    """A probe record like the simulator's: e (V) and i (A), (N,) each at RATE."""
    rng = np.random.default_rng(0)
    t = np.arange(N) / RATE
    e = np.sin(2 * np.pi * 417 * t) + 1e-3 * rng.standard_normal(N)
    i = 1e-4 * np.cos(2 * np.pi * 417 * t) + 1e-7 * rng.standard_normal(N)
    return e, i


def npz_record(tmp_path, e, i) -> np.ndarray:
    """What ``read_record`` makes of an .npz holding ``e`` and ``i``."""
    path = tmp_path / "reference.npz"
    np.savez(path, e=e, i=i, sample_rate_hz=RATE)
    return read_record(path, RATE, N)


def write_tdms(path, channels: dict, group="rec", properties=None):
    """``channels`` ``{name: data}`` in one group, with ``properties`` (default: the
    waveform's ``wf_increment``) on each."""
    props = {"wf_increment": 1 / RATE} if properties is None else properties
    with nptdms.TdmsWriter(path) as w:
        w.write_segment([nptdms.ChannelObject(group, name, np.asarray(data), properties=props)
                         for name, data in channels.items()])
    return path


def _chunk(cid: bytes, payload: bytes) -> bytes:
    return cid + struct.pack("<I", len(payload)) + payload + b"\0" * (len(payload) % 2)


def write_wav(path, frames: np.ndarray, *, tag: int, bits: int, rate: int = 48000,
              extensible: bool = False):
    """A RIFF WAVE of ``frames`` ``(n, n_channels)`` (counts or floats), format ``tag`` (1:
    PCM, 3: float) of ``bits``; an odd-sized LIST chunk before the data."""
    n, ch = frames.shape
    if bits == 24:
        data = frames.astype("<i4").view(np.uint8).reshape(n, ch, 4)[:, :, :3].tobytes()
    else:
        kind = "f" if tag == 3 else "u" if bits == 8 else "i"
        data = frames.astype(f"<{kind}{bits // 8}").tobytes()
    align = ch * bits // 8
    fmt = struct.pack("<HHIIHH", 0xFFFE if extensible else tag, ch, rate, rate * align, align,
                      bits)
    if extensible:
        fmt += struct.pack("<HHIH", 22, bits, 3, tag) + GUID_TAIL
    body = b"WAVE" + _chunk(b"fmt ", fmt) + _chunk(b"LIST", b"INFOx") + _chunk(b"data", data)
    path.write_bytes(b"RIFF" + struct.pack("<I", len(body)) + body)
    return path


def write_csv(path, index: str, first, e, i, e_name="e", i_name="i"):
    """A CSV with ``index`` column values ``first`` and ``e``, ``i`` (written with repr)."""
    rows = [f"{index},{e_name},{i_name}"]
    rows += [f"{a!r},{b!r},{c!r}" for a, b, c in zip(first.tolist(), e.tolist(), i.tolist(),
                                                     strict=True)]
    path.write_text("\n".join(rows) + "\n")
    return path


def test_tdms_gives_the_npz_records_values(signal, tmp_path):
    """Float64 channels as they are; the current as the converter's volts times i_scale."""
    e, i = signal
    expected = npz_record(tmp_path, e, i)
    path = write_tdms(tmp_path / "a.tdms", {"e": e, "i": i})
    np.testing.assert_array_equal(read_record(path, RATE, N), expected)
    volts = write_tdms(tmp_path / "v.tdms", {"e": e, "i": i * R})
    got = read_record(volts, RATE, N, profile=RecordingProfile(i_scale=1 / R))
    np.testing.assert_array_equal(got, npz_record(tmp_path, e, i * R * (1 / R)))


def test_tdms_integers_need_the_full_scale_and_ni_scaling_makes_floats(signal, tmp_path):
    e, i = signal
    counts = {"e": np.round(e / 2 * 32767).astype(np.int16),
              "i": np.round(i * R / 2 * 32767).astype(np.int16)}
    raw = write_tdms(tmp_path / "raw.tdms", counts)
    with pytest.raises(RecordingError, match="16-bit integers; give full_scale_v"):
        read_record(raw, RATE, N)
    with pytest.raises(RecordingError, match="give i_scale"):
        read_record(raw, RATE, N, profile=RecordingProfile(full_scale_v=2.0))
    got = read_record(raw, RATE, N, profile=RecordingProfile(full_scale_v=2.0, i_scale=1 / R))
    np.testing.assert_allclose(got[0, 0], e, rtol=0, atol=2 / 32768)
    np.testing.assert_allclose(got[1, 0], i, rtol=0, atol=2 / 32768 / R)
    linear = {"wf_increment": 1 / RATE, "NI_Number_Of_Scales": 1,
              "NI_Scale[0]_Scale_Type": "Linear", "NI_Scale[0]_Linear_Slope": 2 / 32768,
              "NI_Scale[0]_Linear_Y_Intercept": 0.0}
    scaled = write_tdms(tmp_path / "scaled.tdms", counts, properties=linear)
    got = read_record(scaled, RATE, N, profile=RecordingProfile(i_scale=1 / R))
    np.testing.assert_allclose(got[0, 0], e, rtol=0, atol=2 / 32768)
    with pytest.raises(RecordingError, match="full_scale_v scales integer samples only"):
        read_tdms(scaled, RecordingProfile(full_scale_v=2.0))


def test_tdms_names_what_is_missing_or_inconsistent(signal, tmp_path):
    e, i = signal
    named = write_tdms(tmp_path / "named.tdms", {"voltage": e, "current": i})
    with pytest.raises(RecordingError, match=r"no channel 'e' for e; its channels: "
                                             r"\['current', 'voltage'\]"):
        read_tdms(named, RecordingProfile())
    rec = read_tdms(named, RecordingProfile(e_channel="voltage", i_channel="current"))
    np.testing.assert_array_equal(rec.load("i"), i[None])
    with pytest.raises(RecordingError, match="both name 'e'"):
        read_tdms(named, RecordingProfile(i_channel="e"))
    uneven = write_tdms(tmp_path / "uneven.tdms", {"e": e, "i": i[:-1]})
    with pytest.raises(RecordingError, match="hold 4800 and 4799 samples"):
        read_tdms(uneven, RecordingProfile())
    two = tmp_path / "groups.tdms"
    with nptdms.TdmsWriter(two) as w:
        w.write_segment([nptdms.ChannelObject(g, k, e) for g in ("a", "b") for k in "ei"])
    with pytest.raises(RecordingError, match=r"2 groups \['a', 'b'\]; give group"):
        read_tdms(two, RecordingProfile())
    with pytest.raises(RecordingError, match=r"no group 'c'; its groups: \['a', 'b'\]"):
        read_tdms(two, RecordingProfile(group="c"))
    with pytest.raises(RecordingError, match="states no sampling rate.*sample_rate_hz"):
        read_tdms(two, RecordingProfile(group="b"))
    assert read_tdms(two, RecordingProfile(group="b", sample_rate_hz=RATE)).rate == RATE
    path = write_tdms(tmp_path / "a.tdms", {"e": e, "i": i})
    with pytest.raises(RecordingError, match="48000 Hz .* sample_rate_hz is 44100 Hz"):
        read_tdms(path, RecordingProfile(sample_rate_hz=44100.0))
    bad = tmp_path / "bad.tdms"
    bad.write_bytes(b"not a TDMS file at all, just text" * 4)
    with pytest.raises(RecordingError, match="not a readable TDMS file"):
        read_tdms(bad, RecordingProfile())
    bad.write_bytes(path.read_bytes()[:-8])
    with pytest.raises(RecordingError, match="truncated: its last segment holds less"):
        read_tdms(bad, RecordingProfile())


def test_wav_float_and_pcm_give_the_npz_records_values(signal, tmp_path):
    """Float32 exactly (the .npz of the same float32 values); int16 (stdlib wave's writer)
    within one step of the converter."""
    e, i = signal
    e32, v32 = e.astype(np.float32), (i * R).astype(np.float32)
    path = write_wav(tmp_path / "f.wav", np.stack([e32, v32], 1), tag=3, bits=32)
    got = read_record(path, RATE, N, profile=RecordingProfile(i_scale=1 / R))
    np.testing.assert_array_equal(got, npz_record(tmp_path, e32.astype(float),
                                                  v32.astype(float) * (1 / R)))
    counts = np.round(np.stack([e, i * R], 1) / 2 * 32767).astype("<i2")
    pcm = tmp_path / "pcm.wav"
    with wave.open(str(pcm), "wb") as w:
        w.setnchannels(2)
        w.setsampwidth(2)
        w.setframerate(48000)
        w.writeframes(counts.tobytes())
    got = read_record(pcm, RATE, N, profile=RecordingProfile(full_scale_v=2.0, i_scale=1 / R))
    np.testing.assert_allclose(got[0, 0], e, rtol=0, atol=2 / 32768)
    np.testing.assert_allclose(got[1, 0], i, rtol=0, atol=2 / 32768 / R)


@pytest.mark.parametrize(("tag", "bits", "extensible"),
                         [(1, 8, False), (1, 16, False), (1, 24, False), (1, 24, True),
                          (1, 32, False), (3, 32, True), (3, 64, False)])
def test_every_wav_sample_format_is_scaled_as_stated(tag, bits, extensible, tmp_path):
    """Counts c of b bits are c / 2**(b-1) * full_scale_v volts (8-bit: offset by 128), the
    extremes and sign of packed 24-bit samples included; floats are volts as written."""
    rng = np.random.default_rng(bits)
    if tag == 3:
        frames = rng.uniform(-1.5, 1.5, (50, 3))
        expected = frames.astype(f"<f{bits // 8}").astype(float)
        profile = RecordingProfile(e_channel="2", i_channel="0", e_scale=2.0, i_scale=1 / R)
    else:
        half = 2 ** (bits - 1)
        low, high = (0, 2 * half - 1) if bits == 8 else (-half, half - 1)
        frames = rng.integers(low, high, (50, 3), endpoint=True)
        frames[:2, 2] = low, high
        expected = (frames - (half if bits == 8 else 0)) / half * 5.0
        profile = RecordingProfile(e_channel="2", i_channel="0", e_scale=2.0, i_scale=1 / R,
                                   full_scale_v=5.0)
    path = write_wav(tmp_path / "x.wav", frames, tag=tag, bits=bits, extensible=extensible)
    rec = read_wav(path, profile)
    assert (rec.shape, rec.rate) == ((1, 50), RATE)
    np.testing.assert_allclose(rec.load("e")[0], expected[:, 2] * 2.0, rtol=1e-15)
    np.testing.assert_allclose(rec.load("i")[0], expected[:, 0] / R, rtol=1e-15)


def test_wav_refusals_name_the_key(signal, tmp_path):
    e, i = signal
    frames = np.stack([e, i * R], 1)
    f32 = write_wav(tmp_path / "f.wav", frames, tag=3, bits=32)
    pcm = write_wav(tmp_path / "p.wav", np.round(frames * 1000), tag=1, bits=16)
    with pytest.raises(RecordingError, match="stores 16-bit integers; give full_scale_v"):
        read_wav(pcm, RecordingProfile(i_scale=1 / R))
    with pytest.raises(RecordingError, match="32-bit floats.*full_scale_v scales integer"):
        read_wav(f32, RecordingProfile(i_scale=1 / R, full_scale_v=1.0))
    with pytest.raises(RecordingError, match="a WAV holds voltages.*give i_scale"):
        read_wav(f32, RecordingProfile())
    with pytest.raises(RecordingError, match="48000 Hz .* sample_rate_hz is 44100 Hz"):
        read_wav(f32, RecordingProfile(i_scale=1 / R, sample_rate_hz=44100.0))
    mono = write_wav(tmp_path / "m.wav", frames[:, :1], tag=3, bits=32)
    with pytest.raises(RecordingError, match=r"holds 1 channel\(s\); a recording needs two"):
        read_wav(mono, RecordingProfile(i_scale=1 / R))
    with pytest.raises(RecordingError, match="i_channel '2': a WAV channel is an index"):
        read_wav(f32, RecordingProfile(i_scale=1 / R, i_channel="2"))
    with pytest.raises(RecordingError, match="group 'WT': a WAV has no groups"):
        read_wav(f32, RecordingProfile(i_scale=1 / R, group="WT"))
    whole = f32.read_bytes()
    for cut, needle in ((len(whole) - 7, "truncated: its 'data' chunk states"),
                        (30, "truncated: its 'fmt ' chunk"), (6, "not a WAV file"),
                        (60, "truncated: its 'data' chunk")):
        (tmp_path / "cut.wav").write_bytes(whole[:cut])
        with pytest.raises(RecordingError, match=needle):
            read_wav(tmp_path / "cut.wav", RecordingProfile(i_scale=1 / R))
    odd = bytearray(whole)
    odd[20:22] = struct.pack("<H", 2)  # format tag 2: ADPCM
    (tmp_path / "adpcm.wav").write_bytes(bytes(odd))
    with pytest.raises(RecordingError, match="format 2 with 32-bit samples"):
        read_wav(tmp_path / "adpcm.wav", RecordingProfile(i_scale=1 / R))


def test_csv_gives_the_npz_records_values(signal, tmp_path):
    e, i = signal
    expected = npz_record(tmp_path, e, i)
    timed = write_csv(tmp_path / "t.csv", "time_s", np.arange(N) / RATE, e, i)
    rec = read_csv_record(timed, RecordingProfile())
    assert rec.rate == RATE
    np.testing.assert_array_equal(read_record(timed, RATE, N), expected)
    counted = write_csv(tmp_path / "s.csv", "sample", np.arange(N), e, i)
    got = read_record(counted, RATE, N, profile=RecordingProfile(sample_rate_hz=RATE))
    np.testing.assert_array_equal(got, expected)
    # an oscilloscope's times to 7 digits: the rate it was set to, and the profile's accepted
    scope = tmp_path / "scope.csv"
    scope.write_text("time,ch1,ch2\n" + "".join(
        f"{k / RATE:.6e},{a!r},{b!r}\n"
        for k, a, b in zip(range(N), e.tolist(), i.tolist(), strict=True)))
    profile = RecordingProfile(e_channel="ch1", i_channel="ch2")
    assert read_csv_record(scope, profile).rate == RATE
    np.testing.assert_array_equal(read_record(scope, RATE, N, profile=profile), expected)
    assert read_csv_record(scope, RecordingProfile(e_channel="ch1", i_channel="ch2",
                                                   sample_rate_hz=RATE)).rate == RATE


def test_csv_refusals_name_the_line_and_column(signal, tmp_path):
    e, i = signal
    t = np.arange(N) / RATE
    keep = np.arange(N) != 100
    gap = write_csv(tmp_path / "gap.csv", "time_s", t[keep], e[keep], i[keep])
    with pytest.raises(RecordingError, match="line 102: time_s is 2 sample spacings"):
        read_csv_record(gap, RecordingProfile())
    timed = write_csv(tmp_path / "t.csv", "time_s", t, e, i)
    with pytest.raises(RecordingError, match="gives 48000 Hz, but the profile's "
                                             "sample_rate_hz is 48010 Hz"):
        read_csv_record(timed, RecordingProfile(sample_rate_hz=48010.0))
    with pytest.raises(RecordingError, match="full_scale_v scales integer samples only"):
        read_csv_record(timed, RecordingProfile(full_scale_v=1.0))
    with pytest.raises(RecordingError, match="group 'WT': a CSV has no groups"):
        read_csv_record(timed, RecordingProfile(group="WT"))
    counted = write_csv(tmp_path / "s.csv", "sample", np.arange(N), e, i)
    with pytest.raises(RecordingError, match="a sample column states no rate; give "
                                             "sample_rate_hz"):
        read_csv_record(counted, RecordingProfile())
    skipped = write_csv(tmp_path / "k.csv", "sample", np.arange(N)[keep], e[keep], i[keep])
    with pytest.raises(RecordingError, match="line 102: sample 101"):
        read_csv_record(skipped, RecordingProfile(sample_rate_hz=RATE))
    lines = timed.read_text().splitlines()
    for edit, needle in (
            (lambda x: x[:4] + [x[4].rsplit(",", 1)[0] + ",1.2.3"] + x[5:],
             "line 5, column 'i': '1.2.3' is not a number"),
            (lambda x: x[:4] + [x[4] + ",7"] + x[5:], "line 5 has 4 cells; the header has 3"),
            (lambda x: ["time_s,e,current"] + x[1:], r"no column 'i' for i; its columns: "
                                                     r"\['time_s', 'e', 'current'\]"),
            (lambda x: ["t,e,i"] + x[1:], "one index column, time_s"),
            (lambda x: ["time_s,e,e"] + x[1:], "column 'e' appears twice"),
            (lambda x: x[:1], "a header but no rows")):
        (tmp_path / "x.csv").write_text("\n".join(edit(lines)) + "\n")
        with pytest.raises(RecordingError, match=needle):
            read_csv_record(tmp_path / "x.csv", RecordingProfile())


def test_profiles_read_from_yaml_with_options_over_them(tmp_path):
    assert load_profile(None, e_scale=None) is None
    path = tmp_path / "profile.yaml"
    path.write_text("group: pxi\ne_channel: 0\ni_channel: ai1\ni_scale: 1e-4\n")
    assert load_profile(path, i_scale=2e-4, full_scale_v=None) == RecordingProfile(
        group="pxi", e_channel="0", i_channel="ai1", i_scale=2e-4)
    assert load_profile(None, sample_rate_hz=RATE) == RecordingProfile(sample_rate_hz=RATE)
    path.write_text("e_chanel: ai0\n")
    with pytest.raises(SchemaError, match=r"profile.yaml: e_chanel: unknown key; allowed keys"):
        load_profile(path)
    path.write_text("i_scale: 0\n")
    with pytest.raises(SchemaError, match=r"profile.yaml: i_scale: must be in \[1e-12, 1e\+12\]"):
        load_profile(path)
    with pytest.raises(SchemaError, match="options: full_scale_v: must be in"):
        load_profile(None, full_scale_v=-1.0)
    with pytest.raises(FileError, match="no such recording profile"):
        load_profile(tmp_path / "missing.yaml")


def test_wtml_predict_refuses_a_bad_recording_in_one_line(monkeypatch, tmp_path, capsys):
    """Through the command line: an onset export (its folder stood in for: the refusal comes
    before any graph runs) given a truncated WAV exits 2 with one line naming the file."""
    meta = SimpleNamespace(sample_rate_hz=RATE, n_samples=N, scene={"max_contacts": 2})
    monkeypatch.setattr("wtml.runtime.predict.task_of", lambda model: "onset")
    monkeypatch.setattr("wtml.runtime.onset.load_export",
                        lambda model: (SimpleNamespace(meta=meta), None))
    path = write_wav(tmp_path / "rec.wav", np.zeros((N, 2)), tag=3, bits=32)
    path.write_bytes(path.read_bytes()[:-100])
    assert main(["predict", "--model", str(tmp_path), "--input", str(path)]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "Traceback" not in err, err
    assert err.startswith("wtml predict: error: ") and f"{path}: truncated" in err, err
