"""The wall's own motion from the whisk cycles' currents (wtml.decoders.wall_motion): the
charge a moving wall adds is read back as the wall's rms motion, a still wall reads its
noise, a stream reads what a whole record does, and the scene's simulator agrees."""

import dataclasses

import numpy as np
import pytest
import torch

from wtml.decoders.domain import DomainGate, Gated, ZeParts
from wtml.decoders.onset import frame_labels
from wtml.decoders.wall_motion import (
    WallMotion,
    frame_means,
    mains_taps,
    series_stiffness,
)
from wtml.scenes import load_scene

HUE0 = 1.33e-6  # m/V
KS = 1.5  # N/m
FRAME_S = 1 / 420.0


def _record(lag: float, motion: np.ndarray | None, n_cycles: int = 2, noise: float = 0.0,
            seed: int = 0) -> tuple[torch.Tensor, torch.Tensor, np.ndarray]:
    """Frames' mean currents (A) of a record whose whisk current repeats every ``lag``
    frames, with the current a wall moving by ``motion(t)`` (m, a function of the frame) adds
    while the tip touches (the middle half of each cycle), and white ``noise`` (A per frame);
    the contact probabilities (1 in contact) and the touching mask."""
    n = int(round(lag * n_cycles))
    f = np.arange(n)
    phase = (f + 0.5) / lag % 1.0
    touching = (phase > 0.25) & (phase < 0.75)
    whisk = 4e-8 * np.sin(2 * np.pi * (f + 0.5) / lag)  # the drive's current, A
    level = whisk.copy()
    if motion is not None:  # i = HUE(0) k_s dx_b/dt in contact (charge per displacement)
        x = motion(f) * touching
        level += HUE0 * KS * np.gradient(x) / FRAME_S
    level += noise * np.random.default_rng(seed).standard_normal(n)
    return (torch.tensor(level[None], dtype=torch.float32),
            torch.tensor(touching[None].astype(np.float32)), touching)


def _motion(rms: float, seed: int = 1):
    """A wall's motion: a few tones of 5-20 Hz with random phases, ``rms`` m."""
    rng = np.random.default_rng(seed)
    hz, phase = rng.uniform(5, 20, 6), rng.uniform(0, 2 * np.pi, 6)

    def x(f):
        t = f * FRAME_S
        return rms * np.sqrt(2 / 6) * np.sin(2 * np.pi * hz[:, None] * t + phase[:, None]).sum(0)
    return x


@pytest.mark.parametrize("lag", [420.0, 262.5])
def test_a_moving_walls_charge_is_read_back_as_its_motion(lag):
    """A wall moving 0.3 µm rms adds HUE(0) k_s x_b of charge in contact; the whisk cycles'
    difference, integrated, is x_b a cycle apart, whose rms over the touching frames is √2
    times the motion's there: read back within 3 % (the frames' differencing and the line
    through the free frames), at a whole lag and at 262.5 frames a cycle (interpolated)."""
    x = _motion(0.3e-6)
    level, prob, touching = _record(lag, x)
    wm = WallMotion(lag, FRAME_S, KS)
    got = wm(level, prob, torch.tensor([HUE0])).item()
    f = np.arange(level.shape[1])
    second = f >= np.ceil(lag)
    diff = x(f) - x(f - lag)
    truth = np.sqrt(np.mean(diff[second & touching] ** 2) / 2)
    assert got == pytest.approx(truth, rel=0.03)
    assert 0.1e-6 < got < 1e-6


def test_a_still_wall_reads_its_noise_not_its_whisk_or_offsets():
    """Identical cycles (the whisk's current, 40 nA) with 1 pA of noise per frame read the
    noise summed over the contact: a frame's difference is 1.7 nm of charge-equivalent
    motion (√2 pA through HUE(0) k_s), a random walk about its line over the 210 touching
    frames ~√(210/6) of that, over √2: ~7 nm, under 10 nm; a constant offset between the
    cycles' currents (a drift of the coupling shows so) is taken by the line through the free
    frames; no touching frame reads 0."""
    level, prob, _ = _record(420.0, None, noise=1e-12)
    wm = WallMotion(420.0, FRAME_S, KS)
    hue0 = torch.tensor([HUE0])
    still = wm(level, prob, hue0).item()
    assert 1e-9 < still < 10e-9
    tilted = level.clone()
    tilted[:, 420:] += 3e-12  # 3 pA more in the second cycle: a ramp of ΔQ, no motion
    assert wm(tilted, prob, hue0).item() < 2 * still + 1e-9
    assert wm(level, torch.zeros_like(prob), hue0).item() == 0.0


def test_a_stream_of_chunks_reads_the_whole_records_motion():
    """Fed 56 frames at a time (the cycles' edge inside a chunk) and 1, with the state
    carried and the mains period's average on (8.4 frames, 50 Hz on a 420 Hz probe), the
    running read after the last chunk is the whole record's to float32 rounding."""
    level, prob, _ = _record(420.0, _motion(0.2e-6), noise=1e-12)
    wm = WallMotion(420.0, FRAME_S, KS, mains_frames=8.4)
    hue0 = torch.tensor([HUE0])
    whole = wm(level, prob, hue0).item()
    for chunk in (56, 1):
        state = wm.initial_state(1)
        for k in range(0, level.shape[1], chunk):
            got, state = wm.running(level[:, k:k + chunk], prob[:, k:k + chunk], hue0,
                                    torch.tensor([float(k)]), state)
        assert got.item() == pytest.approx(whole, rel=1e-4), chunk


def test_the_mains_period_average_nulls_the_hum_that_does_not_repeat():
    """Hum of 300 pA at 50 Hz and its 3rd harmonic, sampled on frames of a 420 Hz probe,
    with a whisk of 1.6 Hz (31.25 mains cycles a whisk cycle: the hum does not repeat
    between cycles): unaveraged it reads as ~1 µm of motion; averaged over one mains period
    (8.4 frames, the last tap 0.4) it reads under 20 nm; the taps sum to 1."""
    lag = 420 / 1.6
    level, prob, _ = _record(lag, None)
    f = np.arange(level.shape[1])
    # the hum's mean over each frame (a frame is 1/420 s)
    hum = sum(a * np.sinc(h * 50 * FRAME_S) * np.sin(2 * np.pi * h * 50 * (f + 0.5) * FRAME_S)
              for h, a in ((1, 3e-10), (3, 0.3e-10)))
    hummed = level + torch.tensor(hum[None], dtype=torch.float32)
    hue0 = torch.tensor([HUE0])
    assert WallMotion(lag, FRAME_S, KS)(hummed, prob, hue0).item() > 0.3e-6
    assert WallMotion(lag, FRAME_S, KS, mains_frames=8.4)(hummed, prob, hue0).item() < 20e-9
    assert sum(mains_taps(8.4)) == pytest.approx(1.0) and mains_taps(8.4)[-1] == pytest.approx(
        0.4 / 8.4)
    assert mains_taps(0.0) == [1.0] and mains_taps(7.0) == [1 / 7] * 7


def test_series_stiffness_is_the_tip_under_voltage_drive_in_series_with_the_wall():
    """k_tip from the nominal device's T at low frequency satisfies reciprocity's charge per
    tip displacement, 1/|t11| = HUE(0) k_tip; k_s is k_tip in series with the wall's
    geometric-mean stiffness, below both."""
    scene = load_scene("configs/scenes/onset.yaml")
    model = scene.transducer()
    w = 2 * np.pi * 0.5
    t = model.transduction_matrix(np.array([w]))[0]
    k_tip = abs(1j * w * t[0, 1] / t[0, 0])
    assert 1 / abs(t[0, 0]) == pytest.approx(model.static_tip_displacement_per_volt() * k_tip,
                                             rel=1e-4)
    k_wall = np.sqrt(np.prod(scene.wall.stiffness))
    ks = series_stiffness(scene)
    assert ks == pytest.approx(1 / (1 / k_tip + 1 / k_wall), rel=1e-9)
    assert ks < min(k_tip, k_wall)


@pytest.fixture(scope="module")
def moving_records():
    """The onset scene's own simulator: 12 records of still walls and 12 of walls moving
    with the floor at 0.4 µm rms (the acquisition's base motion, 5-20 Hz), every wall within
    reach; the base motion they were stepped with."""
    scene = load_scene("configs/scenes/onset.yaml")
    amp = scene.whisk_amplitude_m()
    gaps = np.linspace(0.15, 0.85, 12) * amp
    a = scene.acquisition
    moving = dataclasses.replace(scene, acquisition=dataclasses.replace(a, effects=(
        dataclasses.replace(a.effects, base=dataclasses.replace(a.effects.base, enabled=True,
                                                                rms_m=0.4e-6)))))
    drawn = {}
    real = type(a.effects).base_motion

    def kept(self, *args):
        drawn["x"] = real(self, *args)
        return drawn["x"]
    type(a.effects).base_motion = kept
    try:
        still = scene.simulate(12, np.random.default_rng(4), gaps=gaps)
        moved = moving.simulate(12, np.random.default_rng(4), gaps=gaps)
    finally:
        type(a.effects).base_motion = real
    return scene, still, moved, drawn["x"][:, -scene.n_samples:]


def test_the_simulators_moving_walls_read_their_motion_and_still_walls_read_none(
        moving_records):
    """Through the true contacts (the labels' frames) and the scene's k_s and mains period,
    the simulator's walls moving 0.4 µm rms (each read against the rms of its own motion a
    cycle apart over its touching frames, over √2) read 0.6-2x it at every wall (k_s is the
    nominal: the true walls' 3-8 N/m in series with the tip give 0.84-1.44x it, their laws'
    tangents more; measured 0.89-1.67x, median 1.10x), and every still wall under 20 nm: the
    charge a real wall's motion makes is the one the module reads."""
    scene, still, moved, x_b = moving_records
    period = int(round(scene.acquisition.sample_rate_hz / scene.drive.probe_hz))
    lag = scene.drive.probe_hz / scene.drive.whisk_hz
    wm = WallMotion(lag, period / scene.acquisition.sample_rate_hz, series_stiffness(scene),
                    scene.drive.probe_hz / scene.acquisition.effects.hum.mains_hz)

    def read(rec):
        i = torch.tensor(rec["i"], dtype=torch.float32)
        level = frame_means(i, period)
        targets = torch.tensor(np.concatenate([rec["gap"][:, None], rec["onset"],
                                               rec["detachment"]], 1))
        prob = frame_labels(targets, level.shape[1], period / scene.acquisition.sample_rate_hz,
                            scene.max_contacts)
        return wm(level, prob, torch.tensor(rec["hue0"], dtype=torch.float32)).numpy(), prob
    quiet, _ = read(still)
    assert np.all(quiet < 20e-9), quiet
    got, prob = read(moved)
    xf = frame_means(torch.tensor(x_b), period).numpy()
    n = int(lag)
    touch = (prob[:, n:2 * n] > 0.5) | (prob[:, :n] > 0.5)
    diff = xf[:, n:2 * n] - xf[:, :n]
    truth = np.sqrt(np.array([np.mean(d[t] ** 2) for d, t in zip(diff, touch.numpy(),
                                                                  strict=True)]) / 2)
    ratio = got / truth
    assert np.all((ratio > 0.6) & (ratio < 2.0)) and 0.9 < np.median(ratio) < 1.3, ratio


def test_a_graph_takes_the_largest_of_its_checks_over_their_limits():
    """Gated with two self-checks (the onset net's wall-motion share and looks' spread): the
    domain score is the largest of the gate's and each check over its own limit, the checks
    leave the outputs, and σ is NaN where any passes its limit."""
    class Net(torch.nn.Module):
        def forward(self, ze_re, ze_im):
            a = ze_re[:, 0]
            return a, 0.1 * torch.ones_like(a), ze_re[:, 1], ze_re[:, 2]

    gate = DomainGate(ZeParts(), 6)
    x = torch.tensor([[1.0, 0.5, 0.1], [1.0, 1.5, 0.1], [1.0, 0.2, 0.8]])
    gate.fit(x, torch.zeros_like(x))
    graph = Gated(Net(), gate, (1,), checks=(1.0, 0.5)).eval()
    with torch.no_grad():
        value, sigma, inside, score = graph(x, torch.zeros_like(x))
    np.testing.assert_allclose(score.numpy(), np.maximum(
        gate.score(gate.features(x, torch.zeros_like(x))).numpy(),
        np.maximum(x[:, 1].numpy() / 1.0, x[:, 2].numpy() / 0.5)), rtol=1e-6)
    assert inside.tolist() == [True, False, False]
    assert np.isfinite(sigma[0].item()) and torch.isnan(sigma[1:]).all()
    with pytest.raises(ValueError, match="checks must be limits > 0"):
        Gated(Net(), gate, (1,), checks=(1.0, 0.0))
