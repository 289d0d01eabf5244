"""The onset slice: labels, the step's effect, the thesis pipeline's cross-check, the timing
rule, and the exported graphs (ONNX against torch, the streaming graph chunk by chunk against
the offline one, records read on a device)."""

import dataclasses
import json
import subprocess
import sys
import warnings

import numpy as np
import pytest
import torch
from hypothesis import example, given
from hypothesis import strategies as st

from tests.conftest import ONSET_SMALL, ROOT
from wtml.decoders.onset import MOTION_LIMIT, TOUCH_LOOKBACK, asinh, touch_spread
from wtml.exporters.onset import calibration_file, record_inputs, thesis_pipeline
from wtml.physics.spread import DeviceSpread
from wtml.runtime.contacts import Timing, contacts_from, intervals
from wtml.runtime.onset import (
    combine_pieces,
    cut_pieces,
    pieces_spread,
    predict_records,
    stream_record,
)
from wtml.runtime.predict import InputError, OnnxModel
from wtml.runtime.recordings import read_record
from wtml.scenes import load_scene

SMALL = ONSET_SMALL


@pytest.fixture(scope="module")
def spread_scene():
    """The shipped scene, small: every record's device drawn from its spread."""
    return dataclasses.replace(load_scene(ROOT / "configs/scenes/onset.yaml"), **SMALL)


@pytest.fixture(scope="module")
def scene(spread_scene):
    """The shipped scene on the nominal device (the preset alone)."""
    return dataclasses.replace(spread_scene, spread=DeviceSpread())


def tensors(rec: dict) -> list[torch.Tensor]:
    """A graph's inputs (e, i and the records' calibration) as tensors."""
    return [torch.tensor(x) for x in record_inputs(rec)]


@given(st.floats(allow_nan=False, allow_infinity=False, width=32))
@example(3.630511346273124e-4)  # log(a + sqrt(a² + 1)) alone was 1.25e-7 off here
@example(0.0999999940395)  # the series' edge
@example(0.1)
@example(-0.0)  # the slope at 0
def test_the_exported_asinh_is_torchs(x):
    """The decoder's asinh (a series and log and sqrt, which the exporter has) against
    torch's, float32, value and slope, over the whole float32 range: near 0, and beyond where
    x² overflows (clipped at 1e18)."""
    t = torch.tensor([x], dtype=torch.float32)
    want = torch.asinh(t.clamp(-1e18, 1e18))
    assert torch.allclose(asinh(t), want, rtol=1e-6, atol=1.2e-7)
    t.requires_grad_(True)
    asinh(t).backward()
    assert torch.allclose(t.grad, 1 / torch.sqrt(1 + t.detach().double() ** 2).float()
                          if abs(x) < 1e18 else torch.zeros(1), rtol=1e-5)


def test_intervals_merge_touches_on_successive_probe_peaks():
    rate = 1000.0
    active = np.zeros((2, 100), bool)
    active[0, 10:12] = active[0, 14:16] = active[0, 40:50] = True  # gap 2 samples, then 24
    active[1, 90:] = True  # still touching at the end
    on, off = intervals(active, rate, merge_s=0.003, max_count=3)
    np.testing.assert_allclose(on[0, :2], [0.010, 0.040])
    np.testing.assert_allclose(off[0, :2], [0.016, 0.050])
    assert np.isnan(on[0, 2]) and on[1, 0] == 0.090 and np.isnan(off[1, 0])


def test_each_whisk_touches_once_near_where_the_whisking_position_reaches_the_wall(scene):
    """Two whisk cycles, two contacts, each starting on the first probe peak that reaches the
    wall: when the whisking position u_L = HUE(0) e_L is up to the probe's amplitude (0.224 µm
    at 420 Hz) short of g, and at most one probe period's whisking (0.11 µm) less (§10)."""
    exact = dataclasses.replace(scene, calibration_error=0.0)
    amp = exact.whisk_amplitude_m()
    gaps = np.array([0.3, 0.7]) * amp
    rec = exact.simulate(2, np.random.default_rng(0), gaps=gaps)
    t_reach = np.arccos(-gaps / amp) / (2 * np.pi)  # u_L = -amp cos(2π t) = g
    for r in range(2):
        on, off = rec["onset"][r], rec["detachment"][r]
        assert np.sum(np.isfinite(on)) == 2 and np.all(off[:2] > on[:2])
        lead = t_reach[r] - on[0]  # how much earlier than u_L reaches g
        speed = 2 * np.pi * np.sqrt(amp**2 - gaps[r] ** 2)  # whisking speed there, m/s
        assert 0.224e-6 - speed / 420 - 0.01e-6 < lead * speed < 0.23e-6, lead * speed
        assert abs(on[1] - on[0] - 1.0) < 2e-3  # the second whisk repeats the first


def test_halving_the_step_moves_the_onsets_by_less_than_the_scene_allows(scene):
    """The onset and detachment times at twice the sampling rate move by less than 2 coarse
    steps (75 µs: 6 nm of whisking at most, below the scene's 1 % calibration error)."""
    fine = dataclasses.replace(scene, acquisition=dataclasses.replace(
        scene.acquisition, sample_rate_hz=2 * scene.acquisition.sample_rate_hz))
    gaps = np.array([0.5]) * scene.whisk_amplitude_m()
    a = scene.simulate(1, np.random.default_rng(1), gaps=gaps)
    b = fine.simulate(1, np.random.default_rng(1), gaps=gaps)
    for key in ("onset", "detachment"):
        ok = np.isfinite(a[key])
        assert np.array_equal(ok, np.isfinite(b[key]))
        assert np.max(np.abs(a[key][ok] - b[key][ok])) < 2 / scene.acquisition.sample_rate_hz


def test_thesis_pipeline_lands_just_beyond_the_wall_without_noise(scene):
    """physics.md §10's independent cross-check: the thesis pipeline locates the wall 0.25 to
    0.77 µm beyond it (k_c = 5 N/m, no noise, no calibration error)."""
    quiet = dataclasses.replace(
        scene, calibration_error=0.0,
        acquisition=dataclasses.replace(scene.acquisition, e_noise_v=0.0, i_noise_a=0.0),
        wall=dataclasses.replace(scene.wall, stiffness=(5.0, 5.0)))
    amp = quiet.whisk_amplitude_m()
    gaps = np.array([0.3, 0.6]) * amp
    rec = quiet.simulate(2, np.random.default_rng(2), gaps=gaps)
    with torch.no_grad():
        gap = thesis_pipeline(quiet)(*tensors(rec))[0].numpy()
    beyond = gap - gaps
    assert np.all((beyond > 0.1e-6) & (beyond < 1.0e-6)), beyond


def test_exported_graphs_match_torch(onset_export, spread_scene):
    """ONNX against torch on records of devices drawn from the spread, each record through
    its own device's calibration (the graphs' inputs t_re, t_im, hue0)."""
    from wtml.decoders.checkpoint import load_decoder
    from wtml.decoders.domain import Gated

    scene = spread_scene
    module = load_decoder(onset_export["run"] / "checkpoints/last.ckpt")
    rec = scene.simulate(3, np.random.default_rng(5))
    assert len({complex(t) for t in rec["t_probe"][:, 0, 1]}) == 3  # three devices
    x = record_inputs(rec)
    model = OnnxModel(onset_export["model"] / "model.onnx")
    limit = model.meta.domain.self_check_limit
    assert limit > 0
    with torch.no_grad():
        ref = Gated(module.net, module.gate, (1,), checks=(MOTION_LIMIT, limit)).eval()(
            *tensors(rec))
        ref_cl = thesis_pipeline(scene)(*tensors(rec))
    dec = model.run(*x)
    cl = OnnxModel(onset_export["model"] / "classical.onnx").run(*x)
    np.testing.assert_allclose(dec["gap"], ref[0].numpy(), rtol=1e-4, atol=1e-10)
    np.testing.assert_allclose(dec["contact"], ref[2].numpy(), atol=1e-4)
    np.testing.assert_allclose(dec["detach_margin"], ref[3].numpy(),
                               atol=1e-4 * scene.whisk_amplitude_m())
    np.testing.assert_array_equal(dec["in_domain"], ref[-2].numpy())
    np.testing.assert_allclose(cl["gap"], ref_cl[0].numpy(), rtol=1e-4, atol=1e-10)
    assert np.mean(cl["contact"] == ref_cl[2].numpy()) > 0.9999


def test_streaming_graph_fed_chunks_gives_the_offline_answer(onset_export, scene):
    """stream.onnx, fed one probe period at a time with its state carried, gives the offline
    graph's contact probabilities frame by frame and, after the last chunk, its gap, sigma
    and domain score."""
    rec = scene.simulate(3, np.random.default_rng(7))
    model = OnnxModel(onset_export["model"] / "model.onnx")
    offline = model.run(*record_inputs(rec))
    offline |= model.half_widths(offline)
    stream = OnnxModel(onset_export["model"] / "stream.onnx")
    streamed = stream_record(stream, *record_inputs(rec))
    assert streamed["contact"].shape == offline["contact"].shape
    np.testing.assert_allclose(streamed["contact"], offline["contact"], atol=1e-5)
    np.testing.assert_allclose(streamed["gap"], offline["gap"], rtol=1e-5, atol=1e-12)
    np.testing.assert_allclose(streamed["sigma"], offline["sigma"], rtol=1e-4, atol=1e-12)
    np.testing.assert_allclose(streamed["sigma_95"], offline["sigma_95"], rtol=1e-4,
                               atol=1e-12)
    # the record summary's sums run over chunks in another order than the offline mean:
    # float32 rounding (RESOLUTION) whitened, a few parts in 1e3 of the score
    np.testing.assert_allclose(streamed["domain_score"], offline["domain_score"], rtol=1e-2,
                               atol=1e-3)
    np.testing.assert_array_equal(streamed["in_domain"], offline["in_domain"])
    with pytest.raises(InputError, match="do not split into chunks"):
        stream_record(stream, rec["e"][:, :-1], rec["i"][:, :-1], *record_inputs(rec)[2:])


def test_wtml_stream_answers_a_longer_stream_record_by_record(onset_export, scene, tmp_path):
    """``wtml stream``'s loop over a stream of two records (four whisk cycles, one device):
    each record's answer is the offline graph's on that record alone (the state starts
    afresh at its first sample: a state carried on would sum the first record's frames into
    the second's score), and the second is judged with the first as two pieces of one
    recording are (combine_pieces, the export's limit); the first, held by default, takes
    that verdict too."""
    import io

    from wtml.exporters.onset import twice_as_long
    from wtml.runtime.stream import run_stream

    rec = twice_as_long(scene).simulate(1, np.random.default_rng(8), gaps=[5e-6])
    x, _ = cut_pieces(np.stack([rec["e"], rec["i"]]), scene.n_samples, "test",
                      scene.acquisition.sample_rate_hz)
    model = OnnxModel(onset_export["model"] / "model.onnx")
    offline = model.run(*x.astype(np.float32), *(np.repeat(c, 2, 0)
                                                 for c in record_inputs(rec)[2:]))
    cal = calibration_file(tmp_path / "cal.npz", scene, rec)
    pairs = np.stack([rec["e"][0], rec["i"][0]], -1).astype("<f4").tobytes()
    got = run_stream(onset_export["model"], io.BytesIO(pairs), cal, first_alone=True)
    assert [r.number for r in got.records] == [0, 1] and not got.stopped
    np.testing.assert_allclose([r.domain_score for r in got.records], offline["domain_score"],
                               rtol=1e-2, atol=1e-3)
    np.testing.assert_allclose([r.gap_m for r in got.records], offline["gap"], rtol=1e-5,
                               atol=1e-12)
    np.testing.assert_allclose([r.sigma_m for r in got.records], offline["sigma"], rtol=1e-4,
                               atol=1e-12)
    pair = combine_pieces(offline, 2, model.meta.domain.pieces_limit)
    assert [r.in_domain for r in got.records] == [offline["in_domain"][0], pair["in_domain"][0]]
    assert got.records[1].apart == pair["pieces_apart"][0]
    np.testing.assert_allclose(got.records[1].apart_sigma, pair["pieces_spread"][0], rtol=1e-3)
    assert got.records[1].end_s == pytest.approx(2 * scene.n_samples
                                                 / scene.acquisition.sample_rate_hz)
    # by default the first record is held and judged with the second: the pair's verdict
    held = run_stream(onset_export["model"], io.BytesIO(pairs), cal).records
    np.testing.assert_array_equal([r.gap_m for r in held], [r.gap_m for r in got.records])
    assert held[0].in_domain == held[1].in_domain == pair["in_domain"][0]
    assert held[0].apart == pair["pieces_apart"][0]
    assert held[0].decided_s == held[1].end_s


def test_the_looks_agreement_is_their_weighted_distance_from_each_sides_mean_in_sigma():
    """touch_spread over four looks (two whisk cycles' approach and retreat): cycles met at
    g ± d give d/σ; cycles whose approach and retreat are swapped (each cycle's whole at g,
    which the cycles' wholes alone cannot see) give d/σ too; a bias shared by every approach
    and every retreat gives 0, as do one cycle holding the whole vote whatever the other's
    (empty) sums, and a record without a wall (NaN gap) whatever its looks."""
    g, sd, d, b = 5e-6, 0.2e-6, 0.3e-6, 7e-6
    quarter = [0.25] * 4
    looks = [  # (shares, locations), looks ordered: cycle 1 approach, retreat, cycle 2 ...
        (quarter, [g - d, g - d, g + d, g + d]),
        (quarter, [g + d, g - d, g - d, g + d]),
        (quarter, [g + b, g - b, g + b, g - b]),
        ([0.6, 0.4, 0.0, 0.0], [g + b, g - b, 0.0, 0.0]),
        (quarter, [g - d, g - d, g + d, g + d]),
    ]
    share = torch.tensor([w for w, _ in looks], dtype=torch.float64)
    sums = share * torch.tensor([x for _, x in looks], dtype=torch.float64)
    gap = torch.tensor([g, g, g, g, float("nan")], dtype=torch.float64)
    out = touch_spread(share, sums, gap, torch.full((5,), sd, dtype=torch.float64))
    np.testing.assert_allclose(out.numpy(), [d / sd, d / sd, 0.0, 0.0, 0.0], rtol=1e-9,
                               atol=1e-9)
    with pytest.raises(ValueError, match=r"touch_spread: .*\(5, 3\)"):  # the cycles' old layout
        touch_spread(share[:, :3], sums[:, :3], gap, torch.full((5,), sd))


def _oracle(onset_export, uniform: bool = False):
    """The fixture's checkpoint with an oracle's heads (its own 3 epochs find no wall): every
    frame's contact logit 20 and σ 0.1 µm; g's vote 30 on the frames in contact (|Zm| over
    2e-4 N·s/m; ~1.5e-3 on a wall), each estimating the frame's reach; or (``uniform``) the
    same vote on every frame, each estimating the reach, 1 µm more in contact. Returns the
    module (its ``net`` patched)."""
    from wtml.decoders.checkpoint import load_decoder
    from wtml.decoders.onset import OnsetNet

    module = load_decoder(onset_export["run"] / "checkpoints/last.ckpt")
    net = module.net

    def outputs(h, f, step, per_volt):
        p = OnsetNet.outputs(net, h, f, step, per_volt)
        touching = (f[..., 1:3].norm(dim=-1) > 2e-4).float()
        vote = torch.zeros_like(touching) if uniform else 30 * touching
        est = p["reach"] + 1e-6 * touching if uniform else p["reach"]
        log_sd = torch.full_like(touching, np.log(0.1e-6 / net.amp))
        return p | {"contact": torch.full_like(touching, 20.0), "vote": vote, "est": est,
                    "log_sd": log_sd}

    net.outputs = outputs
    return module


SPLICES = {"between cycles": (0, 0, 1, 1), "within cycles": (0, 1, 1, 0)}
"""Which of the two records (walls at 0.25 and 0.75 of the whisking amplitude) each quarter
of a spliced record comes from (:func:`_spliced`): its cycles' approaches and retreats."""


def _spliced(scene, quarters: tuple[int, ...] = SPLICES["between cycles"]
             ) -> tuple[list[torch.Tensor], list[torch.Tensor]]:
    """Two records of walls at 0.25 and 0.75 of the whisking amplitude (the nominal device, no
    calibration error), and one spliced from them by quarters of the record (the whisk's far
    end at t = 0, 1 and 2 s, its reach at its peak at 0.5 and 1.5 s, where both walls are in
    contact): quarter q from record ``quarters[q]``. Between cycles: its first cycle from the
    first wall, its second from the second; within cycles: each cycle's approach from one
    wall and retreat from the other, the second cycle the other way round."""
    exact = dataclasses.replace(scene, calibration_error=0.0)
    amp = exact.whisk_amplitude_m()
    rec = exact.simulate(2, np.random.default_rng(3), gaps=np.array([0.25, 0.75]) * amp)
    edges = [exact.n_samples * q // 4 for q in range(5)]
    x = [torch.tensor(y) for y in record_inputs(rec)]
    return x, [torch.cat([y[k:k + 1, a:b] for k, a, b in zip(quarters, edges[:-1], edges[1:],
                                                              strict=True)], 1)
               for y in x[:2]] + [y[:1] for y in x[2:]]


def _streamed(stream, inputs: list[torch.Tensor]) -> tuple[torch.Tensor, ...]:
    """The streaming graph's outputs after the record's last chunk (torch)."""
    state = stream.initial_state(len(inputs[0]))
    chunk, n = stream.chunk_samples, inputs[0].shape[1]
    assert n % chunk == 0
    with torch.no_grad():
        for k in range(0, n, chunk):
            out = stream(inputs[0][:, k:k + chunk], inputs[1][:, k:k + chunk], *inputs[2:], state)
            state = out[5]
    return out


def _onnx(graph, path, outputs: tuple[str, ...], inputs: tuple[str, ...], widths):
    """``graph`` written by the exporter's own :func:`export_graph`, as an onnxruntime
    session."""
    import onnxruntime as ort

    from wtml.exporters.graphs import export_graph

    export_graph(graph, widths[0], path, {"outputs": json.dumps(list(outputs))}, inputs, widths)
    return ort.InferenceSession(str(path), providers=["CPUExecutionProvider"])


def test_the_look_of_a_frame_counts_from_the_records_start(onset_export, scene):
    """Frames 0-419 are the first whisk cycle (420 probe periods of the 1 Hz whisk), 420-839
    the second; a cycle's first 210 frames are its approach (the tip's reach rises from its
    far end to its peak at the cycle's middle), the rest its retreat; a frame past the
    record's cycles is its last cycle's retreat."""
    module = _oracle(onset_export)
    assert (module.net.cycle_frames, module.net.cycles, module.net.looks) == (420, 2, 4)
    frames = [0.0, 209.0, 210.0, 419.0, 420.0, 629.0, 630.0, 839.0, 900.0]
    got = module.net.look_of(torch.tensor(frames))
    np.testing.assert_array_equal(got.argmax(-1).numpy(), [0, 0, 1, 1, 2, 2, 3, 3, 3])
    assert got.sum(-1).eq(1).all()
    # the reach of a record's frames peaks at each cycle's middle, where its looks change
    x, _ = _spliced(scene)
    with torch.no_grad():
        reach = module.net.reach(module.net.frames(*x), module.net.reach_per_volt(x[2], x[3]))
    assert set(reach[:, :420].argmax(-1).tolist()) <= {209, 210}
    assert set(reach[:, 420:].argmax(-1).tolist()) <= {209, 210}


def test_the_looks_keep_to_the_whisks_phase_when_its_cycle_is_not_whole_frames(scene, tmp_path):
    """A 1.6 Hz whisk under the 420 Hz probe: 262.5 probe periods a cycle. Each frame's look
    is where its middle falls in the whisk, over ten cycles: frame 2362 (its middle at
    2362.5, cycle 9's start) begins cycle 9; a cycle of 262 frames (the ratio rounded) would
    have begun it at frame 2358, four frames early, and kept drifting. Its ONNX graph agrees."""
    from wtml.decoders.onset import OnsetDecoder

    fast = dataclasses.replace(scene, drive=dataclasses.replace(scene.drive, whisk_hz=1.6,
                                                                cycles=10.0))
    net = OnsetDecoder()._make(fast, torch.stack([torch.zeros(5), torch.ones(5)]))
    assert (net.cycle_frames, net.cycles, net.looks) == (262.5, 10, 20)
    frames = torch.arange(2 * 2625, dtype=torch.float32)
    look = net.look_of(frames).argmax(-1)
    middle = (frames + 0.5) / 262.5  # whisk cycles at each frame's middle
    want = (2 * middle.floor() + (middle % 1 >= 0.5)).clamp(max=19)
    np.testing.assert_array_equal(look.numpy(), want.numpy())
    assert look[2361] == 17 and look[2362] == 18  # cycle 8's retreat, then cycle 9's approach
    assert look[2358] == 17  # not 18, as a cycle of 262 frames would say
    # every look of the ten cycles holds 131 or 132 frames (half of 262.5, on either side)
    counts = torch.bincount(look[:2625], minlength=20)
    assert set(counts.tolist()) <= {131, 132}
    # the graphs compute the same looks (the stream passes float frame indices, chunk by chunk)
    import onnxruntime as ort

    from wtml.exporters.graphs import OPSET

    class Looks(torch.nn.Module):
        def forward(self, start: torch.Tensor) -> torch.Tensor:
            return net.look_of(start + torch.arange(64, dtype=start.dtype)).argmax(-1)

    path = tmp_path / "looks.onnx"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the tracer's notes on the frozen arange
        torch.onnx.export(Looks(), (torch.zeros(2, 1),), str(path), input_names=["start"],
                          output_names=["look"], dynamo=False, opset_version=OPSET,
                          dynamic_axes={"start": {0: "batch"}, "look": {0: "batch"}})
    starts = torch.arange(0, 2625 + 64, 64, dtype=torch.float32)[:, None]
    got = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"]).run(
        None, {"start": starts.numpy()})[0]
    np.testing.assert_array_equal(got, Looks()(starts).numpy())
    np.testing.assert_array_equal(got.ravel()[:2625], want[:2625].numpy())


@pytest.mark.parametrize("splice", sorted(SPLICES))
def test_an_object_that_moves_between_looks_is_flagged(onset_export, scene, tmp_path, splice):
    """The spliced records (:func:`_spliced`) through the oracle's heads (votes on the frames
    in contact): the looks' spread is, by hand from the frames, each look's mean reach in
    contact from its side's (approach or retreat) over σ, and the graph flags the record, its
    domain score the spread over the limit (0.5) or, where larger, the wall's motion read from
    the cycles' currents over its limit (a spliced record's cycles meet two walls); the records
    it was spliced from stay near 0.
    Spliced within cycles, each cycle holds both walls, and the cycles' wholes alone (the
    check before the looks) read less than half the looks' spread; between cycles, as much.
    The streaming form, fed 56 frames at a time (the looks' edges, frames 210, 420 and 630,
    inside a chunk), ends on the same score, and so do both as ONNX graphs."""
    from wtml.decoders.domain import Gated
    from wtml.decoders.onset_stream import StreamingOnset
    from wtml.runtime.metadata import DECODER_OUTPUTS, ONSET_INPUTS, STREAM_INPUTS, STREAM_OUTPUTS

    module = _oracle(onset_export)
    net = module.net
    x, spliced = _spliced(scene, SPLICES[splice])
    graph = Gated(net, module.gate, (1,), checks=(MOTION_LIMIT, 0.5)).eval()
    stream = StreamingOnset(net, module.gate, 56, check_limit=0.5).eval()
    with torch.no_grad():
        whole, (motion, moved) = net(*x)[-1], net(*spliced)[-2:]
        gated = graph(*spliced)
        f = net.frames(*spliced)
        reach = net.reach(f, net.reach_per_volt(spliced[2], spliced[3]))[0].double()
    out = _streamed(stream, spliced)
    assert np.all(whole.numpy() < 0.1), whole
    touching = (f[0, :, 1:3].norm(dim=-1) > 2e-4).numpy()
    frame = np.arange(len(touching))
    look = 2 * (frame // 420) + (frame % 420 >= 210)
    share = np.array([np.mean(touching & (look == k)) for k in range(4)]) / touching.mean()
    at = np.array([reach.numpy()[touching & (look == k)].mean() for k in range(4)])
    side = [(share[h::2] * at[h::2]).sum() / share[h::2].sum() for h in (0, 1)]
    expect = np.sqrt(sum(share[k] * (at[k] - side[k % 2]) ** 2 for k in range(4))) / 0.1e-6
    assert moved.item() == pytest.approx(expect, rel=1e-3)
    assert moved.item() > 10
    # the cycles' wholes alone (the check before the looks): as much between cycles; within
    # them (9σ apart against 24σ between) ~1/3 of the looks' spread
    weight = share.reshape(2, 2).sum(1)
    cycle = (share * at).reshape(2, 2).sum(1) / weight
    alone = np.sqrt((weight * (cycle - (share * at).sum()) ** 2).sum()) / 0.1e-6
    assert (alone < 0.5 * moved.item() if splice == "within cycles"
            else alone == pytest.approx(moved.item(), rel=0.1))
    score = max(moved.item() / 0.5, motion.item() / MOTION_LIMIT)
    assert not gated[-2].item() and gated[-1].item() == pytest.approx(score, rel=1e-5)
    assert not out[-2].item() and out[-1].item() == pytest.approx(gated[-1].item(), rel=1e-4)
    n = scene.n_samples
    offline = _onnx(graph, tmp_path / "model.onnx", DECODER_OUTPUTS, ONSET_INPUTS,
                    (n, n, 4, 4, ()))
    got = offline.run(None, dict(zip(ONSET_INPUTS, (y.numpy() for y in spliced), strict=True)))
    assert not got[-2].item() and got[-1].item() == pytest.approx(gated[-1].item(), rel=1e-4)
    chunked = _onnx(stream, tmp_path / "stream.onnx", STREAM_OUTPUTS, STREAM_INPUTS,
                    (stream.chunk_samples,) * 2 + (4, 4, (), stream.state_size))
    state = np.zeros((1, stream.state_size), np.float32)
    for k in range(0, n, stream.chunk_samples):
        part = [y[:, k:k + stream.chunk_samples].numpy() for y in spliced[:2]]
        res = chunked.run(None, dict(zip(STREAM_INPUTS, (*part, *(y.numpy() for y in spliced[2:]),
                                                         state), strict=True)))
        state = res[5]
    assert not res[-2].item() and res[-1].item() == pytest.approx(gated[-1].item(), rel=1e-3)


def test_an_export_of_several_ranges_scales_sigma_by_the_answers_range_in_both_graphs(
        onset_export, scene, tmp_path, monkeypatch):
    """The oracle's heads answer every wall with σ 0.1 µm (the fixture's own net answers
    none, so its export keeps one range): exported on 384 fresh records, the decoder gets
    GAP_RANGES ranges of the answered gap, its σ is 0.1 µm × the scale of the answer's range
    for walls across them, and the streaming graph, whose running gap can cross the ranges'
    edges mid-record, ends each record on the same σ and 95 % half-width."""
    from wtml.exporters import onset as exporter
    from wtml.runtime.onset import stream_record
    from wtml.runtime.predict import OnnxModel

    monkeypatch.setattr(exporter, "FRESH_RECORDS", 384)
    monkeypatch.setattr(exporter, "PIECE_RECORDS", 32)
    paths = exporter.export_onset(_oracle(onset_export), scene, tmp_path)
    model, stream = OnnxModel(paths["decoder"]), OnnxModel(paths["stream"])
    r = model.intervals["sigma_95"]
    assert len(r.edges) == exporter.GAP_RANGES - 1 and np.ptp(r.scales) > 0.01, r
    amp = scene.whisk_amplitude_m()
    rec = scene.simulate(8, np.random.default_rng(11), gaps=np.linspace(0.1, 0.9, 8) * amp)
    x = record_inputs(rec)
    off = model.run(*x)
    off |= model.half_widths(off)
    walls = np.isfinite(off["gap"]) & off["in_domain"]  # σ NaN where flagged
    assert walls.sum() >= 5
    which = r.range_of(off["gap"][walls])
    assert len(set(which.tolist())) == exporter.GAP_RANGES
    # the net's σ, 0.1 µm, with the wall's motion as read from the cycles' currents (the
    # oracle's contact everywhere leaves no free frame for its line: a share of ~0.1)
    with torch.no_grad():
        share = _oracle(onset_export).net(*(torch.tensor(v) for v in x))[5].numpy()[walls]
    assert np.all(share < 0.3)
    np.testing.assert_allclose(off["sigma"][walls], 0.1e-6 * np.asarray(r.scales)[which]
                               * np.sqrt(1 + share.astype(float) ** 2), rtol=1e-4)
    streamed = stream_record(stream, *x)
    for key in ("gap", "sigma", "sigma_95"):
        np.testing.assert_allclose(streamed[key], off[key], rtol=1e-4, err_msg=key)


def test_the_streamed_looks_are_the_offline_ones_where_every_frame_votes(onset_export, scene):
    """With every frame voting alike, the spliced record's looks differ by their share of
    frames in contact (~0.2 µm), and a frame given to the wrong look would move that look's
    estimate by ~60 nm (210 frames a look; the reach at the cycles' edge is -12.6 µm, at the
    looks' edge within a cycle +12.6 µm): the streaming form, fed 56 frames at a time (the
    looks' edges inside a chunk) and 60 (the cycles' edge on a chunk's edge), ends on the
    offline spread, read through a limit small enough that it alone makes the score."""
    from wtml.decoders.onset_stream import StreamingOnset

    module = _oracle(onset_export, uniform=True)
    _, spliced = _spliced(scene)
    with torch.no_grad():
        offline = module.net(*spliced)[-1].item()
    assert offline > 0.3
    for frames in (56, 60):
        stream = StreamingOnset(module.net, module.gate, frames, check_limit=1e-6).eval()
        score = _streamed(stream, spliced)[-1].item()
        assert score * 1e-6 == pytest.approx(offline, rel=1e-3), frames


def test_timing_rule_finds_every_contact_from_zm_steps_and_the_detachment_level(scene):
    """The decoder's timing rule is exact up to the phase in a frame: with Zm's steps over
    the fitted threshold (touch_threshold), a contact probability that passes 0.5 three
    frames late (frame_labels shifted: a slow net) and each record's detachment level in the
    middle of its brackets (detach_brackets), the rule (contacts_from) finds every onset and
    detachment within 0.3 ms, and a free record gets none."""

    from wtml.bench.onset import event_metrics, match_events
    from wtml.decoders.onset import (
        OnsetDecoder,
        OnsetNet,
        detach_brackets,
        edge_offsets,
        frame_labels,
        frame_period,
        touch_threshold,
    )

    rec = scene.simulate(4, np.random.default_rng(8), gaps=[2e-6, 6e-6, np.nan, 10e-6])
    targets = np.concatenate([rec["gap"][:, None], rec["onset"], rec["detachment"],
                              rec["coupling"][:, None]], 1)
    frame_s = frame_period(scene) / scene.acquisition.sample_rate_hz
    offsets = edge_offsets(targets, frame_s, scene.max_contacts)
    net = OnsetDecoder()._make(scene, torch.stack([torch.zeros(5), torch.ones(5)]))
    x = tensors(rec)
    with torch.no_grad():
        f = net.frames(*x).double()
    reach = net.reach(f, net.reach_per_volt(*x[2:4]).double())
    step = OnsetNet.steps(f, f[:, :1, :3])[..., 1:].norm(dim=-1).numpy()
    threshold = touch_threshold(step, targets, frame_s, scene.max_contacts)
    lo, hi = detach_brackets(torch.tensor(targets), reach, frame_s, scene.max_contacts)
    off = torch.nanmean((lo + hi) / 2, 1)[:, None]
    walled = np.isfinite(rec["gap"])
    assert torch.all(lo[walled].nan_to_num(-1.0) < off[walled])
    assert torch.all(off[walled] <= hi[walled].nan_to_num(1.0))
    labels = frame_labels(torch.tensor(targets), reach.shape[1], frame_s, scene.max_contacts)
    meta = Timing(frame_s, offsets[0], offsets[1], 2 / scene.drive.probe_hz, TOUCH_LOOKBACK,
                  scene.max_contacts)
    margin = torch.where(torch.tensor(walled)[:, None], reach - off, -1.0)
    late = torch.nn.functional.pad(labels, (3, 0))[:, :-3]
    pred = {"contact": late.numpy(), "detach_margin": margin.numpy(), "touch": step / threshold}
    onset, detach = contacts_from(pred, meta)
    assert event_metrics(rec, onset, detach)["f1"] == 1.0
    assert np.all(np.isnan(onset[~walled]))
    for key, found in (("onset", onset), ("detachment", detach)):
        tp, fp, fn, err = match_events(rec[key], found, 0.3e-3)
        assert fp == fn == 0 and tp == np.isfinite(rec[key]).sum(), (key, err)


def test_a_first_touch_shows_in_its_own_frame_as_a_step_of_zm(scene):
    """Why the decoder can call the onset's frame: Zm's step from the frame before is, on the
    frame that holds a first touch, at least 30 times the largest step over the free
    whisking before it, for linear walls across the range (and the penetrations of the first
    probe peak that they get). The softer laws of the mixture (a power law's tangent vanishes
    at a graze) step Zm less at their first touch; the bench's transfer table shows the
    decoder's onsets on each law alone. On the ideal acquisition: the shipped scene's
    bench-top one (converter noise, ADC floor, hum) raises free whisking's steps, and its
    first touches stand 2-25 times above them (tests/test_mains_lines.py)."""
    from wtml.decoders.onset import OnsetDecoder, OnsetNet, frame_period

    a = scene.acquisition
    scene = dataclasses.replace(scene, wall=dataclasses.replace(scene.wall, law={"linear": 1.0}),
                                acquisition=dataclasses.replace(a, effects=a.effects.only()))
    amp = scene.whisk_amplitude_m()
    rec = scene.simulate(12, np.random.default_rng(12),
                         gaps=np.linspace(0.1, 0.9, 12) * amp)
    frames = OnsetDecoder()._frames(scene)
    with torch.no_grad():
        f = frames(*tensors(rec)).double()
    step = OnsetNet.steps(f, f[:, :1, :3])[..., 1:].norm(dim=-1).numpy()
    frame_s = frame_period(scene) / scene.acquisition.sample_rate_hz
    for r in range(len(step)):
        k = int(rec["onset"][r, 0] // frame_s)
        free = step[r, k - 40:k].max()  # the 95 ms of free whisking before the first touch
        assert step[r, k] > 30 * free, (r, step[r, k], free)


def test_ruptures_peer_is_pelt_with_the_l2_cost():
    """The peer's compiled PELT (linear kernel) finds the change points of ruptures's
    reference ``Pelt(model="l2")``, and marks the raised segment as the contact."""
    import ruptures

    from wtml.baselines.onset_classical import ruptures_contacts

    rng = np.random.default_rng(9)
    x = np.concatenate([rng.normal(0, 1, 60), rng.normal(8, 1, 40), rng.normal(0, 1, 50)])
    pen = 10 * np.log(len(x))
    reference = ruptures.Pelt(model="l2", min_size=2, jump=1).fit(x).predict(pen=pen)
    u = np.linspace(0.0, 1.0, len(x))
    gap, state = ruptures_contacts(x, u, threshold=4.0, penalty=pen)
    assert reference == [60, 100, 150]
    assert np.array_equal(np.flatnonzero(state), np.arange(60, 100))
    assert gap == pytest.approx((u[60] + u[99]) / 2)


def test_cramer_rao_bound_scales_with_the_noise_and_not_with_its_numerics(scene):
    """On a white-noise acquisition the bound on g is proportional to the current's noise,
    NaN without a wall, and moves by less than 2x with the finite-difference step and the
    simulation's upsampling; the scene's acquisition (the converter's coloured noise, the ADC
    floor, the hum's unknown phases) only raises it."""
    from wtml.bench.onset import cramer_rao_bound

    gaps = np.array([0.3, 0.6, 0.5]) * scene.whisk_amplitude_m()  # the scene has free records
    labels = scene.simulate(3, np.random.default_rng(4), gaps=gaps)
    labels["gap"][2] = np.nan
    acq = scene.acquisition
    white = dataclasses.replace(scene, acquisition=dataclasses.replace(
        acq, effects=acq.effects.only()))
    base = cramer_rao_bound(white, labels, upsample=2, step_m=10e-9)
    other = cramer_rao_bound(white, labels, upsample=4, step_m=40e-9)
    louder = cramer_rao_bound(dataclasses.replace(white, acquisition=dataclasses.replace(
        white.acquisition, i_noise_a=10 * acq.i_noise_a)), labels, upsample=2, step_m=10e-9)
    real = cramer_rao_bound(scene, labels, upsample=2, step_m=10e-9)
    assert np.isnan(base[2]) and np.all(np.isfinite(base[:2])) and np.all(base[:2] > 0)
    assert np.all(np.abs(np.log(other[:2] / base[:2])) < np.log(2)), (base, other)
    np.testing.assert_allclose(louder[:2] / base[:2], 10.0, rtol=1e-3)
    assert np.all(real[:2] > base[:2]) and np.isnan(real[2]), (real, base)


def test_whittle_fisher_is_the_time_domain_sum_for_white_noise_and_weighs_by_the_density():
    """Parseval: under white noise of variance σ² the Whittle information equals
    Σ_t g_j g_k / σ² (odd and even lengths); a density raised tenfold in a band removes a
    sinusoid's information there by 10x and leaves one outside it alone."""
    from wtml.bench.onset import whittle_fisher

    rng = np.random.default_rng(0)
    rate, sigma = 1000.0, 0.3
    for n in (256, 257):
        g = rng.standard_normal((2, 3, n))
        f = np.fft.rfftfreq(n, 1 / rate)
        got = whittle_fisher(g, np.full(len(f), 2 * sigma**2 / rate), rate)
        np.testing.assert_allclose(got, np.einsum("njt,nkt->njk", g, g) / sigma**2,
                                   rtol=1e-10)
    n = 1000
    t, f = np.arange(n) / rate, np.fft.rfftfreq(n, 1 / rate)
    tones = np.stack([np.sin(2 * np.pi * 50 * t), np.sin(2 * np.pi * 300 * t)])[None]
    flat = np.full(len(f), 2 * sigma**2 / rate)
    loud = np.where((f > 20) & (f < 100), 10 * flat, flat)
    ratio = np.diag(whittle_fisher(tones, loud, rate)[0]) / np.diag(
        whittle_fisher(tones, flat, rate)[0])
    np.testing.assert_allclose(ratio, [0.1, 1.0], rtol=1e-9)


def test_a_records_pieces_are_cut_in_order_and_combined_as_one_answer():
    """A record of twice the graph's length is two records, one after the other; their
    answers make one: the mean gap, σ not shrunk by √k (the pieces share their errors), in
    domain only where every piece is and their walls lie within the limit, the score the
    larger of the pieces' and the spread over the limit; pieces that disagree on whether
    there is a wall at all are flagged; a path without σ is checked for that alone. A record
    of k pieces is judged on its k − 1 pairs one after the other (as the limit is fitted);
    one of more than MAX_PIECES is refused."""
    x = np.arange(2 * 3 * 20, dtype=np.float32).reshape(2, 3, 20)
    cut, k = cut_pieces(x, 10, "rec.npz", 5.0)
    assert k == 2 and cut.shape == (2, 6, 10)
    np.testing.assert_array_equal(cut[:, 2], x[:, 1, :10])
    np.testing.assert_array_equal(cut[:, 5], x[:, 2, 10:])
    assert cut_pieces(x, 20, "rec.npz", 5.0)[1] == 1
    with pytest.raises(InputError, match=r"rec.npz: records of 4 s \(20 samples at 5 Hz\); "
                                         r"the model takes records of 3 s"):
        cut_pieces(x, 15, "rec.npz", 5.0)
    four, k = cut_pieces(x, 5, "rec.npz", 5.0)  # four pieces
    assert k == 4 and four.shape == (2, 12, 5)
    np.testing.assert_array_equal(four[:, 7], x[:, 1, 15:])
    with pytest.raises(InputError, match="or of 2 to 8 of them one after the other"):
        cut_pieces(np.zeros((2, 1, 90)), 10, "rec.npz", 5.0)  # nine pieces
    from wtml.runtime.onset import MAX_PIECES
    from wtml.runtime.predict import INPUT_FORMATS

    assert f"recording of 2 to {MAX_PIECES} times the trained record" in " ".join(
        INPUT_FORMATS.split())  # wtml predict --help says what the code takes
    um = 1e-6
    gap = np.array([[3.0, 3.02], [3.0, 3.1], [3.0, 3.02], [np.nan, 3.0], [np.nan, np.nan]]) * um
    sigma = np.full_like(gap, 0.1 * um)
    spread = pieces_spread(gap, sigma)
    np.testing.assert_allclose(spread[:3], [0.02 / np.hypot(0.1, 0.1), 0.1 / np.hypot(0.1, 0.1),
                                            0.02 / np.hypot(0.1, 0.1)], rtol=1e-9)
    assert np.isinf(spread[3]) and spread[4] == 0
    three = np.array([[1.0, 3.0, 2.0]]) * um  # the largest pair with a σ: a piece without
    assert pieces_spread(three, np.array([[0.1, 0.1, np.nan]]) * um)[0] == pytest.approx(
        2 / np.hypot(0.1, 0.1))  # one (out of domain) hides nothing of the others, last
    steps = np.array([[1.0, 3.0, 5.0], [1.0, 5.0, 5.0]]) * um  # or between them: 1 -> 5
    np.testing.assert_allclose(pieces_spread(steps, np.array([[0.1, np.nan, 0.1]] * 2) * um),
                               4 / np.hypot(0.1, 0.1))
    assert np.isinf(pieces_spread(np.array([[1.0, 2.0]]) * um, np.zeros((1, 2)))[0])
    assert np.isnan(pieces_spread(gap[:1], np.full((1, 2), np.nan))[0])
    drift = np.array([[1.0, 1.2, 1.4, 1.6]]) * um  # each piece against the one before only
    assert pieces_spread(drift, np.full((1, 4), 0.1 * um))[0] == pytest.approx(
        0.2 / np.hypot(0.1, 0.1))
    assert pieces_spread(gap[:, :1], sigma[:, :1])[0] == 0
    pred = {"gap": gap.ravel(), "sigma": sigma.ravel(), "sigma_95": 2 * sigma.ravel(),
            "in_domain": np.array([1, 1, 1, 1, 1, 0, 1, 1, 1, 1], bool),
            "domain_score": np.array([0.1, 0.2, 0.3, 0.1, 0.9, 1.5, 0.1, 0.1, 0.2, 0.4])}
    out = combine_pieces(pred, 2, limit=0.5)
    np.testing.assert_array_equal(out["in_domain"], [True, False, False, False, True])
    np.testing.assert_allclose(out["gap"][:4], [3.01 * um, 3.05 * um, 3.01 * um, 3.0 * um])
    assert np.isnan(out["gap"][4])
    np.testing.assert_allclose(out["sigma"][:4], 0.1 * um)  # not 0.1 / √2
    np.testing.assert_allclose(out["sigma_95"][:4], 0.2 * um)
    np.testing.assert_allclose(out["domain_score"][:3],
                               [max(0.2, spread[0] / 0.5), spread[1] / 0.5, 1.5])
    assert np.isinf(out["domain_score"][3]) and out["domain_score"][4] == 0.4
    classical = combine_pieces({**pred, "sigma": np.full(10, np.nan)}, 2, limit=0.5)
    np.testing.assert_array_equal(classical["in_domain"], [True, True, False, False, True])
    one = combine_pieces(pred, 1, limit=0.0)
    for key in ("gap", "sigma", "in_domain", "domain_score"):
        np.testing.assert_array_equal(one[key], pred[key])


def test_the_pieces_limit_is_the_fresh_pieces_quantile_and_needs_whole_cycles(scene,
                                                                               monkeypatch):
    """The export's limit is the :data:`SPREAD_QUANTILE` of the spread over the fresh
    records whose two pieces both answer a wall in domain (a stand-in decoder: record r's
    second piece r·1 nm from its first, σ 0.1 µm; every fifth record's second piece out of
    domain), and the share of those records it flags; a scene whose records do not hold
    whole whisk cycles gets no limit (its long recordings are refused)."""
    import wtml.exporters.onset as exporter

    monkeypatch.setattr(exporter, "PIECE_RECORDS", 40)
    monkeypatch.setattr(exporter, "PIECE_CHUNK", 16)
    seen = []

    def decoder(e, i, t_re, t_im, hue0):
        rows = torch.arange(len(e)) + 2 * sum(seen)  # pieces of records across chunks
        seen.append(len(e) // 2)
        record, piece = rows // 2, rows % 2
        gap = 4e-6 + (piece * record).double() * 1e-9
        inside = ~((piece == 1) & (record % 5 == 4))
        return (gap.double(), torch.full((len(e),), 1e-7, dtype=torch.float64), inside,
                torch.where(inside, 0.5, 2.0))

    limit, flagged = exporter.pieces_limit(decoder, scene)
    spread = np.arange(40) * 1e-9 / np.hypot(1e-7, 1e-7)
    answered = np.arange(40) % 5 != 4
    want = np.quantile(spread[answered], exporter.SPREAD_QUANTILE)
    assert seen == [16, 16, 8] and limit == pytest.approx(want, rel=1e-9)
    assert flagged == pytest.approx(np.mean(~answered | (spread > want)))
    assert exporter.whole_pieces(scene)
    odd = dataclasses.replace(scene, drive=dataclasses.replace(scene.drive, cycles=2.5))
    assert not exporter.whole_pieces(odd) and exporter.pieces_limit(decoder, odd) == (0.0, 0.0)


def test_predict_reads_a_record_of_two_pieces_as_the_device_would(onset_export, spread_scene,
                                                                   tmp_path, monkeypatch):
    """A record of four whisk cycles, each of two records of its own device: its contacts are
    its two halves' (onsets and detachments of the second half from the record's start,
    numbered across the record), its answer theirs combined (the classical path's gap their
    mean, through each half's own calibration); halves that locate the wall apart are
    flagged by the export's limit; a record of 1.5 times the length is refused, and so is a
    long record for an export without the limit."""
    import wtml.runtime.onset as onset_runtime

    scene = spread_scene
    longer = dataclasses.replace(scene, drive=dataclasses.replace(scene.drive, cycles=4.0))
    rec = longer.simulate(2, np.random.default_rng(21), gaps=[4e-6, 7e-6])
    assert rec["hue0"][0] != rec["hue0"][1]
    rate, n = scene.acquisition.sample_rate_hz, scene.n_samples
    cal = calibration_file(tmp_path / "cal.npz", scene, rec)
    whole, halves = tmp_path / "whole.npz", tmp_path / "halves.npz"
    np.savez(whole, e=rec["e"], i=rec["i"], sample_rate_hz=rate)
    np.savez(halves, e=rec["e"].reshape(4, n), i=rec["i"].reshape(4, n), sample_rate_hz=rate)
    np.savez(tmp_path / "cal4.npz", frequency_hz=[scene.drive.probe_hz],
             t=np.repeat(np.asarray(rec["t_probe"])[:, None], 2, 0),
             hue0=np.repeat(rec["hue0"], 2))
    rows = predict_records(onset_export["model"], whole, calibration=cal)
    parts = predict_records(onset_export["model"], halves, calibration=tmp_path / "cal4.npz")
    for method in ("decoder", "classical"):
        got = [r for r in rows if r["method"] == method]
        assert {r["record"] for r in got} == {0, 1}
        for r in (0, 1):
            mine = [g for g in got if g["record"] == r]
            theirs = [p for p in parts if p["method"] == method and p["record"] // 2 == r]
            for key in ("onset (s)", "detachment (s)"):
                want = sorted(p[key] + (p["record"] % 2) * n / rate for p in theirs
                              if p["contact"] >= 0)
                assert sorted(g[key] for g in mine if g["contact"] >= 0) == pytest.approx(
                    want, rel=1e-9, nan_ok=True)
            assert [g["contact"] for g in mine] == (list(range(len(mine))) if mine[0][
                "contact"] >= 0 else [-1])
            assert mine[0]["domain_score"] >= max(p["domain_score"] for p in theirs) - 1e-9
            if method == "classical":  # each half through its own device's calibration
                halves_gap = {p["record"]: p["gap (m)"] for p in theirs}
                assert mine[0]["gap (m)"] == pytest.approx(np.nanmean(list(
                    halves_gap.values())), rel=1e-6)
    assert any(r["contact"] >= 0 and r["onset (s)"] > n / rate for r in rows
               if r["method"] == "classical")  # the second half's contacts are there
    limit = OnnxModel(onset_export["model"] / "model.onnx").meta.domain.pieces_limit
    assert limit > 0
    run = OnnxModel.run

    def walls_apart(self, *inputs):  # the fixture's net finds no wall: the halves' walls 1 µm
        out = run(self, *inputs)  # and 3 µm, σ 0.1 µm (first record), or alike (second)
        if self.meta.kind == "decoder":
            out["gap"] = np.array([1.0, 3.0, 2.0, 2.0]) * 1e-6
            out["sigma"] = np.full(4, 1e-7)
            out["in_domain"] = np.ones(4, bool)
            out["domain_score"] = np.full(4, 0.1)
        return out

    with monkeypatch.context() as m:
        m.setattr(OnnxModel, "run", walls_apart)
        dec = {r["record"]: r for r in predict_records(onset_export["model"], whole,
                                                       calibration=cal)
               if r["method"] == "decoder"}
    assert not dec[0]["in_domain"] and "2 pieces locate the wall 14 sigma apart" in dec[0][
        "flags"]
    assert dec[0]["domain_score"] == pytest.approx(2 / np.hypot(0.1, 0.1) / limit, rel=1e-6)
    assert dec[0]["gap (m)"] == pytest.approx(2e-6) and dec[0]["sigma (m)"] == pytest.approx(
        1e-7)
    assert dec[1]["in_domain"] and dec[1]["flags"] == ""

    def both_outside(self, *inputs):  # every piece out of its domain: one flag names both
        out = walls_apart(self, *inputs)
        if self.meta.kind == "decoder":
            out["in_domain"] = np.zeros(4, bool)
            out["domain_score"] = np.full(4, 2.0)
        return out

    with monkeypatch.context() as m:
        m.setattr(OnnxModel, "run", both_outside)
        flags = [r["flags"] for r in predict_records(onset_export["model"], whole,
                                                     calibration=cal)
                 if r["method"] == "decoder" and r["record"] == 1][0]
    assert flags.startswith("outside the trained domain (its inputs, or its whisk cycles'")
    assert flags.endswith("(pieces 1, 2 of 2)") and flags.count("outside") == 1
    odd = tmp_path / "odd.npz"
    np.savez(odd, e=rec["e"][:, :3 * n // 2], i=rec["i"][:, :3 * n // 2], sample_rate_hz=rate)
    with pytest.raises(InputError, match="or of 2 to 8 of them one after the other"):
        predict_records(onset_export["model"], odd, calibration=cal)
    load = onset_runtime.load_export

    def without_limit(path):
        models = load(path)
        for model in models:
            model.meta = dataclasses.replace(model.meta, domain=dataclasses.replace(
                model.meta.domain, pieces_limit=0.0))
        return models

    monkeypatch.setattr(onset_runtime, "load_export", without_limit)
    with pytest.raises(InputError, match="export it again"):
        predict_records(onset_export["model"], whole, calibration=cal)
    assert predict_records(onset_export["model"], halves, calibration=tmp_path / "cal4.npz")


def test_predict_reads_a_record_of_three_pieces_judging_each_with_the_one_before(
        onset_export, scene, tmp_path, monkeypatch):
    """A record of six whisk cycles is three records: contacts in each, one answer; a wall
    that steps between the second and third pieces is flagged, one that drifts by less than
    the limit between each piece and the next is not (each pair as the limit was fitted)."""
    rec = dataclasses.replace(scene, drive=dataclasses.replace(scene.drive, cycles=6.0)
                              ).simulate(1, np.random.default_rng(22), gaps=[5e-6])
    rate, n = scene.acquisition.sample_rate_hz, scene.n_samples
    cal = calibration_file(tmp_path / "cal.npz", scene, rec)
    path = tmp_path / "three.npz"
    np.savez(path, e=rec["e"], i=rec["i"], sample_rate_hz=rate)
    rows = [r for r in predict_records(onset_export["model"], path, calibration=cal)
            if r["method"] == "classical"]
    assert max(r["onset (s)"] for r in rows) > 2 * n / rate  # the third piece's contacts
    limit = OnnxModel(onset_export["model"] / "model.onnx").meta.domain.pieces_limit
    run = OnnxModel.run

    def walls(gaps):
        def patched(self, *inputs):
            out = run(self, *inputs)
            if self.meta.kind == "decoder":
                out |= {"gap": np.array(gaps) * 1e-6, "sigma": np.full(3, 1e-7),
                        "in_domain": np.ones(3, bool), "domain_score": np.full(3, 0.1)}
            return out
        return patched

    step = 0.9 * limit * np.hypot(0.1, 0.1)  # µm: within the limit between neighbours
    for gaps, flagged in (([4.0, 4.0 + step, 4.0 + 2 * step], False), ([4.0, 4.0, 6.0], True)):
        with monkeypatch.context() as m:
            m.setattr(OnnxModel, "run", walls(gaps))
            (dec,) = {r["record"]: r for r in predict_records(
                onset_export["model"], path, calibration=cal)
                if r["method"] == "decoder"}.values()
        assert dec["in_domain"] != flagged and dec["gap (m)"] == pytest.approx(
            np.mean(gaps) * 1e-6)
        assert ("two of its 3 pieces, one after the other, locate the wall" in dec[
            "flags"]) == flagged
    nine = tmp_path / "nine.npz"  # refused from its header, before a sample is read
    np.savez(nine, e=np.zeros((1, 9 * n)), i=np.zeros((1, 9 * n)), sample_rate_hz=rate)
    import wtml.runtime.recordings as recordings

    monkeypatch.setattr(recordings, "record_cost", lambda *a: pytest.fail("read on"))
    with pytest.raises(InputError, match="or of 2 to 8 of them one after the other"):
        predict_records(onset_export["model"], nine, calibration=cal)


def test_predict_reads_records_resamples_and_refuses(onset_export, scene, tmp_path):
    rec = scene.simulate(1, np.random.default_rng(6))
    rate = scene.acquisition.sample_rate_hz
    path = tmp_path / "rec.npz"
    np.savez(path, e=rec["e"][0], i=rec["i"][0], sample_rate_hz=rate)
    rows = predict_records(onset_export["model"], path,
                           calibration=calibration_file(tmp_path / "cal.npz", scene))
    assert {r["method"] for r in rows} == {"decoder", "classical"}
    # the same record at twice the rate is resampled to the trained one
    from scipy.signal import resample_poly

    double = tmp_path / "double.npz"
    np.savez(double, e=resample_poly(rec["e"][0], 2, 1), i=resample_poly(rec["i"][0], 2, 1),
             sample_rate_hz=2 * rate)
    x = read_record(double, rate, scene.n_samples)
    assert x.shape == (2, 1, scene.n_samples)
    # 3e-3 of the peak current, 0.2 nA: the peak is 67 nA since the dielectric loss is right
    # at the 1 Hz whisk (it was 380 nA, and 2e-3 of it 0.76 nA)
    np.testing.assert_allclose(x[1, 0, 2000:-2000], rec["i"][0, 2000:-2000],
                               atol=3e-3 * np.abs(rec["i"]).max())
    odd = tmp_path / "odd.npz"
    np.savez(odd, e=rec["e"][0], i=rec["i"][0], sample_rate_hz=rate * np.pi / 3)
    with pytest.raises(InputError, match="not a ratio of whole numbers"):
        read_record(odd, rate, scene.n_samples)
    short = tmp_path / "short.npz"
    np.savez(short, e=rec["e"][0, :1000], i=rec["i"][0, :1000], sample_rate_hz=rate)
    with pytest.raises(InputError, match="the model takes records of"):
        read_record(short, rate, scene.n_samples)
    bad = tmp_path / "bad.npz"
    np.savez(bad, e=rec["e"][0], sample_rate_hz=rate)
    with pytest.raises(InputError, match="missing \\['i'\\]"):
        read_record(bad, rate, scene.n_samples)


def test_predict_needs_the_devices_calibration_and_refuses_without_it(onset_export, scene,
                                                                       tmp_path):
    """The export names the calibration it needs (metadata ``references``; the graphs'
    inputs t_re, t_im, hue0); ``wtml predict`` without it, or with one that lacks HUE(0) or is
    taken at another frequency, is a clear error, never a silent default; with it, a record
    gets the decoder's answer through the device's own calibration."""
    import json

    from wtml.runtime.metadata import ONSET_INPUTS, STREAM_INPUTS

    model = OnnxModel(onset_export["model"] / "model.onnx")
    assert "calibration" in model.references
    assert json.loads(model.metadata["inputs"]) == list(ONSET_INPUTS)
    assert [i.name for i in model.session.get_inputs()] == list(ONSET_INPUTS)
    stream = OnnxModel(onset_export["model"] / "stream.onnx")
    assert [i.name for i in stream.session.get_inputs()] == list(STREAM_INPUTS)
    rec = scene.simulate(1, np.random.default_rng(13))
    path = tmp_path / "rec.npz"
    np.savez(path, e=rec["e"], i=rec["i"], sample_rate_hz=scene.acquisition.sample_rate_hz)
    with pytest.raises(InputError, match="needs --calibration"):
        predict_records(onset_export["model"], path)
    cli = subprocess.run([sys.executable, "-m", "wtml.cli", "predict", "--model",
                          str(onset_export["model"]), "--input", str(path)], cwd=ROOT,
                         capture_output=True, text=True)
    assert cli.returncode != 0 and "needs --calibration" in cli.stderr
    t, hue0 = scene.calibrated(scene.transducer())
    no_hue = tmp_path / "no_hue.npz"
    np.savez(no_hue, frequency_hz=[scene.drive.probe_hz], t=t[None])
    with pytest.raises(InputError, match="needs 'hue0'"):
        predict_records(onset_export["model"], path, calibration=no_hue)
    other = tmp_path / "other.npz"
    np.savez(other, frequency_hz=[400.0], t=t[None], hue0=hue0)
    with pytest.raises(InputError, match="is not the model's"):
        predict_records(onset_export["model"], path, calibration=other)
    negative = tmp_path / "negative.npz"
    np.savez(negative, frequency_hz=[scene.drive.probe_hz], t=t[None], hue0=-hue0)
    with pytest.raises(InputError, match="hue0 must be finite and > 0"):
        predict_records(onset_export["model"], path, calibration=negative)
    cal = calibration_file(tmp_path / "cal.npz", scene, rec)
    rows = predict_records(onset_export["model"], path, calibration=cal)
    out = model.run(*record_inputs(rec))
    dec = [r for r in rows if r["method"] == "decoder"]
    assert dec[0]["domain_score"] == pytest.approx(float(out["domain_score"][0]), rel=1e-6)
    # beside σ, the 95 % half-width the runtime makes of the answers (OnnxModel.half_widths,
    # the decoder's alone: the classical path is not recalibrated). This fixture's decoder
    # (3 epochs) finds no wall, so σ is NaN: a stand-in width shows that each row gets it.
    assert set(model.half_widths(out)) == {"sigma_95"}
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(OnnxModel, "half_widths", lambda self, out: {
            name: np.full(len(out["gap"]), 7e-7) for name in self.intervals})
        rows = predict_records(onset_export["model"], path, calibration=cal)
    assert all(r["sigma_95 (m)"] == 7e-7 for r in rows if r["method"] == "decoder")
    assert all(np.isnan(r["sigma_95 (m)"]) for r in rows if r["method"] == "classical")


def test_a_decoder_trained_on_one_device_flags_the_others(onset_export, scene, spread_scene):
    """The fixture's decoder was trained on the nominal device alone: records of devices
    drawn from the shipped spread, each with its own calibration, fall outside its domain
    (its gate sees the device's calibration), far beyond the nominal device's."""
    model = OnnxModel(onset_export["model"] / "model.onnx")
    spread = model.run(*record_inputs(spread_scene.simulate(4, np.random.default_rng(14))))
    nominal = model.run(*record_inputs(scene.simulate(4, np.random.default_rng(14))))
    assert np.all(spread["domain_score"] > 1), spread["domain_score"]
    assert not spread["in_domain"].any()
    # the fixture's gate (16 training records) scores the nominal device's records near its
    # training ones (0.01-3 measured), the other devices' far beyond
    assert spread["domain_score"].min() > 100 * nominal["domain_score"].max()


def test_predict_names_the_looks_check_when_it_flags(onset_export, spread_scene, tmp_path):
    """A record outside the domain is flagged by `wtml predict` with what the onset decoder's
    domain score holds beside the gate's inputs where it answers a wall: its looks' agreement
    (each whisk cycle's approach and retreat; the export states its limit in the decoder's
    metadata; the classical graph, without the check, states none and is flagged plainly). A
    row without a wall (the fixture's net answers none) is flagged plainly too: the check is
    0 there."""
    rec = spread_scene.simulate(1, np.random.default_rng(14))  # another device: outside
    path = tmp_path / "rec.npz"
    np.savez(path, e=rec["e"][0], i=rec["i"][0],
             sample_rate_hz=spread_scene.acquisition.sample_rate_hz)
    rows = predict_records(onset_export["model"], path,
                           calibration=calibration_file(tmp_path / "cal.npz", spread_scene, rec))
    decoder = [r for r in rows if r["method"] == "decoder"]
    classical = [r for r in rows if r["method"] == "classical"]
    assert decoder and not any(r["in_domain"] for r in decoder + classical)
    hint = "whisk cycles' approaches and retreats locate the wall apart"
    # the decoder's graph holds the check where it answers a wall; the classical one has none
    assert all((hint in r["flags"]) == np.isfinite(r["gap (m)"]) for r in decoder)
    assert all(r["flags"] == "outside the trained domain" for r in classical)
    assert OnnxModel(onset_export["model"] / "model.onnx").meta.domain.self_check_limit > 0
    assert OnnxModel(onset_export["model"] / "classical.onnx").meta.domain.self_check_limit == 0


def test_a_missing_wall_passes_the_gates_range_check_only_where_absence_is_an_answer():
    """NaN (no wall) is in range for an output declared ``absent_ok`` (the onset scene's
    gap), out of range for any other; a finite answer outside the range fails either way."""
    from wtml.decoders.domain import DomainGate, ZeParts

    gap = torch.tensor([float("nan"), 5e-6, 50e-6])
    for absent, expect in (((0,), [True, True, False]), ((), [False, True, False])):
        gate = DomainGate(ZeParts(), 2, {0: (1e-6, 1e-5)}, absent)
        assert gate.outputs_in_range((gap,)).tolist() == expect
    with pytest.raises(ValueError, match="absent"):
        DomainGate(ZeParts(), 2, {0: (1e-6, 1e-5)}, (1,))
    ranges = load_scene(ROOT / "configs/scenes/onset.yaml").output_ranges()
    assert ranges["gap"].absent_ok


@given(top=st.lists(st.floats(0.0, 1.0), min_size=4, max_size=4),
       shift=st.lists(st.floats(-3e-6, 3e-6), min_size=4, max_size=4),
       off=st.lists(st.floats(-3e-6, 3e-6), min_size=4, max_size=4))
def test_a_wall_is_reported_if_and_only_if_a_contact_interval_is(top, shift, off):
    """One decision gives the wall and the contacts (``answer``): over any contact
    probabilities and detachment levels, a record reports g (and σ) exactly when the rule
    (``contacts_from``) gives it at least one contact interval; otherwise both are NaN."""

    from wtml.decoders.onset import answer

    n = 40
    reach = torch.linspace(-1e-6, 1e-6, n).repeat(4, 1) + torch.tensor(shift)[:, None]
    # each record's probabilities peak at `top` in the middle of the record
    prob = torch.tensor(top)[:, None] * torch.exp(-torch.linspace(-3, 3, n) ** 2)[None]
    gap, sd, off_margin = answer(torch.full((4,), 3e-6), torch.full((4,), 1e-7),
                                 prob.amax(-1), {"reach": reach}, torch.tensor(off))
    meta = Timing(0.001, 0.0, 0.001, 0.002, TOUCH_LOOKBACK, 8)
    onset, _ = contacts_from({"contact": prob.numpy(), "detach_margin": off_margin.numpy(),
                              "touch": np.zeros((4, n))}, meta)
    has_interval = np.isfinite(onset).any(1)
    np.testing.assert_array_equal(np.isfinite(gap.numpy()), has_interval)
    np.testing.assert_array_equal(np.isfinite(sd.numpy()), has_interval)
    np.testing.assert_array_equal(has_interval, prob.amax(-1).numpy() > 0.5)


def test_a_free_record_is_in_domain_and_reports_a_wall_only_with_a_contact(onset_export,
                                                                          scene):
    """Free whisking is normal input: records without a wall score in the trained domain for
    the exported decoder (``wtml predict``'s rows) and the streaming graph alike, a record
    reports a wall (g, σ) exactly when it reports a contact, and "no wall" is in domain.
    (Whether a trained decoder answers "no contact" on them is the bench's count,
    :func:`wtml.bench.onset.free_positives`: this fixture's decoder has 3 epochs.)"""
    free = dataclasses.replace(scene, wall=dataclasses.replace(scene.wall, free_fraction=1.0))
    rec = free.simulate(3, np.random.default_rng(11))
    path = onset_export["model"] / "free.npz"
    np.savez(path, e=rec["e"], i=rec["i"], sample_rate_hz=scene.acquisition.sample_rate_hz)
    cal = calibration_file(onset_export["model"] / "free_cal.npz", scene, rec)
    rows = [r for r in predict_records(onset_export["model"], path, calibration=cal)
            if r["method"] == "decoder"]
    assert {r["record"] for r in rows} == {0, 1, 2}
    for r in rows:
        assert r["domain_score"] <= 1  # free whisking's inputs are in the trained domain
        assert np.isfinite(r["gap (m)"]) == (r["contact"] >= 0)
        assert np.isfinite(r["gap (m)"]) or np.isnan(r["sigma (m)"])  # σ NaN out of domain too
        if r["contact"] < 0:  # "no wall" passes the range check
            assert r["in_domain"] and r["flags"] == ""
    streamed = stream_record(OnnxModel(onset_export["model"] / "stream.onnx"),
                             *record_inputs(rec))
    offline = OnnxModel(onset_export["model"] / "model.onnx").run(*record_inputs(rec))
    np.testing.assert_array_equal(streamed["in_domain"], offline["in_domain"])
    np.testing.assert_array_equal(np.isnan(streamed["gap"]), np.isnan(offline["gap"]))
    assert np.all(offline["in_domain"] | np.isfinite(offline["gap"]))


def test_the_bench_counts_every_wall_and_contact_on_free_records():
    """A free record that reports a wall counts once, and each contact interval once more,
    over the free records' total duration."""
    from wtml.bench.onset import free_positives

    gap = np.array([np.nan, 4e-6, np.nan, 2e-6])
    onset = np.full((4, 8), np.nan)
    onset[1, :2] = [0.3, 1.3]
    onset[3, 0] = 0.5
    out = free_positives(gap, onset, seconds=8.0)
    assert (out["walls"], out["contacts"]) == (2, 3)
    assert out["per_s"] == pytest.approx(5 / 8.0)
    assert free_positives(np.full(4, np.nan), np.full((4, 8), np.nan), 8.0)["per_s"] == 0


def test_the_main_jobs_onset_lines_state_free_whisking_and_f1_targets():
    from wtml.pipeline import Stages, _onset_lines

    row = {"rmse": 0.07e-6, "max": 0.2e-6, "range": "all", "missed": 0}
    free = {"walls": 0, "contacts": 1, "seconds": 108.0, "per_s": 1 / 108.0, "flagged": 0.0}
    onset = {"n_test": 32, "methods": [
        {"name": "decoder (ONNX)", "rows": [row], "f1": 0.97, "false_per_s": free["per_s"],
         "free": free, "fig522_r2": 0.9997},
        {"name": "thesis pipeline (ONNX)", "rows": [row | {"rmse": 0.5e-6}]}],
        "reference": [{"rows": [row | {"rmse": 1.4e-12}]}],
        "streaming": {"chunk_ms": 2.38, "delay_ms_p50": 3.0, "gap_max_diff_m": 1e-11},
        "domain_flag": {"whisk 7.5 V": 1.0}, "false_alarm_held_out": 0.0,
        "simulator": [{"modes": 6, "threads": 1, "per_core": 1500.0}],
        "transfer": [{"name": name, "kind": kind, "records": 4, "methods": [
            {"rmse": rmse, "within_2sigma": cover, "f1": 0.97}]} for name, kind, rmse, cover in (
                ("the trained scene (in family)", "in family", 0.07e-6, 0.95),
                ("contact law linear alone", "in family", 0.06e-6, 0.95),
                ("contact law hunt_crossley alone (held out)", "held out", 0.12e-6, 0.80),
                ("mains hum alone (not in training)", "acquisition", 0.4e-6, 0.2))]}
    text = "\n".join(_onset_lines(onset, Stages()))
    for needle in ("F1 at ±1 ms 0.970 (target in the main job ≥ 0.95: met",
                   "hunt_crossley (held out) 0.120 µm (80 % in 2σ, F1 0.97)",
                   "≥ 90 % within 2σ: MISSED); worst acquisition effect: mains hum alone (not "
                   "in training) 0.400 µm",
                   "free whisking, 108 s: 0 walls and 1 contacts reported (target none: MISSED)",
                   "0 % flagged out of domain (target 0: met)"):
        assert needle in text, needle


def test_an_onset_starts_the_last_run_of_touches_not_a_lone_noise_step_ahead():
    """The timing rule (``contacts_from``) starts a contact where its last run of touches
    starts: a deepening contact steps Zm over the threshold on every frame, while a noise step
    over it (on the bench-top acquisition, a few % of free whisking's frames) stands alone.
    Here a lone noise touch 2 frames ahead of a contact's run of touches, inside the rule's
    lookback, does not pull the onset early; without the run, a lone touch still calls it."""

    n = 30
    prob = np.zeros((2, n))
    prob[:, 14:20] = 0.9  # the net's contact probability passes 0.5 two frames after the touch
    touch = np.full((2, n), 0.3)
    touch[0, 10] = 1.5  # noise, alone
    touch[0, 12:20] = 20.0  # the contact's run of touches
    touch[1, 12] = 1.5  # a touch alone
    meta = Timing(0.001, 0.0, 0.001, 0.002, TOUCH_LOOKBACK, 8)
    onset, _ = contacts_from({"contact": prob, "detach_margin": np.where(prob > 0.5, 1.0, -1.0),
                              "touch": touch}, meta)
    np.testing.assert_allclose(onset[:, 0], [0.012, 0.012])


ONSET_EDITS = {
    "negative frame": ({"frame_s": "-0.0024"}, "metadata frame_s: must be in"),
    "frame not whole samples": ({"frame_s": "0.0023"}, "metadata frame_s: must be a whole"),
    "onset offset NaN": ({"onset_offset_s": "NaN"}, "metadata onset_offset_s: not valid JSON"),
    "onset offset -139 s": ({"onset_offset_s": "-139"}, "metadata onset_offset_s: must be in"),
    "detach offset past the frame": ({"detach_offset_s": "0.5"},
                                     "metadata detach_offset_s: must be in [0, frame_s"),
    "merge 1e9 s": ({"merge_s": "1e9"}, "metadata merge_s"),
    "merge a string": ({"merge_s": '"2"'}, "metadata merge_s: must be a number"),
    "rate 0": ({"sample_rate_hz": "0"}, "metadata sample_rate_hz: must be in"),
    "other record length": ({"n_samples": "1000"}, "metadata n_samples: says input 'e'"),
    "no domain outputs": ({"domain": json.dumps({
        "score": "x", "quantile": 0.999, "false_alarm_fresh": 0.0, "n_fresh": 1,
        "outputs": {}})}, "metadata domain.outputs: must give the ranges of 'gap'"),
    "outputs swapped": ({"outputs": '["sigma", "gap", "contact", "detach_margin", "touch"]'},
                        "metadata outputs: must be"),
    "another task": ({"task": "texture"}, "metadata classes: missing"),
    "no scene": ({"scene": None}, "metadata scene: missing"),
}


@pytest.mark.parametrize("name", sorted(ONSET_EDITS))
def test_an_onset_export_with_edited_metadata_is_one_line(onset_export, scene, tmp_path,
                                                          capsys, name):
    """Metadata edits made consistent with the manifest (what once gave onsets at -139 s,
    every contact gone, or a traceback) are refused by the schema: one line naming the file
    and the key. The streaming graph's own keys are checked when it is loaded."""
    import shutil

    from tests.test_export_files import edit_metadata, one_line
    from wtml.cli import main
    from wtml.runtime.predict import load_export

    folder = tmp_path / "export"
    shutil.copytree(onset_export["model"], folder)
    rec = scene.simulate(1, np.random.default_rng(6))
    path = tmp_path / "rec.npz"
    np.savez(path, e=rec["e"], i=rec["i"], sample_rate_hz=scene.acquisition.sample_rate_hz)
    cal = calibration_file(tmp_path / "cal.npz", scene, rec)
    argv = ["predict", "--model", str(folder), "--input", str(path), "--calibration", str(cal)]
    if name == sorted(ONSET_EDITS)[0]:
        assert main(argv) == 0
        edit_metadata(folder, "stream.onnx", chunk_samples=None)
        with pytest.raises(ValueError, match="stream.onnx: metadata chunk_samples: missing"):
            load_export(folder, stream=True)
        capsys.readouterr()
    change, needle = ONSET_EDITS[name]
    edit_metadata(folder, "model.onnx", **change)
    one_line(capsys, argv, "model.onnx: " + needle)


def test_the_coverage_bench_reads_its_long_records_as_the_device_does(onset_export, tmp_path,
                                                                      monkeypatch):
    """`wtml bench coverage`'s rows of records of twice the whisk cycles (the trained scene
    and the object moving most) are answered as two records each and combined by the
    runtime's own rule, the checkpoint's raw answers alike: one answer per record."""
    import wtml.bench.coverage as coverage

    calls = []
    combine = coverage.combine_pieces

    def counted(pred, k, limit):
        calls.append((k, len(pred["gap"]), limit))
        return combine(pred, k, limit)

    monkeypatch.setattr(coverage, "combine_pieces", counted)
    labelled = []
    truth = coverage.onset_truth
    monkeypatch.setattr(coverage, "onset_truth", lambda rec: labelled.append(len(rec["gap"]))
                        or truth(rec))
    tasks = {"onset": {"data": onset_export["data"], "model": onset_export["model"],
                       "checkpoint": onset_export["run"] / "checkpoints/last.ckpt"}}
    coverage.run_coverage(tasks, tmp_path, records={"onset": 3, "independent": 0},
                          only_rows=["read as two"], progress=lambda _: None)
    rows = json.loads((tmp_path / "summary.json").read_text())["tasks"]["onset"]["intervals"][
        "sigma"]["rows"]
    names = sorted({r["name"] for r in rows})
    assert names == ["object moving with the base alone (rms_m 8e-07); records of 4 whisk "
                     "cycles read as two", "test shard", "the trained scene (in family); "
                     "records of 4 whisk cycles read as two"]
    limit = OnnxModel(onset_export["model"] / "model.onnx").meta.domain.pieces_limit
    assert calls == [(2, 6, limit)] * 4  # two rows, each the export's answers and the raw ones
    assert labelled[1:] == [3, 3]  # every row's truth labels its devices (the test shard first)
