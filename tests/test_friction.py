"""Friction on the time-domain transducer (physics.md §11): its fundamental against the
describing function, the energy balance through T, convergence in the step, the free limit."""

import numpy as np
import pytest

from wtml.physics.beam_presets import build
from wtml.physics.friction import Friction, describing_function, grains, pad_grains
from wtml.physics.modal import LinearTipLoad, ModalTransducer

F0, RATE = 36.0, 51200.0


@pytest.fixture(scope="module")
def macro() -> ModalTransducer:
    return ModalTransducer.from_beam(build("macro"), 14)


def tone(rate: float, seconds: float = 1.0, volts: float = 10.0):
    t = np.arange(int(round(seconds * rate))) / rate
    w = 2 * np.pi * F0
    return t, volts * np.sin(w * t), volts * w * np.cos(w * t)


def phasor(x: np.ndarray, t: np.ndarray, start: float = 0.5, harmonic: int = 1) -> np.ndarray:
    """The phasor at ``harmonic`` × F0 from ``start`` to the end (whole cycles for the 1 s
    tones here), shape ``x.shape[:-1]``."""
    sel = t >= start
    return 2 * np.mean(x[..., sel] * np.exp(-2j * np.pi * harmonic * F0 * t[sel]), axis=-1)


def specimen(seed: int, size_um: float, pressing: float):
    return grains(np.random.default_rng(seed), size_um * 1e-6, 4e-3, spread=0.3,
                  asperity=0.2 * size_um / 35, pressing_n=pressing)


def test_coulomb_fundamental_is_the_describing_function(macro):
    t, e, de = tone(RATE)
    mu = np.array([0.3, 0.65, 0.8])
    load = Friction(mu, 3.3e-4, angle=0.0, slip_speed=2e-3)
    out = macro.simulate(e, 1 / RATE, load, drive_rate=de, dtype=np.float64,
                         tones=[(2 * np.pi * F0, e)])
    v, f = phasor(out["v"], t), phasor(out["force"], t)
    zm = f / v
    expected = describing_function(load.coulomb, np.abs(v))
    np.testing.assert_allclose(zm.real, expected, rtol=0.02)
    assert np.all(np.abs(zm.imag) < 0.2 * zm.real)  # in phase with V


def test_energy_per_cycle_is_the_friction_work_and_the_power_through_t(macro):
    """The friction force's work per cycle in the time domain equals μN cosθ times the path
    (Coulomb) and the mechanical power that T gives from the electrical phasors alone."""
    t, e, de = tone(RATE)
    load = Friction([0.5, 0.8], 3.3e-4, angle=np.deg2rad(10), slip_speed=1e-3, viscous=2e-4)
    out = macro.simulate(e, 1 / RATE, load, drive_rate=de, dtype=np.float64,
                         tones=[(2 * np.pi * F0, e)])
    period = int(round(RATE / F0 * 9))  # 9 whole cycles (36 Hz · 0.25 s)
    sl = slice(len(t) - period, len(t))
    work = np.sum(out["force"][:, sl] * out["v"][:, sl], axis=1) / RATE
    path = np.sum(np.abs(out["v"][:, sl]), axis=1) / RATE
    vv = np.sum(out["v"][:, sl] ** 2, axis=1) / RATE
    np.testing.assert_allclose(work, load.coulomb * path + load.viscous * vv, rtol=2e-3)
    tt = macro.transduction_matrix(np.array([2 * np.pi * F0]))[0]
    ee, ii = phasor(e, t), phasor(out["i"], t)
    ff = tt[1, 1] * ee - tt[0, 1] * ii
    vel = -tt[1, 0] * ee + tt[0, 0] * ii
    power = 0.5 * np.real(ff * np.conj(vel))  # W, at the fundamental
    np.testing.assert_allclose(power * period / RATE, work, rtol=0.02)


def test_halving_the_step_moves_the_phasors_less_than_the_noise(macro):
    """With asperities: the current's fundamental phasor at the texture scene's simulation
    step and at half of it differ by less than the phasor noise of the scene's current
    channel over a 0.25 s window (sampled at its ADC rate)."""
    from wtml.scenes.texture import TextureScene

    scene = TextureScene()
    step_rate = scene.acquisition.sample_rate_hz * scene.oversample
    pos, imp = pad_grains([specimen(s, d, 3.3e-4) for s, d in enumerate((15.3, 35.0, 52.2))])
    answers = []
    for rate in (step_rate, 2 * step_rate):
        t, e, de = tone(rate)
        load = Friction([0.65, 0.7, 0.8], 3.3e-4, np.deg2rad(10), 0.01, 0.0, pos, imp)
        out = macro.simulate(e, 1 / rate, load, drive_rate=de, dtype=np.float64,
                         tones=[(2 * np.pi * F0, e)])
        answers.append(phasor(out["i"], t))
    window = int(0.25 * scene.acquisition.sample_rate_hz)
    noise = scene.acquisition.i_noise_a * np.sqrt(2 / window)  # std of a phasor, A
    change = np.abs(answers[0] - answers[1])
    assert np.all(change < noise), (change, noise)
    assert np.all(change > 0)  # the step matters at all (else this test proves nothing)


def test_no_friction_and_no_grains_is_the_free_transducer(macro):
    t, e, de = tone(RATE, 0.2)
    tones = [(2 * np.pi * F0, e)]
    none = macro.simulate(e, 1 / RATE, Friction([0.0], 3.3e-4), drive_rate=de, tones=tones)
    free = macro.simulate(e, 1 / RATE, LinearTipLoad([0.0], [0.0]), drive_rate=de, tones=tones)
    for key in ("u", "v", "i"):
        np.testing.assert_array_equal(none[key], free[key])


def test_grains_arrive_at_the_rate_v_over_d():
    rng = np.random.default_rng(1)
    pos, imp = grains(rng, 20e-6, 2e-3, spread=0.3, asperity=0.2, pressing_n=3.3e-4)
    assert np.all(np.diff(pos) > 0)
    assert abs(len(pos) / 4e-3 * 20e-6 - 1) < 0.05  # mean spacing = d
    np.testing.assert_allclose(imp.mean(), 0.2 * 3.3e-4 * 20e-6, rtol=0.05)


def test_bad_friction_input_names_the_field():
    with pytest.raises(ValueError, match="mu"):
        Friction([-0.1], 1e-3)
    with pytest.raises(ValueError, match="slip_speed"):
        Friction([0.5], 1e-3, slip_speed=0.0)
    with pytest.raises(ValueError, match="positions"):
        Friction([0.5], 1e-3, positions=[[2e-6, 1e-6]], impulses=[[1e-9, 1e-9]])
