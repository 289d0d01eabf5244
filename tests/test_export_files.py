"""Export folders and every file ``wtml predict`` reads: identity (the manifest's sha256),
the graphs' metadata against their task's schema, records and side files read from their
headers first, the memory ceiling, and one line (exit 2) for each bad input.

The onset and texture exports' own metadata edits are in tests/test_onset.py and
tests/test_texture.py (their fixtures); :func:`edit_metadata` is shared."""

import json
import os
import shutil
import time
import tracemalloc
import zipfile
from pathlib import Path

import numpy as np
import onnx
import pytest
from conftest import FLUID_SMALL

from wtml import __version__
from wtml.cli import main
from wtml.data import load_shards
from wtml.files import MEMORY_CEILING, FileError, sha256
from wtml.runtime import metadata as md
from wtml.runtime.predict import InputError, OnnxModel, load_export, read_input
from wtml.runtime.recordings import read_record
from wtml.runtime.texture import window_batches, windows
from wtml.scenes import FluidScene, OnsetScene, RadialScene, TextureScene
from wtml.schema import SchemaError


def edit_metadata(folder: Path, name: str, rehash: bool = True, **changes: str | None) -> None:
    """Change graph ``name``'s metadata keys in ``folder`` (a value of None removes the key)
    and, with ``rehash``, make the manifest agree (its sha256, size and metadata): an edit
    that only the schema can catch."""
    path = folder / name
    model = onnx.load(str(path))
    props = {p.key: p.value for p in model.metadata_props}
    for key, value in changes.items():
        if value is None:
            props.pop(key, None)
        else:
            props[key] = value
    del model.metadata_props[:]
    for key, value in props.items():
        model.metadata_props.add(key=key, value=value)
    onnx.save(model, str(path))
    if rehash:
        manifest = json.loads((folder / "manifest.json").read_text())
        for entry in manifest["files"]:
            if entry["name"] == name:
                entry["sha256"], entry["bytes"] = sha256(path), path.stat().st_size
        manifest["metadata"][name] = props
        (folder / "manifest.json").write_text(json.dumps(manifest))


def one_line(capsys, argv: list[str], *needles: str) -> str:
    """``wtml argv`` exits 2 with one line on stderr holding every needle."""
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "Traceback" not in err, err
    for needle in needles:
        assert needle in err, (needle, err)
    return err


@pytest.fixture
def fluid_copy(flow, tmp_path):
    """A copy of the fluid flow's export folder, an input and a calibration for it."""
    tmp, _ = flow
    folder = tmp_path / "export"
    shutil.copytree(tmp / "export", folder)
    freq = FLUID_SMALL.excitation.frequency_hz
    np.savez(tmp_path / "m.npz", frequency_hz=freq, ze=load_shards(tmp / "data", [3])["ze"][:3])
    np.savez(tmp_path / "cal.npz", frequency_hz=freq, t=FLUID_SMALL.calibrated_t())
    return folder, tmp_path / "m.npz", tmp_path / "cal.npz"


def _predict(folder, data, cal) -> list[str]:
    return ["predict", "--model", str(folder), "--input", str(data), "--calibration", str(cal)]


# ------------------------------------------------------------------------ identity


def test_export_lists_every_file_with_its_sha256_and_the_graphs_metadata(flow):
    """manifest.json names each file `wtml export` wrote with its sha256 and size, carries
    the metadata each graph carries, the task, the scene hash and the package version; the
    schema's tables are the scenes' and decoders' own."""
    folder = flow[0] / "export"
    manifest = json.loads((folder / "manifest.json").read_text())
    assert manifest["wtml_version"] == __version__ and manifest["task"] == "fluid"
    assert {f["kind"]: f["name"] for f in manifest["files"]} == {
        "decoder": "model.onnx", "classical": "classical.onnx"}
    for entry in manifest["files"]:
        path = folder / entry["name"]
        assert entry["sha256"] == sha256(path) and entry["bytes"] == path.stat().st_size
        props = {p.key: p.value for p in onnx.load(str(path)).metadata_props}
        assert manifest["metadata"][entry["name"]] == props
        assert props["scene_hash"] == manifest["scene_hash"]
    from wtml.decoders.onset import CALIBRATION

    assert md.ONSET_CALIBRATION == CALIBRATION
    for task, cls in (("fluid", FluidScene), ("radial", RadialScene),
                      ("texture", TextureScene)):
        assert md.GRAPH_OUTPUTS[(task, "classical")] == cls.OUTPUTS
        # the fluid decoder's graph adds its intervals (issue 25 §4)
        assert md.GRAPH_OUTPUTS[(task, "decoder")] == cls.OUTPUTS + (
            md.FLUID_SIGMAS if task == "fluid" else ())
    assert md.GRAPH_OUTPUTS[("onset", "decoder")][:2] == OnsetScene.OUTPUTS


def test_an_edited_graph_is_refused_by_its_sha256(fluid_copy, capsys):
    folder, data, cal = fluid_copy
    assert main(_predict(folder, data, cal)) == 0
    capsys.readouterr()
    edit_metadata(folder, "model.onnx", rehash=False, frequency_hz="[1.0]")
    one_line(capsys, _predict(folder, data, cal),
             "model.onnx: sha256 does not match manifest.json: edited or damaged",
             "export it again")


def test_a_folder_without_a_manifest_or_with_a_bad_one_is_refused(fluid_copy, capsys):
    folder, data, cal = fluid_copy
    good = (folder / "manifest.json").read_text()
    manifest = json.loads(good)
    variants = {
        "missing": None,
        "not json": "{",
        "a list": "[]",
        "no files": json.dumps({k: v for k, v in manifest.items() if k != "files"}),
        "a path": json.dumps(manifest | {"files": [
            manifest["files"][0] | {"name": "../model.onnx"}, manifest["files"][1]]}),
        "no decoder": json.dumps(manifest | {"files": manifest["files"][1:]}),
        "size a string": json.dumps(manifest | {"files": [
            manifest["files"][0] | {"bytes": "12"}, manifest["files"][1]]}),
        "format 6": json.dumps(manifest | {"format": 6, "wtml_version": "9.1"}),
        "format 1": json.dumps(manifest | {"format": 1}),
        "format 0": json.dumps(manifest | {"format": 0}),
        "format true": json.dumps(manifest | {"format": True}),
        "no device": json.dumps({k: v for k, v in manifest.items() if k != "device"}),
        "another device": json.dumps(manifest | {"device": manifest["device"]
                                                 | {"sha256": "0" * 64}}),
    }
    needles = {"missing": "manifest.json: missing", "not json": "not valid JSON",
               "a list": "must be a mapping", "no files": "files: missing",
               "a path": "files[0].name", "no decoder": "files: must list one 'decoder'",
               "size a string": "files[0].bytes",
               "format 6": f"format: 6, exported by a newer wtml (9.1) than this one "
                           f"({__version__}, reads formats 2-5): install that wtml's runtime",
               "format 0": "format: must be in [2, 5]",
               "format true": "format: must be a number in [2, 5], got True",
               "format 1": "format: 1, exported by an older wtml (it names no device)",
               "no device": "device: missing",
               "another device": "metadata scene's device is not manifest.json's fluid-lumped"}
    for name, text in variants.items():
        if text is None:
            (folder / "manifest.json").unlink()
        else:
            (folder / "manifest.json").write_text(text)
        one_line(capsys, _predict(folder, data, cal), "manifest.json", needles[name])
    (folder / "manifest.json").write_text(json.dumps(manifest | {"format": 2}))
    assert main(_predict(folder, data, cal)) == 0  # an export made before format 3 loads
    (folder / "manifest.json").write_text(good)
    assert main(_predict(folder, data, cal)) == 0


def _schema_keys(cls, path: str = "") -> dict[str, str]:
    """Every key a metadata dataclass reads, nested ones by their dotted path, with its type
    and range: what an older runtime's schema would refuse if it changed."""
    import dataclasses
    import typing

    keys, hints = {}, typing.get_type_hints(cls)
    for f in dataclasses.fields(cls):
        hint = hints[f.name]
        keys[path + f.name] = f"{hint} {f.metadata.get('range', '')}{f.metadata.get('choices', '')}"
        for inner in (hint, *typing.get_args(hint)):
            if dataclasses.is_dataclass(inner):
                keys |= _schema_keys(inner, f"{path}{f.name}.")
    return keys


SCHEMA_FINGERPRINT = {3: "2cff5e5e4ffc8d4e0184f3ea75e2abfca729ff7b50ebb54626e76a16d8e9e788",
                      4: "56215c9ff1b2939b9a4e1d973928c12f3b0c0f0247d7f29847b0036aced875a8",
                      5: "31700925a530fc7cd5676a5f6a0c3e25cbb044b53633480bc3fa5c386b4911a2"}
"""Per export format, the sha256 of every key the runtime's metadata schemas read
(:func:`_schema_keys` of the manifest and each task's graph metadata) and of the tables
they check graphs against (inputs, outputs, references, required keys, kinds)."""


def test_a_change_to_the_metadata_schema_comes_with_a_new_export_format():
    """An older runtime refuses a key it does not know: a schema that gains, loses or narrows a
    key, or changes a graph's inputs, outputs, references or required keys, must raise
    ``MANIFEST_FORMAT`` so that the older runtime says "exported by a newer wtml" instead
    (and this test records the new format's fingerprint). The schemas' ``check`` rules are
    code, not keys: a change there is the author's to judge."""
    import hashlib

    keys = _schema_keys(md.ExportManifest) | _schema_keys(md.OutputDomain, "domain.outputs.*.") | {
        f"{task}.{k}": v for task, cls in md.SCHEMAS.items() for k, v in _schema_keys(cls).items()}
    keys["format"] = "int"  # its range is the formats read, not a key's meaning
    tables = {"required": {task: cls.REQUIRED for task, cls in md.SCHEMAS.items()},
              "kinds": md.KINDS, "gate": md.GATE_OUTPUTS, "physical": md.PHYSICAL,
              "references": md.REFERENCE_KEYS,
              **{name: {"/".join(k): v for k, v in table.items()} for name, table in (
                  ("inputs", md.GRAPH_INPUTS), ("outputs", md.GRAPH_OUTPUTS))}}
    text = json.dumps([keys, tables], sort_keys=True)
    assert "texture.uncertainty.top_slope" in keys and "texture.domain.quantile" in keys
    assert SCHEMA_FINGERPRINT.get(md.MANIFEST_FORMAT) == hashlib.sha256(
        text.encode()).hexdigest(), (
        f"the export metadata's schema is not format {md.MANIFEST_FORMAT}'s: raise "
        f"MANIFEST_FORMAT and record its fingerprint here")


def test_predict_threads_caps_every_session_it_opens_and_only_while_it_runs(
        fluid_copy, monkeypatch, capsys):
    """``wtml predict --threads N`` opens the decoder's and the classical path's sessions on
    N intra-op threads (default: every core it may use), replacing ``$WTML_THREADS`` for the
    command only, also when it fails; a bad count is refused naming the option."""
    import onnxruntime as ort

    from wtml.cores import THREADS_ENV, capped

    folder, data, cal = fluid_copy
    seen, real = [], ort.InferenceSession

    def session(model, options, **kw):
        seen.append(options.intra_op_num_threads)
        return real(model, options, **kw)

    monkeypatch.setattr(ort, "InferenceSession", session)
    monkeypatch.setattr(os, "sched_getaffinity", lambda _: set(range(4)), raising=False)
    monkeypatch.delenv(THREADS_ENV, raising=False)
    for flags, threads in (([], 4), (["--threads", "3"], 3), (["--threads", "1"], 1)):
        seen.clear()
        assert main(_predict(folder, data, cal) + flags) == 0
        assert seen == [threads, threads] and THREADS_ENV not in os.environ
    monkeypatch.setenv(THREADS_ENV, "2")
    seen.clear()
    assert main(_predict(folder, data, cal) + ["--threads", "3"]) == 0
    assert seen == [3, 3] and os.environ[THREADS_ENV] == "2"  # replaced, then put back
    assert main(_predict(folder, folder / "missing.npz", cal) + ["--threads", "1"]) == 2
    assert os.environ[THREADS_ENV] == "2"  # put back after a failed command too
    capsys.readouterr()
    with pytest.raises(SystemExit):
        main(_predict(folder, data, cal) + ["--threads", "0"])
    assert "--threads" in capsys.readouterr().err
    with pytest.raises(ValueError, match="threads: must be at least 1"), capped(0):
        pass


def test_predict_refuses_an_export_of_another_device(fluid_copy, tmp_path, capsys):
    """The export's manifest names its device and content hash; `wtml predict --device` takes
    the device the measurements come from and refuses an export trained for another: another
    name, or the same name with other values (a user's copy of the shipped file, edited)."""
    from wtml.devices import DEVICES_DIR, device_hash, load_device

    folder, data, cal = fluid_copy
    manifest = json.loads((folder / "manifest.json").read_text())
    shipped = load_device("fluid-lumped")
    assert manifest["device"] == {"name": "fluid-lumped", "sha256": device_hash(shipped)}
    assert main(_predict(folder, data, cal) + ["--device", "fluid-lumped"]) == 0
    capsys.readouterr()
    mine = tmp_path / "mine.yaml"  # the same device, commented and spelled otherwise: accepted
    text = (DEVICES_DIR / "fluid-lumped.yaml").read_text()
    lines = text.splitlines()
    first = next(k for k, line in enumerate(lines) if line.startswith("c0:"))
    lines[first], lines[first + 1] = lines[first + 1], lines[first]  # c0 and phi swapped
    mine.write_text("# my copy\n" + "\n".join(lines).replace("q: 50.0", "q: 5.0e1") + "\n")
    assert device_hash(load_device(mine)) == device_hash(shipped)
    assert main(_predict(folder, data, cal) + ["--device", str(mine)]) == 0
    capsys.readouterr()
    mine.write_text(text.replace("q: 50.0", "q: 45.0"))
    one_line(capsys, _predict(folder, data, cal) + ["--device", str(mine)],
             f"--device {mine}: {folder} was trained for device 'fluid-lumped' (",
             "(same name, other values); train and export a decoder")
    one_line(capsys, _predict(folder, data, cal) + ["--device", "micro"],
             "was trained for device 'fluid-lumped'", "this is 'micro'")
    one_line(capsys, _predict(folder, data, cal) + ["--device", "nano"],
             "unknown device 'nano': not a shipped device")


# Metadata edits made consistent with the manifest: each refused by the schema, naming the key.
FLUID_VARIANTS = {
    "task": ("radial", "metadata inputs"),
    "kind": ("stream", "metadata kind"),
    "outputs": ('["rho", "eta"]', "metadata outputs"),
    "inputs": ('["ze_im", "ze_re", "t_re", "t_im"]', "metadata inputs"),
    "frequency_hz": ("[]", "metadata frequency_hz"),
    "units": ('{"eta": 3}', "metadata units.eta"),
    "scene_hash": ("0" * 64, "metadata scene_hash"),
    "wtml_version": (None, "metadata wtml_version: missing"),
    "references": ("[1, 2]", "metadata references"),
}


@pytest.mark.parametrize("key", sorted(FLUID_VARIANTS))
def test_metadata_edited_consistently_is_refused_by_the_schema(fluid_copy, capsys, key):
    folder, data, cal = fluid_copy
    value, needle = FLUID_VARIANTS[key]
    edit_metadata(folder, "model.onnx", **{key: value})
    one_line(capsys, _predict(folder, data, cal), "model.onnx: " + needle)


def _fluid_props(flow) -> dict[str, str]:
    model = onnx.load(str(flow[0] / "export/model.onnx"))
    return {p.key: p.value for p in model.metadata_props}


@pytest.mark.parametrize("change, needle", [
    ({"task": "banana"}, "metadata task: must be one of"),
    ({"task": None}, "metadata task"),
    ({"frequency_hz": '"90"'}, "metadata frequency_hz"),
    ({"frequency_hz": "[90, -1]"}, "metadata frequency_hz[1]"),
    ({"frequency_hz": "[90, NaN]"}, "metadata frequency_hz: not valid JSON"),
    ({"frequency_hz": "[90, 90]"}, "metadata frequency_hz: must not list a frequency twice"),
    ({"domain": "{}"}, "metadata domain.score: missing"),
    ({"domain": "[]"}, "metadata domain: must be a mapping"),
    ({"units": "null"}, "metadata units: must be a mapping"),
    ({"outputs": "7"}, "metadata outputs: must be a list of strings"),
    ({"scene": '{"task": "fluid"}'}, "metadata scene_hash: is not the hash"),
    ({"label": None, "kind": None}, "metadata kind: missing"),
    ({"extra": "1"}, "metadata extra: unknown key"),
])
def test_metadata_schema_refuses_wrong_types_and_values(flow, change, needle):
    props = _fluid_props(flow) | change
    props = {k: v for k, v in props.items() if v is not None}
    with pytest.raises(SchemaError) as err:
        md.graph_metadata(props, "x/model.onnx")
    assert str(err.value).startswith("x/model.onnx: ") and needle in str(err.value), err.value


@pytest.mark.parametrize("edit, needle", [
    (lambda d: d | {"outputs": {}}, "domain.outputs: must give the ranges of 'eta'"),
    (lambda d: d | {"outputs": {"rho": d["outputs"]["rho"]}}, "must give the ranges of 'eta'"),
    (lambda d: d | {"outputs": d["outputs"] | {"sigma": d["outputs"]["rho"]}},
     "'sigma' is not an output"),
    (lambda d: d | {"quantile": 7}, "domain.quantile"),
    (lambda d: d | {"false_alarm_fresh": -1}, "domain.false_alarm_fresh"),
    (lambda d: d | {"outputs": d["outputs"] | {"eta": d["outputs"]["eta"] | {
        "physical": [1.0, 2.0]}}}, "domain.outputs.eta.physical: must contain"),
    (lambda d: d | {"outputs": d["outputs"] | {"eta": d["outputs"]["eta"] | {
        "log": "yes"}}}, "domain.outputs.eta.log: must be true or false"),
    (lambda d: d | {"outputs": d["outputs"] | {"rho": d["outputs"]["rho"] | {
        "in_domain": [2000.0, 3000.0]}}}, "domain.outputs.rho.in_domain: must contain"),
])
def test_the_domain_cannot_lose_the_impossible_answer_flag(flow, edit, needle):
    """An emptied or partial ``domain.outputs`` would drop the flag of impossible answers
    silently: refused, as are ranges that do not hold the trained one."""
    props = _fluid_props(flow)
    domain = json.loads(props["domain"])
    props["domain"] = json.dumps(edit(domain))
    with pytest.raises(SchemaError, match="x/model.onnx: metadata ") as err:
        md.graph_metadata(props, "x/model.onnx")
    assert needle in str(err.value), err.value


def test_metadata_that_does_not_describe_its_graph_is_refused(fluid_copy):
    """The schema holds the graph to its metadata: renamed outputs (the distance column
    holding sigma) and a grid of another size than the graph's inputs."""
    folder, _, _ = fluid_copy
    edit_metadata(folder, "classical.onnx", frequency_hz=json.dumps(list(range(1, 31))))
    with pytest.raises(SchemaError, match=r"classical.onnx: metadata frequency_hz: says input "
                                          r"'ze_re' is \(batch, 30\)"):
        load_export(folder)
    edit_metadata(folder, "classical.onnx", frequency_hz=json.dumps(
        FLUID_SMALL.excitation.frequency_hz.tolist()), kind="decoder")
    # a fluid decoder graph also returns its intervals (issue 25 §4): its outputs say so first
    with pytest.raises(SchemaError, match=r"classical.onnx: metadata outputs: must be \['eta', "
                                          r"'rho', 'eta_log_sigma', 'rho_sigma'\] for a fluid "
                                          r"decoder graph"):
        load_export(folder)


# ------------------------------------------------------------------ inputs and side files


def test_bad_inputs_and_calibrations_are_one_line(fluid_copy, tmp_path, capsys):
    folder, data, cal = fluid_copy
    freq = FLUID_SMALL.excitation.frequency_hz
    ze = np.load(data)["ze"]
    t = FLUID_SMALL.calibrated_t()
    bad = tmp_path / "bad.npz"

    def refused(arrays: dict, needle: str, *, as_cal: bool = False) -> None:
        np.savez(bad, **arrays)
        argv = _predict(folder, data, bad) if as_cal else _predict(folder, bad, cal)
        one_line(capsys, argv, "bad.npz", needle)

    refused({"frequency_hz": freq, "ze": ze[:0]}, "holds no measurements")
    refused({"frequency_hz": freq, "ze_real": ze.real + 0j, "ze_imag": ze.imag},
            "'ze_real' must be real (it is complex)")
    refused({"frequency_hz": freq, "ze": ze.astype(str)}, "'ze' must hold numbers")
    refused({"frequency_hz": freq[None], "ze": ze}, "'frequency_hz' must have 1 dimension")
    refused({"frequency_hz": freq, "ze": ze[None, None]}, "'ze' must have 1 or 2 dimension")
    refused({"frequency_hz": freq, "e": np.ones((1, 31, 50), complex),
             "i": np.ones((1, 31, 50)), "sample_rate_hz": 1e4}, "'e' must be real")
    refused({"frequency_hz": freq, "e": np.ones((1, 31, 50)), "i": np.ones((1, 31, 50)),
             "sample_rate_hz": [1e4, 2e4]}, "'sample_rate_hz' must be one real number")
    refused({"frequency_hz": freq, "e": np.ones((1, 31, 50)), "i": np.ones((1, 31, 50)),
             "sample_rate_hz": -1.0}, "'sample_rate_hz' must be in")
    refused({"frequency_hz": freq, "ze": ze * 1e300}, "'ze' is beyond the float32 range")
    refused({"frequency_hz": freq, "t": t * 1e300}, "'t' is beyond the float32 range",
            as_cal=True)
    refused({"frequency_hz": freq, "t": t[None, None]}, "t must have shape", as_cal=True)
    refused({"frequency_hz": freq, "t": t.astype(str)}, "'t' must hold numbers", as_cal=True)
    refused({"frequency_hz": freq, "t": np.full_like(t, np.nan)}, "t is NaN", as_cal=True)
    raw = Path(data).read_bytes()
    bad.write_bytes(raw[: len(raw) // 2])
    one_line(capsys, _predict(folder, bad, cal), "bad.npz: not a readable .npz")
    big = tmp_path / "big.csv"
    with open(big, "w") as fh:
        fh.write("frequency_hz,ze_real,ze_imag\n")
        fh.truncate(65 * 1024**2)  # sparse: its size is what is checked
    one_line(capsys, _predict(folder, big, cal), "big.csv", "over the 67.1 MB")


def _record(path: Path, n: int, n_samples: int, rate, dtype=float) -> Path:
    np.savez(path, e=np.zeros((n, n_samples), dtype), i=np.zeros((n, n_samples), dtype),
             sample_rate_hz=rate)
    return path


def test_records_are_checked_from_their_headers(tmp_path):
    """Complex e and i are refused (never cast), as are zero records, a truncated file, a
    rate that is an array, NaN or <= 0, and three-dimensional signals."""
    rec = tmp_path / "r.npz"
    cases = [
        (dict(e=np.zeros((2, 100), complex), i=np.zeros((2, 100)), sample_rate_hz=1e3),
         "'e' must be real (it is complex)"),
        (dict(e=np.zeros((2, 100)), i=np.zeros((2, 100), complex), sample_rate_hz=1e3),
         "'i' must be real (it is complex)"),
        (dict(e=np.zeros((0, 100)), i=np.zeros((0, 100)), sample_rate_hz=1e3),
         "holds no records"),
        (dict(e=np.zeros((2, 100)), i=np.zeros((2, 100)), sample_rate_hz=[1e3, 1e3]),
         "'sample_rate_hz' must be one real number"),
        (dict(e=np.zeros((2, 100)), i=np.zeros((2, 100)), sample_rate_hz=np.nan),
         "'sample_rate_hz' must be in"),
        (dict(e=np.zeros((2, 100)), i=np.zeros((2, 100)), sample_rate_hz=0.0),
         "'sample_rate_hz' must be in"),
        (dict(e=np.zeros((2, 2, 100)), i=np.zeros((2, 2, 100)), sample_rate_hz=1e3),
         "'e' must have 1 or 2 dimension"),
        (dict(e=np.zeros((2, 100)), i=np.zeros((3, 100)), sample_rate_hz=1e3),
         "must have the same shape"),
        (dict(e=np.zeros((2, 100)), i=np.zeros((2, 100)), sample_rate_hz=True),
         "'sample_rate_hz' must be one real number"),
    ]
    for arrays, needle in cases:
        np.savez(rec, **arrays)
        with pytest.raises(FileError, match=str(rec)) as err:
            read_record(rec, 1e3, 100)
        assert needle in str(err.value), (needle, err.value)
    _record(rec, 2, 100, 1e3)
    raw = rec.read_bytes()
    rec.write_bytes(raw[: len(raw) - 300])
    with pytest.raises(FileError, match="not a readable .npz"):
        read_record(rec, 1e3, 100)


def _claimed(path: Path, shape: tuple[int, ...], rate: float) -> Path:
    """An .npz whose e and i headers claim ``shape`` (float64) with no data behind them: what
    reading from the headers sees first."""
    with zipfile.ZipFile(path, "w") as archive:
        for key in ("e", "i"):
            with archive.open(f"{key}.npy", "w") as fh:
                np.lib.format.write_array_header_1_0(fh, {"descr": "<f8", "fortran_order": False,
                                                          "shape": shape})
        with archive.open("sample_rate_hz.npy", "w") as fh:
            np.save(fh, np.float64(rate))
    return path


def test_memory_refusals_are_fast_and_allocate_little(tmp_path, capsys):
    """``sample_rate_hz=1`` on an 860 kB record would resample to 5e9 samples (39 GiB):
    refused before reading e or i, naming the ceiling; so are 1e8 samples for a model fed
    windows (the headers claim them; nothing behind them is read)."""
    rec = _record(tmp_path / "slow.npz", 1, 53760, 1.0)
    assert rec.stat().st_size > 860_000
    for at_least, needle in ((True, "over the 2.15 GB ceiling of wtml predict"),
                             (False, "the model takes records of 53760")):
        tracemalloc.start()
        start = time.perf_counter()
        with pytest.raises(FileError) as err:
            read_record(rec, 48000.0, 53760 if not at_least else 12800, at_least=at_least)
        took = time.perf_counter() - start
        peak = tracemalloc.get_traced_memory()[1]
        tracemalloc.stop()
        assert needle in str(err.value) and str(rec) in str(err.value), err.value
        assert took < 0.5 and peak < 5e6, (took, peak)
    huge = _claimed(tmp_path / "huge.npz", (1, 10**8), 10000.0)
    tracemalloc.start()
    with pytest.raises(FileError, match="over the 2.15 GB ceiling") as err:
        read_record(huge, 10000.0, 12800, at_least=True)
    assert tracemalloc.get_traced_memory()[1] < 5e6
    tracemalloc.stop()
    assert "(1, 100000000)" in str(err.value)
    # the stated ceiling is the package's
    assert MEMORY_CEILING == 2 * 1024**3


def test_long_recordings_are_windowed_in_batches():
    """Windows in batches are the same windows, in the same order, as all at once, and each
    batch is at most the batch size (memory does not grow with the number of windows)."""
    rng = np.random.default_rng(0)
    x = rng.normal(size=(2, 3, 1050)).astype(np.float32)
    cut, owner = windows(x, 100)
    got = list(window_batches(x, 100, 7))
    assert all(b[0].shape[1] <= 7 for b in got)
    np.testing.assert_array_equal(np.concatenate([b[0] for b in got], 1), cut)
    np.testing.assert_array_equal(np.concatenate([b[1] for b in got]), owner)


def test_a_model_run_in_batches_gives_the_answer_of_one_run(fluid_copy, monkeypatch):
    from wtml.runtime import predict

    folder, data, cal = fluid_copy
    model = OnnxModel(folder / "model.onnx")
    ze = np.load(data)["ze"]
    t = np.broadcast_to(FLUID_SMALL.calibrated_t(), (len(ze), *FLUID_SMALL.calibrated_t().shape))
    whole = model.predict(ze, t)
    monkeypatch.setattr(predict, "RUN_BYTES", 1)  # one row per call
    rows = model.predict(ze, t)
    for key in whole:
        np.testing.assert_allclose(rows[key].astype(float), whole[key].astype(float), rtol=1e-6)
    assert read_input(data, model.frequency_hz).shape == ze.shape


def test_a_large_batch_is_cast_into_the_models_scratch(fluid_copy):
    """A batch over SCRATCH_FROM_BYTES (4096 rows, three calls of the graph) is cast into the
    model's float32 scratch, grown from a smaller batch's and kept from call to call. Its
    answers are those of the inputs cast beforehand, to the bit (Ze's complex views, a T per
    row and a T broadcast over the rows alike), the same as one row at a time, and the same
    when two threads call the model at once."""
    import threading

    from wtml.physics.twoport import flat_parts
    from wtml.runtime import predict

    folder, data, _ = fluid_copy
    model = OnnxModel(folder / "model.onnx")
    rng = np.random.default_rng(0)
    ze = np.resize(np.load(data)["ze"], (4096, len(FLUID_SMALL.excitation.frequency_hz)))
    ze = ze * (1 + 0.01 * rng.standard_normal(ze.shape))
    t0 = FLUID_SMALL.calibrated_t()
    per_row = t0 * (1 + 0.005 * rng.standard_normal((len(ze), 1, 1, 1)))
    shared = np.broadcast_to(t0, (len(ze), *t0.shape))
    row = 4 * 10 * ze.shape[1]  # bytes of a row's inputs as float32: Ze and T, re and im
    assert row * len(ze) > predict.RUN_BYTES > row * 200 > predict.SCRATCH_FROM_BYTES
    model.predict(ze[:200], per_row[:200])  # a smaller scratch first: the large batch grows it
    answers = {}
    for name, t in (("per row", per_row), ("shared", shared)):
        whole = answers[name] = model.predict(ze, t)
        scratch = model._scratch.floats
        assert 4 * scratch.size >= row * predict.rows_per_run(row)
        again = model.predict(ze, t)
        assert model._scratch.floats is scratch
        cast = model.run(ze.real.astype(np.float32), ze.imag.astype(np.float32),
                         *flat_parts(t))
        rows = [model.predict(ze[k:k + 1], t[k:k + 1]) for k in range(len(ze))]
        for key in whole:
            np.testing.assert_array_equal(again[key], whole[key])
            np.testing.assert_array_equal(cast[key], whole[key])
            one_by_one = np.concatenate([r[key] for r in rows])
            np.testing.assert_allclose(whole[key].astype(float), one_by_one.astype(float),
                                       rtol=1e-6, atol=1e-12, err_msg=key)
    same = model.predict(ze, np.ascontiguousarray(shared))
    for key in same:
        np.testing.assert_array_equal(same[key], answers["shared"][key])
    got = {}

    def calls(name, t):
        got[name] = [model.predict(ze, t) for _ in range(5)]

    threads = [threading.Thread(target=calls, args=a) for a in (("per row", per_row),
                                                               ("shared", shared))]
    for th in threads:
        th.start()
    for th in threads:
        th.join()
    for name, outs in got.items():
        for out in outs:
            for key in out:
                np.testing.assert_array_equal(out[key], answers[name][key])


# --------------------------------------------------------------------------- the CLI


@pytest.mark.parametrize("argv, needle", [
    (["bench", "onset", "--threads", "x"], "argument --threads: expects a whole number"),
    (["bench", "onset", "--threads", "0"], "argument --threads: expects a whole number in [1"),
    (["bench", "radial", "--max-samples", "-5"], "argument --max-samples: expects a whole "
                                                 "number in [1, 1e+08], got '-5'"),
    (["walkthrough", "--seed", "x"], "argument --seed: expects a whole number, got 'x'"),
    (["predict"], "the following arguments are required: --model, --input"),
    (["predict", "--model", "m", "--input", "x", "--bogus"], "unrecognized arguments: --bogus"),
    (["frobnicate"], "invalid choice: 'frobnicate'"),
])
def test_a_bad_command_line_is_one_line(capsys, argv, needle):
    with pytest.raises(SystemExit) as err:
        main(argv)
    assert err.value.code == 2
    captured = capsys.readouterr()
    lines = captured.err.strip().splitlines()
    assert len(lines) == 1 and needle in lines[0] and "usage:" not in captured.err, captured.err
    assert lines[0].startswith("wtml")


@pytest.mark.parametrize("argv, needle", [
    (["walkthrough", "--seed", "-1"], "argument --seed: expects a number in [0,"),
    (["walkthrough", "--repeats", "100000000"], "argument --repeats: expects a number in [1, "
                                                "1000]"),
])
def test_values_a_verb_cannot_use_are_one_line(capsys, argv, needle):
    """Once a traceback from numpy's seeding, or a run that does not end."""
    one_line(capsys, argv, needle)


def test_a_bug_keeps_its_traceback_and_bad_input_does_not(monkeypatch, capsys):
    """A ValueError raised by wtml's own checks is one line; one raised inside numpy (input
    wtml failed to check) is a bug, and its traceback is kept."""
    import wtml.cli

    def checked(args):
        raise InputError("x.npz: 'ze' must hold numbers")

    def bug(args):
        return np.ones(3).reshape(2)

    monkeypatch.setattr(wtml.cli, "_presets", checked)
    one_line(capsys, ["presets"], "wtml presets: error: x.npz: 'ze' must hold numbers")
    monkeypatch.setattr(wtml.cli, "_presets", bug)
    with pytest.raises(ValueError, match="cannot reshape"):
        main(["presets"])


def test_an_interrupted_export_leaves_no_manifest(fluid_copy, flow, monkeypatch, capsys):
    """`wtml export` removes the folder's manifest first and writes the new one last: a
    re-export that dies half-way leaves a folder that is refused, never old and new graphs
    mixed under the old manifest."""
    from wtml.exporters import common as export
    from wtml.exporters import matrix  # where the fluid graphs are written

    folder, data, cal = fluid_copy
    calls = []

    def dies_on_the_second_graph(*args, **kwargs):
        calls.append(args[2])
        if len(calls) == 2:
            raise KeyboardInterrupt  # as a kill would
        return real(*args, **kwargs)

    real = matrix.export_graph
    monkeypatch.setattr(matrix, "export_graph", dies_on_the_second_graph)
    with pytest.raises(KeyboardInterrupt):
        export.export_model(flow[1], folder)
    assert not (folder / "manifest.json").exists()
    one_line(capsys, _predict(folder, data, cal), "manifest.json: missing", "export it again")


def test_a_checkpoint_from_an_older_wtml_exports_with_a_consistent_scene_hash(flow, tmp_path):
    """A checkpoint whose stored scene lacks a key this version's scene holds (written before
    the key existed: here the fluid transducer's `calibration`) exports, and the export's
    metadata holds the scene as rebuilt, whose hash is its scene_hash: predict accepts it."""
    import torch

    state = torch.load(flow[1], map_location="cpu", weights_only=True)
    scene = state["wtml"]["scene"]
    assert "calibration" in scene["transducer"]
    del scene["transducer"]["calibration"]
    old = tmp_path / "old.ckpt"
    torch.save(state, old)
    from wtml.exporters import common as export

    export.export_model(old, tmp_path / "ex")
    from wtml.runtime.predict import load_export

    decoder, _ = load_export(tmp_path / "ex")
    import json

    assert "calibration" in json.loads(decoder.metadata["scene"])["transducer"]
