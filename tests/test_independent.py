"""The independent onset simulator (wtml.bench.independent): its own modal model against the
beam, its free whisker against its own T, its contact laws' definitions, its fixed-step
integrator's order and its agreement with solve_ivp, and its records against the production
stepper's where both apply (every contact law, no noise): within 1 % rms for the linear wall
and 1.5 % for the smooth laws at the shipped rate, the gap being the production's step error
(it shrinks at the production's order when its step is halved)."""

import dataclasses

import numpy as np
import pytest

from tests.conftest import ROOT
from wtml.bench.independent import (
    ContactLaw,
    ModalModel,
    _Drive,
    contact_law,
    simulate_like,
    simulate_onset,
)
from wtml.physics.beam_presets import build
from wtml.physics.spread import DeviceSpread
from wtml.scenes import load_scene


@pytest.fixture(scope="module")
def nominal():
    """The shipped onset scene without noise and without the acquisition's effects, its wall
    the linear one alone (the tests that compare another law say so), on the nominal device
    (this simulator's model is the preset's: the shipped scene draws each record's device
    from a spread)."""
    base = load_scene(ROOT / "configs/scenes/onset.yaml")
    return dataclasses.replace(
        base, spread=DeviceSpread(), wall=dataclasses.replace(base.wall, law={"linear": 1.0}),
        acquisition=dataclasses.replace(base.acquisition, e_noise_v=0.0, i_noise_a=0.0,
                                        effects=base.acquisition.effects.only()))


@pytest.fixture(scope="module")
def short(nominal):
    """A 0.1 s variant: the whisk at 5 Hz (half a cycle), a 50 ms lead-in."""
    return dataclasses.replace(nominal, drive=dataclasses.replace(
        nominal.drive, whisk_hz=5.0, cycles=0.5, lead_s=0.05))


def _without_whisk_tone(scene, x):
    """``x (n, n_samples)`` less its least-squares component at the whisk tone: the two
    dielectric-loss models (one conductance exact at the probe, or tanδ at every tone) differ
    only there, by ``(G − ωL Cp tanδ) E_L``."""
    t = scene.times()
    w = 2 * np.pi * scene.drive.whisk_hz
    basis = np.stack([np.cos(w * t), np.sin(w * t)], 1)
    coef = np.linalg.lstsq(basis, x.T, rcond=None)[0]
    return x - (basis @ coef).T


def _rel_rms(scene, prod, ind):
    """Each record's rms difference of the production's current from this simulator's,
    relative to its rms, the whisk tone removed from both (:func:`_without_whisk_tone`)."""
    a = _without_whisk_tone(scene, prod["i"].astype(float))
    b = _without_whisk_tone(scene, ind["current"])
    return np.sqrt(np.mean((a - b) ** 2, 1) / np.mean(b**2, 1))


def _agreement(scene, n, seed, gaps=None):
    prod = scene.simulate(n, np.random.default_rng(seed), gaps=gaps)
    ind = simulate_like(scene, prod, detail=True)
    return prod, ind, _rel_rms(scene, prod, ind)


def _same_contacts(scene, prod, ind):
    """The same contacts, every onset and detachment within one sample."""
    np.testing.assert_array_equal(np.isnan(prod["onset"]), np.isnan(ind["onset"]))
    dt = 1 / scene.acquisition.sample_rate_hz
    for key in ("onset", "detachment"):
        both = np.isfinite(prod[key]) & np.isfinite(ind[key])
        assert np.all(np.abs(prod[key] - ind[key])[both] <= dt + 1e-12)


def _with_law(scene, law, rate=1.0):
    """``scene`` with every wall of ``law`` (its parameters drawn from the scene's ranges)
    and the sample rate, the production's step with it, times ``rate``."""
    acq = scene.acquisition
    return dataclasses.replace(
        scene, wall=dataclasses.replace(scene.wall, law={law: 1.0}, free_fraction=0.0),
        acquisition=dataclasses.replace(acq, sample_rate_hz=acq.sample_rate_hz * rate))


@pytest.mark.parametrize("n_modes", [1, 3, 6])
def test_static_tip_displacement_is_the_beams_whatever_the_modes(n_modes):
    beam = build("micro")
    model = ModalModel.from_beam(beam, n_modes)
    assert model.static_tip_displacement_per_volt() == pytest.approx(
        beam.static_tip_displacement_per_volt(), rel=1e-8)


def test_modal_T_is_reciprocal_and_near_the_beams_up_to_the_damping_model():
    beam = build("micro")
    omega = 2 * np.pi * np.array([1.0, 420.0])
    t = ModalModel.from_beam(beam, 20).transduction_matrix(omega)
    assert np.abs(np.linalg.det(t) - 1).max() < 1e-9
    # modal viscous against hysteretic damping: physics.md §9's ~1.3 % at 420 Hz
    rel = np.abs(t - beam.transduction_matrix(omega)) / np.abs(beam.transduction_matrix(omega))
    assert rel.max() < 0.03


def test_drive_is_the_scenes_with_its_lead_in(short):
    drive = _Drive(short)
    n_lead = int(round(short.drive.lead_s * short.acquisition.sample_rate_hz))
    t = np.arange(-n_lead, short.n_samples) / short.acquisition.sample_rate_hz
    e, de = short.drive_voltage(lead=True)
    mine = np.array([drive(x) for x in t])
    el, dl, eh, dh = drive.tones(t)
    np.testing.assert_allclose(mine[:, 0], e, atol=1e-12)
    np.testing.assert_allclose(mine[:, 1], de, atol=1e-9)
    np.testing.assert_allclose(el + eh, e, atol=1e-12)
    np.testing.assert_allclose(dl + dh, de, atol=1e-9)


@pytest.mark.parametrize("method, substeps", [pytest.param("DOP853", 1, marks=pytest.mark.slow),
                                               ("trbdf2", 64)])
def test_free_whisker_current_is_its_own_T_at_both_tones(short, method, substeps):
    """physics.md §9's tie: once the lead-in's ramp is over (t >= 0), the free tip's current
    is the drive's tones through ``(t22/t12) E = jω δ(ω) E`` of the same modal model (the
    dielectric loss ``ω Cp tanδ E`` at each tone included) plus the free modes' decay; a
    least-squares fit of both gives each tone's phasor. Both integrators (the fixed step at
    dt/64: its phase error ~(ωh)² is 5e-5 at the default dt/16)."""
    scale = 1.02
    out = simulate_onset(short, [np.nan], 5.0, 1e-4, scale, method=method, substeps=substeps,
                         detail=True)
    t = short.times()
    wl, wh = 2 * np.pi * short.drive.whisk_hz, 2 * np.pi * short.drive.probe_hz
    model = ModalModel.from_beam(build(short.device), short.n_modes)
    poles = -model.zeta * model.omega + 1j * model.omega * np.sqrt(1 - model.zeta**2)
    basis = np.exp(np.outer(t, np.concatenate([[1j * wl, 1j * wh], poles])))
    basis = np.concatenate([basis.real, basis.imag], 1)
    coef = np.linalg.lstsq(basis, out["current"][0], rcond=None)[0]
    tones = len(poles) + 2
    phasor = coef[:2] - 1j * coef[tones:tones + 2]  # x(t) = Re(X e^{jωt})
    e_phasor = np.array([-short.drive.whisk_v, -1j * short.drive.probe_v])
    t_mat = model.with_coupling(scale).transduction_matrix(np.array([wl, wh]))
    expected = t_mat[:, 1, 1] / t_mat[:, 0, 1] * e_phasor
    np.testing.assert_allclose(phasor, expected, rtol=1e-5)
    # far below resonance the in-phase current is the dielectric's, at the whisk's own ω
    # (one conductance exact at the probe would make it 84 times larger)
    assert (phasor[0] / e_phasor[0]).real == pytest.approx(
        wl * model.capacitance * model.tan_delta, rel=0.02)


def test_agrees_with_the_production_stepper_on_a_short_record(short):
    """Linear wall, no noise: the currents within 1 % rms (measured 1.0e-3 free, 3–7e-3 with
    contacts on 2 s records: the production holds E first-order over its 37 µs step, ~1e-3
    by physics.md §9, second order, and switches the wall on the samples, up to one step late,
    first order: :func:`test_the_gap_is_the_production_steps_error`), every contact's onset
    and detachment within one sample."""
    gaps = np.array([0.1, 0.5]) * short.whisk_amplitude_m()
    base = dataclasses.replace(short, wall=dataclasses.replace(short.wall, free_fraction=0.0))
    prod = base.simulate(2, np.random.default_rng(3), gaps=gaps)
    ind = simulate_onset(base, prod["gap"], prod["stiffness"], prod["damping"],
                         prod["coupling"], detail=True)
    a = _without_whisk_tone(base, prod["i"].astype(float))
    b = _without_whisk_tone(base, ind["current"])
    rel = np.sqrt(np.mean((a - b) ** 2, 1) / np.mean(b**2, 1))
    assert np.all(rel < 1e-2), rel
    assert np.isfinite(prod["onset"][:, 0]).all()
    np.testing.assert_array_equal(np.isnan(prod["onset"]), np.isnan(ind["onset"]))
    dt = 1 / base.acquisition.sample_rate_hz
    for key in ("onset", "detachment"):
        both = np.isfinite(prod[key]) & np.isfinite(ind[key])
        assert np.all(np.abs(prod[key] - ind[key])[both] <= dt + 1e-12)


@pytest.mark.slow
def test_agrees_with_the_production_stepper_on_the_shipped_scene(nominal):
    """2 s records: measured 5.1e-3 and 5.6e-3 rms (seed 11's first two records, 24 and 40
    events), onsets to the sample, detachments within one."""
    prod, ind, rel = _agreement(nominal, 3, 11)
    assert np.all(rel < 1e-2), rel
    np.testing.assert_array_equal(np.isnan(prod["onset"]), np.isnan(ind["onset"]))
    dt = 1 / nominal.acquisition.sample_rate_hz
    for key in ("onset", "detachment"):
        both = np.isfinite(prod[key]) & np.isfinite(ind[key])
        assert np.all(np.abs(prod[key] - ind[key])[both] <= dt + 1e-12)


def _law(law, **params):
    return contact_law(law, 5.0, 0.0, params, 1)


def test_power_law_tangent_is_k_ref_at_the_reference_and_zero_force_at_contact():
    for law in (_law("power", exponent=1.3, reference_m=2e-6),
                _law("mount_hertz", reference_m=2e-6, mount_fraction=0.3)):
        d = 2e-6 * np.array([[1 - 1e-6, 1 + 1e-6]])
        f = law.force(d, 0 * d, 0.0)[0]
        assert (f[0, 1] - f[0, 0]) / (d[0, 1] - d[0, 0]) == pytest.approx(5.0, rel=1e-6)
        assert law.force(np.zeros((1, 1)), np.zeros((1, 1)), 0.01)[0][0, 0] == 0.0


def test_laws_reduce_to_their_limits():
    over = np.geomspace(1e-9, 1e-5, 7)[None]
    rate = 1e-3 * np.ones_like(over)
    a_r = 0.0127
    linear = _law("linear").force(over, rate, a_r)
    np.testing.assert_allclose(_law("power", exponent=1.0).force(over, rate, a_r)[0],
                               linear[0], rtol=1e-9)
    np.testing.assert_allclose(_law("hunt_crossley", exponent=1.4, alpha_s_per_m=0.0).force(
        over, rate, a_r)[0], _law("power", exponent=1.4).force(over, rate, a_r)[0], rtol=1e-12)
    np.testing.assert_allclose(_law("mount_hertz", mount_fraction=0.999).force(
        over, rate, a_r)[0], linear[0], rtol=2e-2)
    np.testing.assert_allclose(_law("mount_hertz", mount_fraction=1e-3).force(
        over, rate, a_r)[0], _law("power", exponent=1.5).force(over, rate, a_r)[0], rtol=2e-2)
    # the series relation holds: the modal overshoot is the penetration plus a_r F
    hc = _law("hunt_crossley", alpha_s_per_m=0.5)
    f = hc.force(over, rate, a_r)[0]
    k = hc.gain[0] * (1 + 0.5 * rate / (1 + a_r * 1.5 * hc.gain[0]
                                        * (over - a_r * f) ** 0.5))
    np.testing.assert_allclose(f, k * (over - a_r * f) ** 1.5, rtol=1e-6)


def test_bad_law_parameters_are_named():
    with pytest.raises(ValueError, match="law must be"):
        contact_law("hertz", 5.0, 0.0, None, 1)
    with pytest.raises(ValueError, match="exponent"):
        contact_law("power", 5.0, 0.0, {"exponent": 2.0}, 1)
    with pytest.raises(ValueError, match="not parameters"):
        contact_law("linear", 5.0, 0.0, {"exponent": 1.2}, 1)
    assert isinstance(contact_law("power", [4.0, 6.0], 0.0, None, 2), ContactLaw)


def _gaps(scene, fractions=(0.2, 0.6, 0.9)):
    return np.array(fractions) * scene.whisk_amplitude_m()


def _rms(x, ref):
    return float(np.sqrt(np.mean((x - ref) ** 2) / np.mean(ref**2)))


def test_fixed_step_converges_at_second_order(short):
    """TR-BDF2 at dt/4, dt/8, dt/16 against dt/64: the error falls 4 times per halving
    (measured 1.2e-4, 3.0e-5, 7.5e-6 rms with contacts); the default dt/16 is far inside the
    smallest gap to the production (1e-3, free tip)."""
    gaps = _gaps(short)
    run = {s: simulate_onset(short, gaps, 5.0, 1e-4, 1.0, substeps=s, detail=True)
           for s in (4, 8, 16, 64)}
    err = [_rms(run[s]["current"], run[64]["current"]) for s in (4, 8, 16)]
    assert 3.5 < err[0] / err[1] < 4.5 and 3.5 < err[1] / err[2] < 4.5, err
    assert err[2] < 2e-5
    for s in (4, 8, 16):
        np.testing.assert_array_equal(run[s]["events"], run[64]["events"])
        np.testing.assert_allclose(run[s]["onset"], run[64]["onset"], equal_nan=True)


def test_power_law_of_exponent_one_is_the_undamped_linear_wall(short):
    """Two paths of the integrator (the linear force in closed form, the power law's Newton
    root; release on the force or on the overshoot) give the same records."""
    gaps = _gaps(short)
    lin = simulate_onset(short, gaps, 5.0, 0.0, 1.0, detail=True)
    pow1 = simulate_onset(short, gaps, 5.0, 0.0, 1.0, law="power",
                          law_params={"exponent": 1.0}, detail=True)
    np.testing.assert_allclose(pow1["current"], lin["current"], rtol=0,
                               atol=1e-9 * np.abs(lin["current"]).max())
    np.testing.assert_array_equal(pow1["events"], lin["events"])
    assert lin["events"].min() > 0


@pytest.mark.parametrize("law", ["power", "hunt_crossley", "mount_hertz"])
def test_smooth_laws_agree_with_the_production_contact_wall(short, law):
    """Each smooth law against the production's ContactWall stepped by
    ModalTransducer.simulate (the scene's law mixture, parameters drawn per record, matched
    through ``simulate_like``): within 1.5 % rms (measured 0.67–1.3e-2 here, where the whisk
    is 5 times faster than the shipped scene's; 0.16–1.07e-2 on its 2 s records), every
    contact to one sample."""
    scene = _with_law(short, law)
    prod, ind, rel = _agreement(scene, 3, 4, _gaps(short))
    assert np.all(prod["law"] == ["linear", "power", "hunt_crossley", "mount_hertz"].index(law))
    assert np.all(rel < 1.5e-2), rel
    assert np.all(ind["events"] > 0)
    _same_contacts(scene, prod, ind)


@pytest.mark.parametrize("law, order", [("linear", 1), ("power", 2), ("mount_hertz", 2)])
def test_the_gap_is_the_production_steps_error(short, law, order):
    """Halving the production's step (the scene at twice the sample rate) shrinks the gap at
    the production's order: about 2 times for the linear wall (switched on the samples), 4 for
    the smooth laws (F trapezoidal over the step) and for the free tip (the drive held
    first-order): measured 2.07, 3.75, 3.56 and 4.00. The modal damping and the loss, this
    simulator's own, do not depend on the step: they are not the gap."""
    gaps = np.concatenate([[np.nan], _gaps(short)])
    rel = [_agreement(_with_law(short, law, rate), 4, 4, gaps)[2] for rate in (1.0, 2.0)]
    free = rel[0][0] / rel[1][0]
    contact = np.sqrt(np.mean(rel[0][1:] ** 2) / np.mean(rel[1][1:] ** 2))
    assert 3.5 < free < 4.5, free
    assert 0.75 * 2**order < contact < 1.25 * 2**order, contact


@pytest.mark.slow
@pytest.mark.parametrize("law, damping", [("linear", 1e-4), ("linear", 0.0), ("power", 0.0),
                                          ("hunt_crossley", 0.0), ("mount_hertz", 0.0)])
def test_fixed_step_agrees_with_solve_ivp(short, law, damping):
    """The cross-check: solve_ivp (DOP853, Radau for the damped wall's force state) at
    rtol 1e-8, its change to 1e-10 1e-9 rms: the fixed step within 1e-4 rms (measured 3e-5),
    the same events, onsets to 1e-9 s."""
    gaps = _gaps(short)
    fixed = simulate_onset(short, gaps, 5.0, damping, 1.0, law=law, detail=True)
    ivp = simulate_onset(short, gaps, 5.0, damping, 1.0, law=law, method="DOP853", rtol=1e-8,
                         detail=True)
    assert _rms(fixed["current"], ivp["current"]) < 1e-4
    np.testing.assert_array_equal(fixed["events"], ivp["events"])
    np.testing.assert_allclose(fixed["onset"], ivp["onset"], atol=1e-9, equal_nan=True)


def test_bad_method_and_substeps_are_named(short):
    with pytest.raises(ValueError, match="method"):
        simulate_onset(short, [1e-6], 5.0, 0.0, 1.0, method="euler")
    with pytest.raises(ValueError, match="substeps"):
        simulate_onset(short, [1e-6], 5.0, 0.0, 1.0, substeps=0)
