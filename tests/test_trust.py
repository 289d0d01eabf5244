"""Trust: no code from files, answers only inside the trained domain, errors a user can act
on, runs that do not overwrite each other, and reference numbers made like the methods'.

The domain gate's false-alarm and detection tests use the shipped scenes at full size (the
gate is fitted on 18000 simulated training inputs, as a training run of the shipped fluid
config does), without training a decoder: the input score does not depend on the net."""

import json
import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import onnx
import pytest
import torch
from conftest import FLUID_SMALL, RADIAL_SMALL, ROOT
from scipy import optimize, stats

from wtml.baselines import ClassicalFluid
from wtml.baselines.fluid_bayes import BayesFluid
from wtml.baselines.radial import InversionRadial
from wtml.bench.accuracy import sampled_errors
from wtml.bench.bounds import radial_crlb
from wtml.cli import build_parser, main
from wtml.data import generate, load_shards
from wtml.decoders.checkpoint import CheckpointError, read_checkpoint
from wtml.decoders.domain import QUANTILE, DomainGate, Gated, ZeParts
from wtml.decoders.fluid import FluidDecoder, load_fluid_net
from wtml.decoders.radial import RadialDecoder
from wtml.physics import ze_from_zm, zm_from_ze
from wtml.physics.beam_presets import build as build_beam
from wtml.physics.loads import stokes_sphere
from wtml.physics.twoport import flat_parts
from wtml.pipeline import Stages, checkpoint_matches, summary
from wtml.runtime.predict import InputError, OnnxModel, predict_file
from wtml.scenes import load_scene
from wtml.schema import build
from wtml.signals import complex_noise
from wtml.training import cli_main

# ---------------------------------------------------------------- 1. no code from files


class _Payload:
    """Unpickling this runs ``os.mkdir(marker)``: what a crafted checkpoint would do."""

    def __init__(self, marker: Path) -> None:
        self.marker = str(marker)

    def __reduce__(self):
        return os.mkdir, (self.marker,)


def test_a_crafted_checkpoint_is_refused_without_running_anything(tmp_path, flow, capsys):
    data = flow[0] / "data"
    marker = tmp_path / "ran"
    evil = tmp_path / "evil.ckpt"
    torch.save({"wtml": {"scene": {"task": "fluid"}}, "state_dict": _Payload(marker)}, evil)
    for argv in (["export", "--checkpoint", str(evil), "--out", str(tmp_path / "x")],
                 ["evaluate", "--checkpoint", str(evil), "--data", str(data)]):
        assert main(argv) == 2
        err = capsys.readouterr().err
        assert "refused" in err and "weights_only=True" in err and len(err.splitlines()) == 1
    with pytest.raises(CheckpointError, match="refused"):
        load_fluid_net(str(evil))
    assert not checkpoint_matches(evil, "0" * 64, str(ROOT / "configs/fluid.yaml"))
    assert not marker.exists()
    # the same file written with plain types only loads, and is told apart as not wtml's
    torch.save({"state_dict": {}}, evil)
    with pytest.raises(CheckpointError, match="not a wtml checkpoint"):
        read_checkpoint(evil)


def test_nothing_is_loaded_with_pickle_anywhere():
    """No unsafe loading in the package, the tests, the entry points: every torch.load and
    load_from_checkpoint says weights_only=True, and numpy never allows pickles. (The
    patterns are assembled so that this file does not match itself.)"""
    unsafe = re.compile("weights_only" + r"\s*=\s*False|allow_pickle" + r"\s*=\s*True|"
                        r"pickle\.loads?\(|" + "pickle" + r"\.Unpickler")
    loads = re.compile(r"(torch\.load|load_from_checkpoint)\(")
    files = [*ROOT.glob("wtml/**/*.py"), *ROOT.glob("tests/*.py"), ROOT / "train.py"]
    assert len(files) > 40
    for path in files:
        text = path.read_text()
        assert not unsafe.search(text), path
        for m in loads.finditer(text):
            call = text[m.start():text.find("\n", text.find(")", m.start()))]
            assert "weights_only=True" in call, (path, call)


# ---------------------------------------------------------------- 2. the trained domain


def _parts(*arrays: np.ndarray) -> list[torch.Tensor]:
    """Complex arrays as the graphs' float32 inputs: real and imaginary part of each (Ze,
    radial's reference), or a calibrated T ``(n, n_freq, 2, 2)`` flattened (fluid)."""
    parts = []
    for z in arrays:
        z = np.asarray(z)
        parts += flat_parts(z) if z.ndim == 4 else (z.real, z.imag)
    return [torch.tensor(np.asarray(p), dtype=torch.float32) for p in parts]


def _measured(data: dict) -> tuple[np.ndarray, ...]:
    """What a task's graphs read of a simulated batch: Ze, and fluid's calibrated T or
    radial's reference."""
    return (data["ze"], *(data[key] for key in ("t", "ref") if key in data))


def _simulate(scene, n: int, seed: int, shards: int = 1) -> dict:
    """``n`` samples simulated as ``shards`` shards (a scene with a device spread draws its
    devices per shard, as a dataset's shards do)."""
    parts = [scene.simulate(n // shards, np.random.default_rng([seed, k]))
             for k in range(shards)]
    return {key: np.concatenate([p[key] for p in parts]) for key in parts[0]}


def _gate(decoder, scene, n_train: int, seed: int, shards: int = 1) -> DomainGate:
    train = _simulate(scene, n_train, seed, shards)
    return decoder.make_gate(scene).fit(*_parts(*_measured(train)))


def _score(gate: DomainGate, *measured: np.ndarray) -> np.ndarray:
    with torch.no_grad():
        return gate(*_parts(*measured)).numpy()


@pytest.fixture(scope="module")
def fluid_domain():
    scene = load_scene(ROOT / "configs/scenes/fluid.yaml")
    return scene, _gate(FluidDecoder(), scene, 18000, 1)


@pytest.fixture(scope="module")
def radial_domain():
    scene = load_scene(ROOT / "configs/scenes/radial.yaml")
    assert scene.spread.none  # the shipped scene: the preset's own device
    return scene, _gate(RadialDecoder(), scene, 60000, 1)


@pytest.fixture(scope="module")
def radial_spread_domain():
    scene = load_scene(ROOT / "configs/scenes/radial_spread.yaml")
    return scene, _gate(RadialDecoder(), scene, 60000, 1, shards=6)  # 12288 devices


def _out_of_domain_variants(ze: np.ndarray) -> dict[str, np.ndarray]:
    return {"Ze x 1e6": ze * 1e6, "Ze x 1e-3": ze * 1e-3,
            "Re Ze x 1.5": 1.5 * ze.real + 1j * ze.imag,
            "Re Ze negated": -ze.real + 1j * ze.imag, "Im Ze negated": ze.conj()}


def _check_held_out_and_variants(scene, gate: DomainGate, n: int, shards: int = 1) -> None:
    """At most 0.3 % of ``n`` held-out in-domain inputs flagged; every variant of 500 of
    them from :func:`_out_of_domain_variants` flagged (radial: the measurement and its
    reference alike, an instrument that reads wrong; fluid: the measurement, its device's
    calibrated T as it is)."""
    held = _measured(_simulate(scene, n, 2, shards))
    assert np.mean(_score(gate, *held) > 1) <= 0.003
    variants = [_out_of_domain_variants(x[:500]) if x.ndim == 2 else None for x in held]
    for name in variants[0]:
        assert np.all(_score(gate, *(x[:500] if v is None else v[name]
                                     for x, v in zip(held, variants, strict=True))) > 1), name


def test_fluid_domain_false_alarms_and_detections(fluid_domain):
    """Held-out in-domain inputs: flagged at about the stated rate (0.1 %; <= 0.3 % allowed
    for 3000 samples, a binomial tail of 1e-3). Every scaled or negated input, and every
    viscosity of the decade above the trained range (η 5-23 Pa·s, at glycerol's density) and
    of the decade below it (η 6.5e-5 to 2e-4 Pa·s, at water's density at 40 °C): flagged.
    The lower decade is an extrapolation along the data's manifold (Zm moves by 8 stds of
    the calibration offset, the way it moves inside the range), which the box catches.
    A device outside the trained spread (its coupling or its clamped capacitance 10 % off,
    the spread ±3 %; its damping 1.6× the preset's, the spread ±25 %) is flagged too, though
    the Zm it reports is right: the decoder was not trained on it."""
    scene, gate = fluid_domain
    _check_held_out_and_variants(scene, gate, 3000)
    rng = np.random.default_rng(3)
    t = scene.calibrated_t()
    for eta, rho in ((np.geomspace(5.0, 23.0, 300), 1260.0),
                     (np.geomspace(6.5e-5, 2e-4, 300), 992.0)):
        zm = stokes_sphere(eta[:, None], rho, scene.sphere.radius, scene.excitation.omega)
        ze = complex_noise(ze_from_zm(t, zm), scene.noise.ze_relative, rng)
        assert np.all(_score(gate, ze, np.broadcast_to(t, (300, *t.shape))) > 1), eta[0]
    assert scene.spread.phi == scene.spread.c0 == 0.03 and scene.spread.c == 0.25
    fluid = scene.simulate(300, rng)
    for name, factor in (("phi", 1.1), ("phi", 0.9), ("c0", 1.1), ("c", 1.6)):
        factors = {f: np.ones(300) for f in scene.spread.FIELDS} | {name: np.full(300, factor)}
        other = scene.device_t(factors)
        zm = zm_from_ze(fluid["t"], fluid["ze"])  # the same loads, seen by the other device
        assert np.all(_score(gate, ze_from_zm(other, zm), other) > 1), (name, factor)


def _far_contacts(scene, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """300 contacts 3300-4500 µm from the tip of the nominal device (trained: 0-3200 µm),
    Ze and the device's free reference."""
    d = 1e-6 * np.linspace(3300, 4500, 300)
    k = np.exp(rng.uniform(*np.log(scene.contact.stiffness), 300))
    ze = complex_noise(scene.ze_of(d, k), scene.noise.ze_relative, rng)
    return ze, np.broadcast_to(scene.free_ze(), ze.shape)


def _far_devices(scene, rng: np.random.Generator, length: float):
    """Contacts in the trained range on devices far off a spread of free-length tolerance
    ``length`` (the bimorph 4× that longer) or with the structural loss doubled: (name, ze,
    ref) for each."""
    k = np.exp(rng.uniform(*np.log(scene.contact.stiffness), 300))
    for factors in ({"bimorph.length": 1 + 4 * length}, {"loss_factor": 2.0}):
        far = build_beam(scene.device, factors=factors)
        d = 1e-6 * rng.uniform(0, 3200, 300)
        ze = complex_noise(scene.ze_of(d, k, far), scene.noise.ze_relative, rng)
        yield factors, ze, np.broadcast_to(scene.free_ze(far), ze.shape)


def test_radial_domain_false_alarms_and_detections(radial_domain):
    """The shipped scene (the preset's device). Held-out in-domain inputs: <= 0.3 % flagged
    (stated 0.1 %). Every scaled or negated input and every contact 100 µm or more past the
    trained 3200 µm: flagged. A device off the preset (its bimorph 2 % longer, or its
    structural loss doubled) is flagged too: this decoder knows the preset alone."""
    scene, gate = radial_domain
    _check_held_out_and_variants(scene, gate, 20000)
    rng = np.random.default_rng(3)
    assert np.all(_score(gate, *_far_contacts(scene, rng)) > 1)
    for factors, ze, ref in _far_devices(scene, rng, 0.005):
        assert np.all(_score(gate, ze, ref) > 1), factors


def test_radial_spread_domain_false_alarms_and_detections(radial_spread_domain):
    """The device-spread variant (configs/scenes/radial_spread.yaml). Held-out in-domain
    inputs over the device spread (new devices): <= 0.3 % flagged (stated 0.1 %). Every
    scaled or negated input, and every device far off the trained spread (its bimorph 4× the
    spread's free-length tolerance longer, or its structural loss doubled): flagged.

    Not claimed here: contacts 3300-4500 µm on the nominal device. Over the spread, the
    gate's ellipsoid of the inputs spans the devices, and a far contact on one device reads
    like a near-range contact on another (a per-record fit of the full beam physics tells
    them apart: χ² 4e5 at 3300 µm, not a quadratic gate). Measured with this fixture's gate:
    it flags none of 300 such contacts. What a user of this variant must know; the shipped
    scene's gate flags them all (above)."""
    scene, gate = radial_spread_domain
    # the held-out devices many (40 × 512): a new device is out of domain whole, so a few
    # hundred of them would count the stated rate in steps of their number
    _check_held_out_and_variants(scene, gate, 20000, shards=40)
    rng = np.random.default_rng(3)
    for factors, ze, ref in _far_devices(scene, rng, scene.spread.length):
        assert np.all(_score(gate, ze, ref) > 1), factors


class _Constant(torch.nn.Module):
    """A stand-in net: (distance, sigma) = (d, 1e-7) for every input."""

    def __init__(self, d: float) -> None:
        super().__init__()
        self.d = d

    def forward(self, ze_re, ze_im):
        d = torch.full((len(ze_re),), self.d)
        return d, torch.full_like(d, 1e-7)


def test_an_answer_outside_the_trained_range_is_out_of_domain_and_its_std_nan():
    """Inputs at the training mean (score 0) but an answer beyond the range's margin: not in
    domain, and the predicted std becomes NaN rather than a confident number."""
    x = torch.randn(256, 4)
    gate = DomainGate(ZeParts(), 4, {0: (0.0, 3.2e-3)}).fit(x[:, :2], x[:, 2:])
    for d, inside in ((1e-3, True), (4e-3, False), (-1e-3, False)):
        dist, sigma, in_domain, score = Gated(_Constant(d), gate, uncertain=(1,))(
            torch.zeros(3, 2), torch.zeros(3, 2))
        assert bool(in_domain.all()) is inside and bool(in_domain.any()) is inside
        assert torch.all(torch.isnan(sigma)) is not inside and torch.all(score < 1)
        assert torch.all(dist == d)  # never hidden


def test_exported_graphs_carry_the_domain_and_agree_with_torch(flow, radial_flow):
    """Both graphs of each export return in_domain and domain_score beside the outputs;
    the decoder's ONNX agrees with its gated torch module on in-domain and out-of-domain
    inputs, and a radial out-of-domain row has a NaN std in the ONNX output itself."""
    from wtml.decoders.checkpoint import load_decoder

    for folder, ckpt in ((flow[0] / "export", flow[1]),
                         (radial_flow / "export/radial",
                          radial_flow / "runs/radial/checkpoints/last.ckpt")):
        module = load_decoder(ckpt)
        data = load_shards(folder.parent.parent / "data" if "radial" in str(folder)
                           else flow[0] / "data", [3])
        # scaled by decades: outside any scene's domain (a negated component can be a
        # plausible measurement of a one-frequency scene, whose Im Ze changes sign)
        ze = np.concatenate([data["ze"][:200], data["ze"][:200] * 1e6,
                             data["ze"][:200] * 1e-3])
        extra = tuple(np.concatenate([data[key][:200]] * 3) for key in ("t", "ref")
                      if key in data)
        uncertain = (1,) if module.scene["task"] == "radial" else ()
        with torch.no_grad():
            ref = Gated(module.net, module.gate, uncertain)(*_parts(ze, *extra))
        got = OnnxModel(folder / "model.onnx").predict(ze, *extra)
        # float32 kernels differ, and the whitening (eigenvalues down to 1e-9 of the largest)
        # amplifies their rounding: scores agree to 1e-3, flags wherever that cannot matter
        np.testing.assert_allclose(got["domain_score"], ref[-1].numpy(), rtol=1e-3)
        clear = np.abs(ref[-1].numpy() - 1) > 1e-3
        np.testing.assert_array_equal(got["in_domain"][clear], ref[-2].numpy()[clear])
        assert not got["in_domain"][200:].any()
        meta = {p.key: p.value for p in onnx.load(str(folder / "classical.onnx")).metadata_props}
        domain = json.loads(meta["domain"])
        assert domain["quantile"] == QUANTILE and 0 <= domain["false_alarm_fresh"] < 1
        classical = OnnxModel(folder / "classical.onnx").predict(ze, *extra)
        assert not classical["in_domain"][200:].any()
        if uncertain:
            assert np.all(np.isnan(got["sigma"][~got["in_domain"]]))
            assert np.all(np.isfinite(got["sigma"][got["in_domain"]]))


def test_predict_flags_out_of_domain_rows_and_impossible_answers(flow, tmp_path, capsys):
    tmp, _ = flow
    data = load_shards(tmp / "data", [3])
    classical = ClassicalFluid(FLUID_SMALL.excitation.omega,
                               FLUID_SMALL.sphere.radius).predict(data["ze"], data["t"])
    negative = np.flatnonzero(classical["eta"] < 0)[:2]
    assert len(negative) == 2  # the closed form gives negative viscosities in domain
    ze = np.concatenate([data["ze"][negative], data["ze"][:2] * 1e6])
    freq = FLUID_SMALL.excitation.frequency_hz
    np.savez(tmp_path / "m.npz", frequency_hz=freq, ze=ze)
    np.savez(tmp_path / "cal.npz", frequency_hz=freq, t=FLUID_SMALL.calibrated_t())
    rows = predict_file(tmp / "export", tmp_path / "m.npz", calibration=tmp_path / "cal.npz")
    for row in rows[:2]:
        assert "classical eta physically impossible" in row["flags"]
    for row in rows[2:]:
        assert row["in_domain"] is False and row["domain_score"] > 1
        assert "outside the trained domain" in row["flags"]
    assert main(["predict", "--model", str(tmp / "export"), "--input", str(tmp_path / "m.npz"),
                 "--calibration", str(tmp_path / "cal.npz"), "--out", str(tmp_path / "p.csv")]) == 0
    err = capsys.readouterr().err
    assert err.count("warning") == 1 and "of 4 rows outside the trained domain" in err
    header = (tmp_path / "p.csv").read_text().splitlines()[0].split(",")
    assert header[:3] == ["sample", "in_domain", "domain_score"] and header[-1] == "flags"


# ---------------------------------------------------------------- 3. errors a user can act on


def _one_line_error(capsys, argv: list[str], *needles: str) -> str:
    assert main(argv) == 2
    captured = capsys.readouterr()
    err = captured.err.strip()
    assert len(err.splitlines()) == 1 and "Traceback" not in err, err
    for needle in needles:
        assert needle in err, (needle, err)
    assert "allow_pickle" not in err
    return err


def test_predict_errors_name_the_file_and_what_to_do(flow, tmp_path, capsys):
    tmp, _ = flow
    good = tmp / "export"
    sample = tmp_path / "s.npz"
    np.savez(sample, frequency_hz=FLUID_SMALL.excitation.frequency_hz,
             ze=load_shards(tmp / "data", [3])["ze"][:1])
    broken = tmp_path / "broken"
    broken.mkdir()
    raw = (good / "model.onnx").read_bytes()

    def predict(model, data=sample, *needles):
        return _one_line_error(capsys, ["predict", "--model", str(model), "--input", str(data)],
                               *needles)

    predict(tmp_path / "nowhere", sample, "no such model folder", "wtml export")
    # a folder without the manifest `wtml export` writes last (an older wtml's, or an
    # interrupted export) is refused before any of its graphs is opened
    predict(broken, sample, "manifest.json: missing", "wtml export")
    (broken / "manifest.json").write_bytes((good / "manifest.json").read_bytes())
    (broken / "model.onnx").write_bytes(b"")
    predict(broken, sample, "model.onnx: empty file", "wtml export")
    # a truncated graph no longer reaches onnxruntime: its sha256 is not the manifest's
    (broken / "model.onnx").write_bytes(raw[: len(raw) // 2])
    predict(broken, sample, "model.onnx: sha256 does not match manifest.json", "wtml export")
    with pytest.raises(InputError, match="model.onnx: not a readable ONNX model"):
        OnnxModel(broken / "model.onnx")  # opened alone, onnxruntime refuses it
    (broken / "model.onnx").write_bytes(raw)
    predict(broken, sample, "classical.onnx: no such model file")
    csv_path = tmp_path / "m.csv"
    csv_path.write_text("sample,frequency_hz,ze_real,ze_imag\n0,90.0,1.0,2.0\n0,91.0,1.0\n")
    predict(good, csv_path, "line 3 has no value for 'ze_imag'")
    (tmp_path / "empty.npz").write_bytes(b"")
    predict(good, tmp_path / "empty.npz", "empty.npz: not a readable .npz")
    (tmp_path / "junk.npz").write_bytes(os.urandom(300))
    predict(good, tmp_path / "junk.npz", "junk.npz: not a readable .npz")
    np.savez(tmp_path / "objects.npz", frequency_hz=np.array([{"a": 1}], dtype=object))
    # read from its headers first: the array of objects is named before anything is loaded
    predict(good, tmp_path / "objects.npz", "objects.npz: key 'frequency_hz' holds Python "
                                            "objects")


def test_export_and_evaluate_errors(flow, radial_flow, tmp_path, capsys):
    tmp, ckpt = flow
    raw = ckpt.read_bytes()
    (tmp_path / "cut.ckpt").write_bytes(raw[: len(raw) // 3])
    (tmp_path / "notes.ckpt").write_text("hello")
    for bad in ("cut.ckpt", "notes.ckpt"):
        _one_line_error(capsys, ["export", "--checkpoint", str(tmp_path / bad), "--out",
                                 str(tmp_path / "x")], f"{bad}: not a readable checkpoint")
    _one_line_error(capsys, ["export", "--checkpoint", str(tmp_path / "none.ckpt"), "--out",
                             str(tmp_path / "x")], "no such checkpoint file")
    (tmp_path / "file").write_text("")
    _one_line_error(capsys, ["export", "--checkpoint", str(ckpt), "--out",
                             str(tmp_path / "file")], "is a file")
    radial_ckpt = radial_flow / "runs/radial/checkpoints/last.ckpt"
    _one_line_error(capsys, ["evaluate", "--checkpoint", str(radial_ckpt), "--data",
                             str(tmp / "data")], "'radial' task", "'fluid' dataset")
    assert main(["evaluate", "--checkpoint", str(radial_ckpt), "--data",
                 str(radial_flow / "data")]) == 0
    assert "RMSE (µm) by range of d" in capsys.readouterr().out


def test_generate_errors_and_scientific_notation(tmp_path, capsys):
    scene_yaml = tmp_path / "s.yaml"
    scene_yaml.write_text("task: fluid\nsamples: 2.4e2\nshards: 2\nnoise:\n  ze_relative: 1e-4\n")
    assert load_scene(scene_yaml).samples == 240
    (tmp_path / "taken").write_text("")
    _one_line_error(capsys, ["generate", "--config", str(scene_yaml), "--out",
                             str(tmp_path / "taken")], "is a file")
    out = tmp_path / "ds"
    assert main(["generate", "--config", str(scene_yaml), "--out", str(out), "--quiet"]) == 0
    (out / "manifest.json").write_text('{"format": ')
    _one_line_error(capsys, ["generate", "--config", str(scene_yaml), "--out", str(out)],
                    "manifest.json: corrupt", "delete it")
    (tmp_path / "bad.yaml").write_text("task: fluid\nsamples: 2.455e2\n")
    _one_line_error(capsys, ["generate", "--config", str(tmp_path / "bad.yaml"), "--out",
                             str(tmp_path / "d2")], "samples: must be an integer")


def test_generate_removes_what_a_killed_writer_left(tmp_path):
    """A kill -9 mid-write leaves ``.shard-*.<host>.<pid>.tmp``: the next run removes those
    of dead processes, and leaves a live writer's (a parallel --shard job) alone."""
    import socket

    scene = build(type(FLUID_SMALL), {"samples": 40, "shards": 2})
    out = tmp_path / "ds"
    out.mkdir()
    dead = subprocess.Popen([sys.executable, "-c", "pass"])
    dead.wait()
    writer = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"])
    host = socket.gethostname()
    orphan = out / f".shard-00000.npz.{host}.{dead.pid}.tmp"
    live = out / f".shard-00001.npz.{host}.{writer.pid}.tmp"
    orphan.write_bytes(b"half a shard")
    live.write_bytes(b"being written")
    try:
        generate(scene, out, progress=False)
    finally:
        writer.kill()
        writer.wait()
    assert not orphan.exists() and live.exists()
    assert len(load_shards(out)["eta"]) == 40


def test_a_file_is_replaced_whole_or_not_at_all_and_a_lock_is_waited_for(tmp_path):
    """``atomic_write``: bytes or a writer; a writer that fails leaves the old file as it was
    and removes its temporary file, whose name ``tmp_writer`` reads as this process's (and so
    ``clean_orphans`` as a live writer's). ``locked``: a process entering a held lock goes on
    only once the holder leaves."""
    import time

    from wtml.files import atomic_write, locked, tmp_name, tmp_writer

    path = atomic_write(tmp_path / "a.json", b"old")
    seen = []

    def half(fh):
        fh.write(b"ne")
        seen.append(sorted(p.name for p in tmp_path.iterdir()))
        raise OSError("disk full")

    with pytest.raises(OSError, match="disk full"):
        atomic_write(path, half)
    assert path.read_bytes() == b"old" and list(tmp_path.iterdir()) == [path]
    assert seen == [sorted(["a.json", tmp_name(path).name])]
    assert tmp_writer(tmp_name(path).name) == os.getpid()
    assert tmp_writer("a.json") is None and tmp_writer(".a.json.elsewhere.12.tmp") is None
    atomic_write(path, lambda fh: fh.write(b"new"))
    assert path.read_bytes() == b"new"
    lock = tmp_path / "made" / "x.lock"
    code = ("import sys, time\nfrom wtml.files import locked\nprint('ready', flush=True)\n"
            f"with locked({str(lock)!r}):\n    print(time.time(), flush=True)")
    with locked(lock):
        other = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE,
                                 text=True)
        assert other.stdout.readline().strip() == "ready"
        time.sleep(0.5)
        left = time.time()
    entered = float(other.communicate(timeout=60)[0])
    assert entered >= left


@pytest.mark.parametrize(("args", "needle"), [
    (["--model.init_args.lr", "-0.1"], "model.lr must be in (0, 10)"),
    (["--data.init_args.batch_size", "0"], "data.batch_size must be a whole number"),
    (["--trainer.max_epochs", "-1"], "trainer.max_epochs must be in [1, 1000000]"),
    (["--data.init_args.data_dir", "nowhere"], "data.data_dir: nowhere does not exist"),
    (["--model.init_args.hidden", "[0]"], "model.hidden must be a list of layer widths"),
])
def test_train_refuses_bad_values_in_one_line(flow, tmp_path, capsys, args, needle):
    base = ["fit", "--config", str(ROOT / "configs/fluid.yaml"), "--data.init_args.data_dir",
            str(flow[0] / "data"), "--trainer.default_root_dir", str(tmp_path / "run")]
    with pytest.raises(SystemExit) as exit_:
        cli_main(base + args)
    assert exit_.value.code == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("train.py: error: ") and needle in err and len(err.splitlines()) == 1
    assert not (tmp_path / "run").exists()  # refused before Lightning started


def test_train_py_exits_2_with_one_line(flow, tmp_path):
    run = subprocess.run([sys.executable, str(ROOT / "train.py"), "fit", "--config",
                          str(ROOT / "configs/fluid.yaml"), "--data.init_args.data_dir",
                          str(flow[0] / "data"), "--model.init_args.lr", "-1"],
                         capture_output=True, text=True, cwd=tmp_path)
    assert run.returncode == 2 and run.stderr.strip().splitlines() == [
        "train.py: error: model.lr must be in (0, 10), got -1.0"]


# ---------------------------------------------------------------- 4. runs, progress, help


def test_runs_follow_the_root_and_never_overwrite_silently(flow, tmp_path, capsys):
    base = ["fit", "--config", str(ROOT / "configs/fluid.yaml"), "--data.init_args.data_dir",
            str(flow[0] / "data"), "--trainer.max_epochs", "2",
            "--model.init_args.hidden", "[8]", "--trainer.log_every_n_steps", "1"]
    first = tmp_path / "runs/first"
    cli_main(base + ["--trainer.default_root_dir", str(first)])
    out = capsys.readouterr().out
    assert re.search(r"epoch +2/2 .*train_loss .*val_loss .* elapsed, ~.* left", out)
    ckpt = first / "checkpoints/last.ckpt"
    before = ckpt.read_bytes()
    cli_main(base + ["--trainer.default_root_dir", str(tmp_path / "runs/trial"),
                     "--trainer.max_epochs", "1"])
    assert (tmp_path / "runs/trial/checkpoints/last.ckpt").exists()
    assert ckpt.read_bytes() == before  # the trial left the trained run alone
    with pytest.raises(SystemExit):
        cli_main(base + ["--trainer.default_root_dir", str(first)])
    err = capsys.readouterr().err
    assert "a run is already there (epoch 2 of 2)" in err and "--overwrite true" in err
    assert ckpt.read_bytes() == before
    cli_main(base + ["--trainer.default_root_dir", str(first), "--overwrite", "true",
                     "--trainer.max_epochs", "1"])
    assert read_checkpoint(ckpt)["wtml"]["max_epochs"] == 1


def test_every_option_of_every_verb_is_explained():
    def parsers(parser):
        yield parser
        for action in parser._actions:
            if isinstance(action, type(parser._subparsers._group_actions[0])
                          if parser._subparsers else ()):
                for sub in action.choices.values():
                    yield from parsers(sub)

    seen = 0
    for parser in parsers(build_parser()):
        for action in parser._actions:
            if action.option_strings and action.dest not in ("help", "version"):
                assert action.help and len(action.help) > 8, (parser.prog, action.dest)
                seen += 1
    assert seen >= 30
    text = build_parser()._subparsers._group_actions[0].choices["predict"].format_help()
    for needle in (".csv", ".npz", "sample_rate_hz", "frequency_hz", "radial", "in_domain",
                   "manifest.json", "ceiling of", "MEMORY_CEILING"):
        assert needle in text


def test_the_main_job_summary_states_targets_times_and_places():
    stages = Stages()
    stages.times = {"fluid": {"generate": 1.0, "train fluid": 70.0},
                    "radial": {"bench": 30.0}}
    fluid = {"decoder_onnx": {"eta_median": 0.0277, "rho_median": 0.00406},
             "bayes": {"eta_median": 0.0246, "rho_median": 0.00335},
             "closed_form": {"eta_median": 0.327, "rho_median": 0.0113},
             "crlb": {"eta_median": 0.029, "rho_median": 0.006},
             "decoder_onnx_latency_s": 30e-6, "decoder_onnx_throughput": 1.1e6,
             "false_alarm": 0.001, "n_test": 3000, "device_records": 300}

    def device(eta, rho):
        return {"methods": [{"name": "decoder ONNX", "eta_median": eta, "rho_median": rho,
                             "flagged": 0.02}]}

    fluid["device_spread"] = [device(0.028, 0.004) | {"device": "nominal device"},
                              device(0.029, 0.0045) | {"device": "trained spread"},
                              device(0.03, 0.005) | {"device": "k ±3 % only"},
                              device(0.03, 0.007) | {"device": "c0 ±3 % only"}]
    row = {"rmse": 0.4e-6, "ratio": 1.02, "max": 4e-6, "range": "all"}
    radial = {"ours_onnx": row, "inversion": row | {"rmse": 0.397e-6},
              "best_polynomial_rmse": 3.42e-6, "ours_onnx_latency_s": 60e-6,
              "inversion_latency_s": 2e-3, "false_alarm": 0.0009, "worst_range_ratio": 1.1,
              "n_test": 10000,
              "nominal_spread": {"rmse": 10.0, "cover": float("nan"), "flagged": 1.0},
              "ours_spread": {"rmse": 33e-6, "cover": 0.94, "flagged": 0.002},
              "ours_spread_nominal": {"rmse": 4e-6, "cover": 1.0, "flagged": 0.0},
              "ours_spread_whisker": {"rmse": 6e-6, "cover": 0.97, "flagged": 0.001},
              "spread_limit": "whisker.modulus ±3 %: 23.3 µm"}
    text = summary({"fluid": fluid, "radial": radial}, stages)
    for needle in ("1.13× the Bayes", "target ≤ 1 %: MISSED", "target ≤ 0.5 %: met",
                   "1.02× the CRLB", "8.6× below the best polynomial",
                   "runs/fluid/bench/report.md", "runs/radial/bench/error_vs_d.png",
                   "train fluid 1 min 10 s", "total:",
                   "devices of the trained spread (300 records): η median 2.90 % (target ≤ 3 %: "
                   "met), ρ 0.450 % (target ≤ 0.6 %: met), flagged 2.0 %",
                   "limited by c0 ±3 %: η 3.00 %, ρ 0.700 % alone",
                   "over the device spread: ours (the preset's device) 10000000.0 µm, 100.0 % "
                   "flagged",
                   "RMSE 33.0 µm (target ≤ 5 µm: MISSED), 94 % of in-domain answers within 2σ "
                   "(target ≥ 90 %: met), 0.2 % flagged; on the nominal device 4.0 µm, 100 % "
                   "within 2σ, 0.0 % flagged",
                   "limited by whisker.modulus ±3 %: 23.3 µm alone",
                   "with the whisker measured (its length, thickness and modulus nominal): "
                   "6.0 µm, 97 % within 2σ, 0.1 % flagged"):
        assert needle in text, needle
    assert "1.1e+06/s at batch 4096 (targets ≤ 50 µs, ≥ 1e6/s: met, met)" in text  # unsaid
    # timed on one thread beside the other lane: the summary says so, and the verdict stays
    fluid |= {"decoder_onnx_throughput": 9.7e5,
              "timing": {"threads": 1, "busy_elsewhere": 0.48, "cores": 2}}
    text = summary({"fluid": fluid}, stages)
    assert ("9.7e+05/s at batch 4096, on 1 thread (targets ≤ 50 µs, ≥ 1e6/s: met, MISSED; "
            "timed while other work kept 48 % of the 2 cores busy: `wtml bench fluid` alone "
            "times it on a quiet machine); in-domain") in text
    fluid["timing"] = {"threads": 2, "busy_elsewhere": 0.02, "cores": 2}
    assert ("9.7e+05/s at batch 4096, on 2 threads (targets ≤ 50 µs, ≥ 1e6/s: met, MISSED); "
            "in-domain") in summary({"fluid": fluid}, stages)
    fluid["timing"] = {"threads": None, "busy_elsewhere": 0.5, "cores": None}  # unsaid parts
    assert ("9.7e+05/s at batch 4096 (targets ≤ 50 µs, ≥ 1e6/s: met, MISSED; timed while "
            "other work kept 50 % of the cores busy") in summary({"fluid": fluid}, stages)


# ---------------------------------------------------------------- 5. numbers that mean it


def test_bound_rows_are_percentiles_of_pooled_errors():
    """Half the samples with a 1 % std, half with 10 %: the pooled median of |error| solves
    ½ P(|N(0,1%)| < m) + ½ P(|N(0,10%)| < m) = ½, not 0.674 × the median std."""
    std = np.repeat([0.01, 0.1], 500)
    err, eta = sampled_errors({"eta": std, "rho": std}, np.ones(1000), draws=400)
    assert err["eta"].shape == eta.shape == (400_000,)
    exact = optimize.brentq(lambda m: sum(2 * stats.norm.cdf(m / s) - 1 for s in (0.01, 0.1))
                            / 2 - 0.5, 1e-6, 1.0)
    assert np.median(err["eta"]) == pytest.approx(exact, rel=0.01)
    assert abs(np.median(err["eta"]) - 0.674 * np.median(std)) > 0.2 * exact


def test_bayes_likelihood_is_the_dense_gaussian():
    """The Woodbury form with the calibration error integrated out equals the complex
    Gaussian log-density with the full covariance D + c² B Bᴴ, up to a constant per
    measurement, on a grid around each measurement's truth (where the posterior has its
    mass), to 1e-5 (measured: 3e-6). Far from it (log-likelihoods ~ -4e4, no weight), the
    misfit lies almost wholly along the calibration error's directions and the Woodbury form
    keeps ~1e-6 relative."""
    c2 = FLUID_SMALL.nuisance.calibration_error ** 2
    data = FLUID_SMALL.simulate(2, np.random.default_rng(0))
    for n in range(2):
        cv, temp = data["volume_fraction"][n], data["temperature_c"][n]
        scene = build(type(FLUID_SMALL), {"fluid": {
            "volume_fraction": [max(cv - 0.02, 0.0), min(cv + 0.02, 1.0)],
            "temperature_c": [temp - 1.0, temp + 1.0]}})
        bayes = BayesFluid(scene, n_fraction=8, n_temperature=3)
        ze = data["ze"][n:n + 1]
        t = data["t"][n]
        fast = bayes.log_likelihood(ze, t[None])[0]
        z, d = zm_from_ze(t, ze[0]), 1 / bayes._noise_weights(ze[0], t)
        grid = bayes.zm_t[0].T
        dense = []
        for g in range(len(bayes.eta)):
            b = np.stack([grid[g], np.full_like(grid[g], bayes.zref)], -1)
            cov = np.diag(d) + c2 * b @ b.conj().T
            r = z - grid[g]
            dense.append(-(r.conj() @ np.linalg.solve(cov, r)).real - np.linalg.slogdet(cov)[1])
        dense = np.array(dense)
        assert np.ptp(dense) > 1  # the likelihood varies across the grid
        # 1e-5 in a log-likelihood is 1e-5 relative in a posterior weight
        np.testing.assert_allclose(fast - fast[0], dense - dense[0], rtol=1e-7, atol=1e-5)


def test_bayes_recovers_the_truth_when_the_data_are_exact():
    scene = build(type(FLUID_SMALL), {"noise": {"ze_relative": 1e-7},
                                      "nuisance": {"calibration_error": 1e-6}})
    data = scene.simulate(40, np.random.default_rng(4))
    pred = BayesFluid(scene, n_fraction=800, n_temperature=200).predict(data["ze"], data["t"])
    assert np.max(np.abs(pred["rho"] / data["rho"] - 1)) < 2e-3
    assert np.median(np.abs(pred["eta"] / data["eta"] - 1)) < 1e-2


def test_bayes_intervals_cover_at_their_level_on_draws_from_the_prior():
    """The exact posterior's intervals are calibrated over the scene's own prior (what
    simulation-based calibration checks): on 400 draws its central credible intervals and
    its mean ± 1σ / 1.96σ of ln η and ρ hold the truth at 68.3 % and 95 % within 7 points
    (3 binomial std); ρ's posterior mean is :meth:`predict`'s, and each 68 % interval lies
    inside its 95 % one."""
    data = FLUID_SMALL.simulate(400, np.random.default_rng(11))
    bayes = BayesFluid(FLUID_SMALL, n_fraction=200, n_temperature=50)
    got = bayes.intervals(data["ze"], data["t"], (0.6827, 0.95))
    np.testing.assert_allclose(got["rho"]["mean"],
                               bayes.predict(data["ze"], data["t"])["rho"], rtol=1e-12)
    for name, truth in (("eta", np.log(data["eta"])), ("rho", data["rho"])):
        g = got[name]
        assert np.all(g["central"][:, 1, 0] <= g["central"][:, 0, 0])
        assert np.all(g["central"][:, 0, 1] <= g["central"][:, 1, 1])
        for k, (nominal, width) in enumerate(((0.6827, 1.0), (0.95, 1.96))):
            inside = (g["central"][:, k, 0] <= truth) & (truth <= g["central"][:, k, 1])
            gaussian = np.abs(truth - g["mean"]) <= width * g["std"]
            assert abs(inside.mean() - nominal) < 0.07, (name, nominal, inside.mean())
            assert abs(gaussian.mean() - nominal) < 0.07, (name, nominal, gaussian.mean())


def test_the_physics_inversion_converges_to_the_bound():
    """The damped, bounded solve reaches the Cramér–Rao bound (README: 1.01× on 10000
    samples; here 600, within 1.15×), where one undamped step stopped at 1.15×."""
    data = RADIAL_SMALL.simulate(600, np.random.default_rng(5))
    err = (InversionRadial(RADIAL_SMALL).predict(data["ze"], data["ref"])["distance"]
           - data["distance"])
    crlb = radial_crlb(RADIAL_SMALL, data["distance"], data["stiffness"])
    assert np.sqrt(np.mean(err**2) / np.mean(crlb**2)) <= 1.15
