"""Every file of a dataset folder checked before it is trusted (issue 22): the manifest, the
shard sidecars and ``scene.json`` against their schemas, each shard from its zip headers (a
regular file of bounded size, the arrays the manifest lists), its values finite, and a folder
that belongs to one scene. Each refusal is one line naming the file and the key."""

import json
import os
import shutil
import subprocess
import sys
import time

import numpy as np
import pytest
import torch
from hypothesis import given
from hypothesis import strategies as st

from tests.conftest import ROOT
from wtml.data import DatasetError, generate, load_shards, read_manifest
from wtml.data.datamodule import ShardDataModule, check_tensors
from wtml.data.shards import NAN_BY_DESIGN, check_finite
from wtml.files import sha256
from wtml.scenes import SCENES, FluidScene, SceneError, config_hash, scene_from_dict, to_dict
from wtml.schema import build

TINY = build(FluidScene, {"samples": 40, "shards": 4})
"""10 records per shard: train shards 0-1, validation 2, test 3."""
OTHER = build(FluidScene, {"samples": 40, "shards": 4, "seed": 1})


@pytest.fixture(scope="module")
def made(tmp_path_factory):
    out = tmp_path_factory.mktemp("made") / "ds"
    generate(TINY, out, progress=False)
    return out


@pytest.fixture
def ds(made, tmp_path):
    """A fresh copy of the tiny dataset, to damage."""
    return shutil.copytree(made, tmp_path / "ds")


def _refused(needles, call, *args, **kwargs):
    """``call(*args, **kwargs)`` raises a one-line DatasetError holding every needle."""
    with pytest.raises(DatasetError) as err:
        call(*args, **kwargs)
    message = str(err.value)
    assert "\n" not in message, message
    for needle in needles:
        assert needle in message, message
    return message


def _edit_manifest(ds, edit):
    path = ds / "manifest.json"
    m = json.loads(path.read_text())
    new = edit(m)  # edits change m in place; the one that returns a value replaces it
    path.write_text(json.dumps(m if new is None else new))


def _rewrite_shard(ds, k, edit):
    """Rewrite shard ``k`` with ``edit(arrays)`` applied, its manifest entry (sha256, arrays)
    made to match: only the checks of the contents can refuse it."""
    npz = ds / f"shard-{k:05d}.npz"
    with np.load(npz) as data:
        arrays = {key: data[key] for key in data.files}
    arrays = edit(arrays) or arrays
    np.savez(npz, **arrays)

    def fix(m):
        m["shards"][k]["sha256"] = sha256(npz)
    _edit_manifest(ds, fix)


def _set(key, value):
    def edit(m):
        m[key] = value
    return edit


def _set_entry(pos, key, value):
    def edit(m):
        m["shards"][pos][key] = value
    return edit


def _index(pos, k):
    """Entry ``pos`` made shard ``k``'s, its file name too."""
    def edit(m):
        m["shards"][pos].update(index=k, file=f"shard-{k:05d}.npz")
    return edit


def _drop(pos, key):
    def edit(m):
        del m["shards"][pos][key]
    return edit


def test_a_sound_dataset_loads(ds):
    assert load_shards(ds)["eta"].shape == (40,)
    m = read_manifest(ds)
    names = [a["name"] for a in m["shards"][0]["arrays"]]
    assert {"ze", "t", "eta", "rho"} <= set(names)
    ze = next(a for a in m["shards"][0]["arrays"] if a["name"] == "ze")
    assert ze == {"name": "ze", "dtype": "<c16", "shape": [31]}
    assert all(e["scene_hash"] == config_hash(TINY) for e in m["shards"])
    who = json.loads((ds / "scene.json").read_text())
    assert who["scene_hash"] == config_hash(TINY) and who["n_shards"] == 4


@pytest.mark.parametrize(("edit", "needles"), [
    (lambda m: [m], ["manifest.json: must be a JSON object", "got list"]),
    (_set("n_shards", None), ["manifest.json: n_shards: must be a number", "None"]),
    (_set("samples", "40"), ["manifest.json: samples: must be a number", "'40'"]),
    (_set("n_shards", 1e9), ["manifest.json: n_shards: must be in [1, 100000]"]),
    (_set("n_shards", 10**400), ["manifest.json: n_shards: must be in [1, 100000]"]),
    (_set("complete", "yes"), ["manifest.json: complete: must be true or false"]),
    (lambda m: m.__delitem__("scene"), ["manifest.json: scene: missing"]),
    (_set("scene", "fluid"), ["manifest.json: scene: must be a mapping"]),
    (_set("scene", [1, 2]), ["manifest.json: scene: must be a mapping"]),
    (lambda m: m["scene"].update(task="nope"), ["manifest.json: scene.task: must be one of"]),
    (lambda m: m["scene"].update(task=[1]), ["manifest.json: scene.task: must be one of"]),
    (lambda m: m["scene"].update(samples=-3), ["manifest.json: scene.samples: must be in"]),
    (lambda m: m["scene"].update(noise=None), ["manifest.json: scene.noise: must be a mapping"]),
    (lambda m: m["scene"].update(seed=5), ["manifest.json: scene_hash:", "not the hash"]),
    (_set("scene_hash", "ab" * 32), ["manifest.json: shards[0].scene_hash:", "another scene"]),
    (lambda m: [e.update(scene_hash="ab" * 32) for e in [m, *m["shards"]]] and None,
     ["manifest.json: scene_hash: abababababab… is not the hash of its scene"]),
    (_set("scene_hash", None), ["manifest.json: scene_hash: must be a string"]),
    (_set("format", "wtml.dataset/1"), ["manifest.json: format:", "older wtml",
                                        "generate it again"]),
    (_set("format", "zip"), ["manifest.json: format: must be one of ['wtml.dataset/3']"]),
    (_set("shards", None), ["manifest.json: shards: must be a list of mappings"]),
    (_set("shards", {"0": {}}), ["manifest.json: shards: must be a list of mappings"]),
    (lambda m: m["shards"].__setitem__(1, None),
     ["manifest.json: shards[1]: must be a mapping"]),
    (_drop(1, "file"), ["manifest.json: shards[1].file: missing"]),
    (_drop(0, "arrays"), ["manifest.json: shards[0].arrays: missing"]),
    (_set_entry(0, "file", "../../x.npz"),
     ["manifest.json: shards[0].file: must be 'shard-00000.npz'", "'../../x.npz'"]),
    (_set_entry(0, "file", "/etc/passwd"),
     ["manifest.json: shards[0].file: must be 'shard-00000.npz'", "'/etc/passwd'"]),
    (_set_entry(2, "file", "shard-00003.npz"), ["manifest.json: shards[2].file: must be"]),
    (_set_entry(0, "count", "10"), ["manifest.json: shards[0].count: must be a number"]),
    (_set_entry(0, "count", 0), ["manifest.json: shards[0].count: must be in [1, "]),
    (_set_entry(0, "count", 11), ["manifest.json: shards[0].count: shard 0", "holds 10, got 11"]),
    (_set_entry(1, "index", 0), ["manifest.json: shards[1].file: must be 'shard-00000.npz'"]),
    (_index(1, 0), ["manifest.json: shards[1].index: shard 0 is listed twice"]),
    (_index(3, 2), ["manifest.json: shards[3].index: shard 2 is listed twice",
                    "also shards[2]"]),  # the test shard would be read as shard 2
    (_index(3, 7), ["manifest.json: shards[3].index: must be in [0, 3]"]),
    (_set_entry(0, "index", -1), ["manifest.json: shards[0].index: must be in [0, "]),
    (_set_entry(0, "sha256", "0"), ["manifest.json: shards[0].sha256: must be 64"]),
    (_set_entry(2, "scene_hash", "ab" * 32), ["manifest.json: shards[2].scene_hash:",
                                              "another scene"]),
    (_set_entry(1, "arrays", []), ["manifest.json: shards[1].arrays: must list"]),
    (lambda m: m["shards"].append(dict(m["shards"][0])),
     ["manifest.json: shards: 5 entries for 4 shards"]),
    (lambda m: m["shards"].__delitem__(3), ["manifest.json: complete: true, but 3 of 4"]),
    (lambda m: m["shards"][0]["arrays"][0].update(dtype="|O"),
     ["manifest.json: shards[0].arrays[0].dtype: must be one of"]),
    (lambda m: m["shards"][0]["arrays"][0].update(shape=[-1]),
     ["manifest.json: shards[0].arrays[0].shape[0]: must be in"]),
    (lambda m: m["shards"][0]["arrays"][0].update(shape="31"),
     ["manifest.json: shards[0].arrays[0].shape: must be a list of whole numbers"]),
    (lambda m: m["shards"][1]["arrays"].__delitem__(0),
     ["manifest.json: shards[1].arrays: differ from shards[0].arrays"]),
    (lambda m: [e.update(arrays=[a for a in e["arrays"] if a["name"] != "eta"])
                for e in m["shards"]] and None,
     ["manifest.json: shards[0].arrays: no 'eta' array", "fluid dataset"]),
    (lambda m: [e["arrays"][0].update(shape=[30]) for e in m["shards"]] and None,
     ["manifest.json: shards[0].arrays: 't' has F = 31 but 'ze' has F = 30"]),
])
def test_crafted_manifests_are_refused_in_one_line(ds, edit, needles):
    _edit_manifest(ds, edit)
    start = time.perf_counter()
    _refused(needles, load_shards, ds)
    _refused(needles, ShardDataModule, str(ds))
    assert time.perf_counter() - start < 5  # n_shards: 1e9 neither allocates nor loops


@pytest.mark.parametrize(("text", "needle"), [
    ('{"format": ', "manifest.json: not valid JSON"),
    ('{"format": "wtml.dataset/2", "format": "x"}', "key 'format' appears twice"),
    ('{"n_shards": NaN}', "NaN is not a JSON number"),
    ("", "manifest.json: not valid JSON"),
])
def test_unreadable_manifests_are_refused(ds, text, needle):
    (ds / "manifest.json").write_text(text)
    _refused([needle], load_shards, ds)


def test_a_missing_or_foreign_scene_json_is_refused(ds):
    other = json.loads((ds / "scene.json").read_text()) | {"scene_hash": config_hash(OTHER)}
    (ds / "scene.json").write_text(json.dumps(other))
    _refused(["manifest.json", "scene.json says", "mixed"], load_shards, ds)
    (ds / "scene.json").write_text(json.dumps(other | {"n_shards": "4"}))
    _refused(["scene.json: n_shards: must be a number"], load_shards, ds)
    (ds / "scene.json").unlink()
    _refused(["no scene.json", "generate it again"], load_shards, ds)


@pytest.mark.parametrize(("edit", "needles"), [
    (lambda a: {k: v for k, v in a.items() if k != "rho"},
     ["shard-00001.npz: key 'rho' is missing"]),
    (lambda a: a.update(ze=a["ze"][:, :30]),
     ["shard-00001.npz: key 'ze' is <c16 (10, 30); the manifest says <c16 (10, 31)"]),
    (lambda a: a.update(eta=a["eta"].astype(np.float32)),
     ["shard-00001.npz: key 'eta' is <f4 (10,); the manifest says <f8 (10,)"]),
    (lambda a: a.update(eta=a["eta"][:0]), ["shard-00001.npz: key 'eta' is <f8 (0,)"]),
    (lambda a: {k: v[:0] for k, v in a.items()}, ["shard-00001.npz: key 'ze' is <c16 (0, 31)"]),
    (lambda a: a.update(extra=np.zeros(10)), ["shard-00001.npz: key 'extra' is not in the"]),
    (lambda a: a.update(ze=np.array([None] * 10)), ["shard-00001.npz: key 'ze' holds Python "
                                                    "objects"]),
])
def test_shards_whose_arrays_differ_from_the_manifest_are_refused(ds, edit, needles):
    _rewrite_shard(ds, 1, edit)
    _refused(needles, load_shards, ds)


def test_non_finite_training_data_is_refused_naming_shard_key_and_row(ds):
    def nan_row_3(a):
        a["ze"][3, 7] = np.nan
    _rewrite_shard(ds, 1, nan_row_3)  # a training shard
    _refused(["shard-00001.npz: 'ze' is NaN or inf in row 3"], load_shards, ds)
    dm = ShardDataModule(str(ds), batch_size=8)  # the manifest is sound: the values are not
    _refused(["shard-00001.npz: 'ze' is NaN or inf in row 3"], dm.train_tensors)
    assert len(dm.test_dataloader().dataset) == 10  # the other splits are fine


@pytest.mark.parametrize(("key", "value", "row", "needle"), [
    ("ze", 1e300, 0, "'ze' gives a NaN or inf training value in row 0"),  # beyond float32
    ("t", 1e39, 9, "'t' gives a NaN or inf training value in row 9"),
])
def test_values_that_overflow_the_training_tensors_are_refused(ds, key, value, row, needle):
    def edit(a):
        a[key][row] = value
    _rewrite_shard(ds, 1, edit)
    assert np.all(load_shards(ds, [1])[key][row] == value)  # finite in the shard itself
    dm = ShardDataModule(str(ds), batch_size=8)
    _refused([f"shard-00001.npz: {needle}"], dm.train_tensors)


@pytest.mark.parametrize(("key", "value", "row"), [("eta", -1.0, 4), ("rho", 1e39, 9),
                                                  ("eta", 0.0, 0)])
def test_labels_outside_the_scene_range_are_refused(ds, key, value, row):
    """A label the scene cannot have drawn (a negative or zero viscosity, whose log is not a
    number; a density beyond float32) is refused when its shard loads, naming key and row."""
    def edit(a):
        a[key][row] = value
    _rewrite_shard(ds, 1, edit)
    _refused([f"shard-00001.npz: '{key}' is {value:.6g} in row {row}", "outside the scene's"],
             load_shards, ds, [1])


def test_a_zero_impedance_is_refused(ds):
    """Ze of 0 Ω at one frequency (a bimorph is a capacitor in every load): refused naming the
    key and the row, before any ratio or inversion divides by it."""
    def edit(a):
        a["ze"][7, 2] = 0
    _rewrite_shard(ds, 1, edit)
    _refused(["shard-00001.npz: 'ze' is 0 Ω in row 7"], load_shards, ds, [1])


def test_the_nan_that_onset_records_hold_by_design(rng):
    """Onset's ``gap`` (no wall), ``onset`` and ``detachment`` (padded) and ``law_delta_ref``
    (the linear law) may be NaN, never inf; every other array of every task must be finite."""
    assert NAN_BY_DESIGN == {"onset": ("gap", "onset", "detachment", "law_delta_ref")}
    n, c = 6, 3
    arrays = {"e": rng.standard_normal((n, 16)).astype(np.float32),
              "gap": np.array([1e-4, np.nan, 2e-4, np.nan, 1e-4, 3e-4]),
              "onset": np.full((n, c), np.nan), "detachment": np.full((n, c), np.nan),
              "coupling": np.ones(n)}
    check_finite("s.npz", arrays, "onset")
    arrays["onset"][5, 1] = np.inf
    _refused(["s.npz: 'onset' is inf in row 5", "NaN by design"], check_finite, "s.npz",
             arrays, "onset")
    arrays["onset"][5, 1] = np.nan
    arrays["coupling"][2] = np.nan
    _refused(["s.npz: 'coupling' is NaN or inf in row 2"], check_finite, "s.npz", arrays,
             "onset")
    _refused(["s.npz: 'gap' is NaN or inf in row 1"], check_finite, "s.npz",
             {"gap": arrays["gap"]}, "texture")
    # the training tensors: e, i, t_re, t_im, hue0, targets (gap, onsets, detachments, coupling)
    x = torch.zeros(n, 16)
    y = torch.tensor(np.column_stack([arrays["gap"], arrays["onset"], arrays["detachment"],
                                      np.ones(n)]), dtype=torch.float32)
    where = [("a.npz", 4), ("b.npz", 2)]
    check_tensors((x, x, x, x, torch.ones(n), y), "onset", where)
    y[5, 0] = float("inf")
    _refused(["b.npz: 'gap' gives a NaN or inf training value in row 1"], check_tensors,
             (x, x, x, x, torch.ones(n), y), "onset", where)
    y[5, 0], y[4, -1] = float("nan"), float("nan")
    _refused(["b.npz: 'coupling' gives"], check_tensors, (x, x, x, x, torch.ones(n), y),
             "onset", where)


def _python(code, timeout=60):
    return subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True,
                          text=True, timeout=timeout)


@pytest.mark.parametrize("kind", ["fifo", "dev_zero", "folder", "sparse_3gb"])
def test_a_shard_that_is_not_a_small_regular_file_is_refused_without_reading(ds, kind):
    """A FIFO (which would block an open), /dev/zero (endless) or a folder as a shard: refused
    from its file type, never opened; a shard over the 2 GiB ceiling from its size. Run in a
    child process with a timeout, so that a hang fails the test instead of stalling it."""
    shard = ds / "shard-00002.npz"
    shard.unlink()
    if kind == "fifo":
        os.mkfifo(shard)
    elif kind == "dev_zero":
        shard.symlink_to("/dev/zero")
    elif kind == "folder":
        shard.mkdir()
    else:
        with open(shard, "wb") as fh:
            fh.truncate(3 * 1024**3)  # sparse: no disk used
    done = _python(f"from wtml.data import load_shards\nload_shards({str(ds)!r})")
    last = done.stderr.strip().splitlines()[-1]
    assert "DatasetError" in last and "shard-00002.npz" in last, done.stderr
    assert ("not a regular file" if kind in ("fifo", "dev_zero") else
            "is a folder" if kind == "folder" else "over the 2.15 GB") in last
    if kind != "sparse_3gb":  # and generation makes it again, never reading it
        done = _python("from tests.test_dataset_files import TINY\nfrom wtml.data import "
                       f"generate\ngenerate(TINY, {str(ds)!r}, progress=False)")
        if kind == "folder":  # a folder is not replaced: one line saying so
            last = done.stderr.strip().splitlines()[-1]
            assert "DatasetError" in last and "shard-00002.npz: is a folder" in last
        else:
            assert done.returncode == 0, done.stderr
            assert load_shards(ds)["eta"].shape == (40,)


def test_generate_refuses_a_folder_of_another_scene_after_a_killed_run(tmp_path):
    """A first run killed before its manifest (its shards and sidecars there, or one shard
    only): a second scene is refused, naming the first; the first scene completes."""
    out = tmp_path / "ds"
    generate(TINY, out, progress=False)
    (out / "manifest.json").unlink()  # killed before the manifest
    mine, theirs = config_hash(TINY)[:12], config_hash(OTHER)[:12]
    _refused([f"{out}: holds shards of another scene, {mine}…", f"this one is {theirs}…",
              "choose another --out"], generate, OTHER, out, progress=False)
    generate(TINY, out, progress=False)  # the same scene goes on
    assert read_manifest(out)["complete"]
    one = tmp_path / "one"
    generate(TINY, one, shard=2, progress=False)  # only shard 2 made, then killed
    _refused(["holds shards of another scene", "choose another --out"], generate, OTHER, one,
             shard=0, progress=False)
    _refused(["holds this scene in 4 shards, not 5", "--shards 4"], generate, TINY, one,
             shards=5, progress=False)
    assert sorted(p.name for p in one.iterdir() if p.suffix == ".npz") == ["shard-00002.npz"]


def test_generate_refuses_foreign_or_older_files(tmp_path, made):
    """Shards without scene.json (an older wtml's, or copied in), an older manifest, or a
    sidecar of another scene in a folder: refused, nothing overwritten."""
    old = shutil.copytree(made, tmp_path / "old")
    (old / "scene.json").unlink()
    _refused([f"{old}: holds dataset files of an unknown scene (manifest.json, 9 in all",
              "choose another --out"], generate, TINY, old, progress=False)
    (old / "manifest.json").unlink()
    _refused(["holds dataset files of an unknown scene (shard-00000.json, 8 in all"],
             generate, OTHER, old, progress=False)
    older = shutil.copytree(made, tmp_path / "older")
    _edit_manifest(older, _set("format", "wtml.dataset/1"))
    _refused(["holds a dataset of an older wtml", "choose another --out"], generate, TINY,
             older, progress=False)
    mixed = shutil.copytree(made, tmp_path / "mixed")
    generate(OTHER, tmp_path / "other", progress=False)
    shutil.copy(tmp_path / "other/shard-00001.json", mixed / "shard-00001.json")
    _refused(["shard-00001.json: a shard of another scene"], generate, TINY, mixed,
             progress=False)


_WRITER = """
import os, sys, time
from wtml.cli import main
open(sys.argv[1] + ".ready", "w").close()
while not os.path.exists(sys.argv[2]):
    time.sleep(0.001)
sys.exit(main(["generate", "--quiet", "--config", sys.argv[3], "--out", sys.argv[4],
               *sys.argv[5:]]))
"""


def _race(tmp_path, jobs):
    """Start one ``wtml generate`` per job (scene, extra args), all into ``tmp_path/ds``,
    released at once; returns each one's exit code and stderr."""
    go = tmp_path / "go"
    procs = []
    for n, (scene, extra) in enumerate(jobs):
        yaml = tmp_path / f"scene{n}.yaml"
        yaml.write_text(json.dumps(to_dict(scene)))  # JSON is YAML
        procs.append(subprocess.Popen(
            [sys.executable, "-c", _WRITER, str(tmp_path / f"w{n}"), str(go), str(yaml),
             str(tmp_path / "ds"), *extra], cwd=ROOT, stderr=subprocess.PIPE, text=True))
    deadline = time.monotonic() + 60
    while not all((tmp_path / f"w{n}.ready").exists() for n in range(len(jobs))):
        assert time.monotonic() < deadline
        time.sleep(0.01)
    go.touch()
    errors = [p.communicate(timeout=60)[1] for p in procs]
    return [(p.returncode, err) for p, err in zip(procs, errors, strict=True)]


def test_two_scenes_generated_into_one_folder_at_once(tmp_path):
    """Whoever comes first owns the folder; the other is refused in one line, and the folder
    holds only the first's shards."""
    (a_code, a_err), (b_code, b_err) = _race(tmp_path, [(TINY, []), (OTHER, [])])
    assert sorted([a_code, b_code]) == [0, 2], (a_err, b_err)
    winner, loser_err = (TINY, b_err) if a_code == 0 else (OTHER, a_err)
    assert loser_err.count("\n") == 1 and "holds shards of another scene" in loser_err
    assert f"{config_hash(winner)[:12]}…" in loser_err
    m = read_manifest(tmp_path / "ds")
    assert m["scene_hash"] == config_hash(winner)
    assert all(e["scene_hash"] == config_hash(winner) for e in m["shards"])
    assert len(load_shards(tmp_path / "ds")["eta"]) == 40


def test_parallel_shard_jobs_of_one_scene_share_a_folder(tmp_path, made):
    results = _race(tmp_path, [(TINY, ["--shard", str(k)]) for k in range(4)])
    assert all(code == 0 for code, _ in results), results
    m = generate(TINY, tmp_path / "ds", progress=False)  # completes and verifies
    assert [e["sha256"] for e in m["shards"]] == [e["sha256"] for e in read_manifest(made)[
        "shards"]]


def test_generate_bounds_its_shard_count(tmp_path):
    for shards, needle in ((0, "--shards: must be a whole number in [1, 40]"),
                           (41, "in [1, 40] (at most the sample count, 40"),
                           (True, "got True")):
        _refused([needle], generate, TINY, tmp_path / "x", shards=shards, progress=False)


@given(st.dictionaries(st.sampled_from(["task", "samples", "shards", "seed", "noise",
                                        "excitation", "fluids", "device", "x"]),
                       st.none() | st.booleans() | st.integers() | st.floats()
                       | st.text(max_size=5) | st.lists(st.integers(), max_size=2)
                       | st.dictionaries(st.text(max_size=3), st.integers(), max_size=2),
                       max_size=4),
       st.sampled_from(sorted(SCENES)))
def test_scene_from_dict_refuses_any_crafted_mapping_in_one_line(changes, task):
    """A manifest's ``scene`` mutated anyhow: a scene, or a SceneError naming the key."""
    data = to_dict(SCENES[task]()) | changes
    try:
        scene_from_dict(data, "scene")
    except SceneError as err:
        assert "\n" not in str(err) and str(err).startswith("scene")


@pytest.mark.parametrize("data", [None, [], "fluid", 3, [("task", "fluid")]])
def test_scene_from_dict_refuses_what_is_not_a_mapping(data):
    with pytest.raises(SceneError, match=r"^scene: must be a mapping"):
        scene_from_dict(data, "scene")


def test_training_on_a_nan_shard_stops_before_the_first_step(ds, tmp_path, capsys):
    """The issue's probe: a NaN in a training shard trained to a NaN checkpoint and exited 0.
    Now ``train.py fit`` ends with one line naming the shard, the key and the row, and writes
    no checkpoint."""
    from wtml.training import cli_main

    def nan(a):
        a["t"][6, 0, 1, 1] = np.nan
    _rewrite_shard(ds, 0, nan)
    with pytest.raises(SystemExit) as done:
        cli_main(["fit", "--config", str(ROOT / "configs/fluid.yaml"),
                  "--data.init_args.data_dir", str(ds), "--data.init_args.batch_size", "8",
                  "--trainer.max_epochs", "1", "--trainer.default_root_dir",
                  str(tmp_path / "run")])
    assert done.value.code == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "shard-00000.npz: 't' is NaN or inf in row 6" in err, err
    assert not list(tmp_path.glob("run/**/*.ckpt"))


@pytest.mark.parametrize("name", ["onset", "texture"])
def test_record_scenes_make_the_arrays_their_task_needs(tmp_path, name):
    """The shipped record scenes, 3 records in 3 shards: every array ``TASK_ARRAYS`` names is
    there with its kind and shape, and the split loads (onset's labels NaN where by design)."""
    from wtml.data.shards import TASK_ARRAYS
    from wtml.scenes import load_scene

    scene = load_scene(ROOT / f"configs/scenes/{name}.yaml")
    small = build(type(scene), to_dict(scene) | {"samples": 3, "shards": 3})
    generate(small, tmp_path, progress=False)
    arrays = {a["name"]: a for a in read_manifest(tmp_path)["shards"][0]["arrays"]}
    for key, (kind, shape) in TASK_ARRAYS[name].items():
        assert np.dtype(arrays[key]["dtype"]).kind == kind
        assert len(arrays[key]["shape"]) == len(shape)
    *inputs, targets = ShardDataModule(str(tmp_path), batch_size=1).train_tensors()
    assert len(targets) == 1 and all(len(x) == 1 for x in inputs)
