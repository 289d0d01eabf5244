"""The time-domain transducer: tied to the two-port path, to the beam, and to closed forms."""

import dataclasses

import numpy as np
import pytest

from wtml.physics import ze_from_zm
from wtml.physics.beam_presets import build
from wtml.physics.modal import LinearTipLoad, ModalTransducer, Wall, convergence_table

W_H = 2 * np.pi * 420.0


@pytest.fixture(scope="module")
def micro():
    return ModalTransducer.from_beam(build("micro"), 3)


def tone_phasors(model, load, fs, periods=21, settle=0.8):
    """Phasors of i and u at 420 Hz under 20 mV, over whole periods after ``settle`` s
    (20 ring times of the 400 Hz mode, so the transient is below 1e-8)."""
    dt = 1 / fs
    t = np.arange(int(round((settle + periods / 420) * fs))) * dt
    e, de = 0.02 * np.cos(W_H * t), -0.02 * W_H * np.sin(W_H * t)
    out = model.simulate(e, dt, load, drive_rate=de, dtype=np.float64, tones=[(W_H, e)])
    n = int(round(periods / 420 * fs))
    keep = np.arange(len(t))[-n:]
    ref = np.exp(-1j * W_H * t[keep])
    return (2 * np.mean(out["i"][:, keep] * ref, -1), 2 * np.mean(out["u"][:, keep] * ref, -1))


def test_steady_tone_through_a_linear_load_matches_the_two_port_answer(micro):
    """i(t) and u(t) of a 420 Hz tone through a spring-damper at the tip equal the phasors
    of ``Ze = (t11 Zm + t12)/(t21 Zm + t22)`` of the same modal T: second order in the step,
    and to ~1e-6 after one Richardson step."""
    load = LinearTipLoad([5.0, 0.5], [2e-4, 0.0])
    t = micro.transduction_matrix(np.array([W_H]))[0]
    zm = load.impedance(np.array([W_H]))[:, 0]
    i_ref = 0.02 / ze_from_zm(t, zm)
    u_ref = (-t[1, 0] * 0.02 + t[0, 0] * i_ref) / (1j * W_H)
    errs, phasors = [], []
    for fs in (40960, 81920, 163840):
        i, u = tone_phasors(micro, load, fs)
        phasors.append((i, u))
        errs.append(np.max(np.abs(i / i_ref - 1)))
    order = np.log2(errs[0] / errs[1]), np.log2(errs[1] / errs[2])
    assert min(order) > 1.8, (errs, order)
    i_r = (4 * phasors[2][0] - phasors[1][0]) / 3
    u_r = (4 * phasors[2][1] - phasors[1][1]) / 3
    assert np.max(np.abs(i_r / i_ref - 1)) < 2e-6
    assert np.max(np.abs(u_r / u_ref - 1)) < 2e-6


def test_modal_t_converges_to_the_beam_and_hue0_does_not_depend_on_n():
    beam = build("micro")
    rows = convergence_table(beam, 2 * np.pi * np.linspace(380.0, 460.0, 41),
                             (1, 2, 3, 6, 10))
    trunc = [r["vs_all_modes"] for r in rows]
    assert all(b < a for a, b in zip(trunc, trunc[1:], strict=False)), trunc
    assert trunc[2] < 1e-3 and trunc[-1] < 1e-5
    # what is left against the beam is the damping model (§9), a few per cent, not truncation
    assert all(0.005 < r["vs_beam"] < 0.05 for r in rows[2:])
    # HUE(0) is the same for every n (the residual makes up the truncated modes) and the beam's
    # static solve to the eigensolver's accuracy on the fundamental (2e-9 here)
    hue0 = [r["hue0"] for r in rows]
    assert max(hue0) < 1e-8 and max(hue0) - min(hue0) < 1e-14, hue0


def modes_to_50_digits(beam) -> tuple[list, list, list]:
    """The beam's generalised eigenproblem solved in 50-digit arithmetic (mpmath): Ω² ascending
    and each mode's value at the tip and coupling, as lists of mpf."""
    import mpmath as mp

    k, m, theta = beam.matrices()
    n = len(theta)
    with mp.workdps(50):
        li = mp.inverse(mp.cholesky(mp.matrix(m.tolist())))
        a = li * mp.matrix(k.real.tolist()) * li.T
        w2, q = mp.eigsy((a + a.T) / 2)
        phi = li.T * q
        order = sorted(range(n), key=lambda j: w2[j])
        at_tip = [phi[n - 2, j] for j in order]
        coupled = [sum(theta[r] * phi[r, j] for r in range(n)) for j in order]
        return [w2[j] for j in order], at_tip, coupled


@pytest.mark.parametrize("preset", ["micro", "macro"])
def test_static_residuals_match_50_digit_modes_and_are_never_negative(preset):
    """``a_r, β_r, δ_r`` (the truncated modes' static compliances) against the same sums from
    modes solved to 50 digits, for every n up to all the DOFs: ``a_r, δ_r ≥ 0``, all three to
    1e-7 (double precision gets 2e-15 to 2e-8, the worst with one mode kept). The macro
    beam's K has condition ~7e9: taking them as ``K⁻¹ - ΦΩ⁻²Φᵀ`` was 6.5× off at 30 modes and
    negative (-1.3e-9 m/N) at 40."""
    beam = build(preset)
    w2, at_tip, coupled = modes_to_50_digits(beam)
    n_dof = len(w2)
    for n in range(1, n_dof + 1):
        got = ModalTransducer.from_beam(beam, n).residual
        assert got[0] >= 0 and got[2] >= 0, (n, got)
        want = [float(sum(x[j] * y[j] / w2[j] for j in range(n, n_dof)))
                for x, y in ((at_tip, at_tip), (at_tip, coupled), (coupled, coupled))]
        np.testing.assert_allclose(got, want, rtol=1e-7, atol=0.0, err_msg=f"n = {n}")
    assert got == (0.0, 0.0, 0.0)


def test_a_wall_never_reached_gives_exactly_the_linear_answer(micro):
    fs = 26880
    t = np.arange(4000) / fs
    tones = [(2 * np.pi, 9.5 * np.cos(2 * np.pi * t)), (W_H, 0.02 * np.cos(W_H * t))]
    e = tones[0][1] + tones[1][1]
    free = micro.simulate(e, 1 / fs, Wall([1.0], 5.0, 1e-4), dtype=np.float64, tones=tones)
    linear = micro.simulate(e, 1 / fs, LinearTipLoad([0.0], [0.0]), dtype=np.float64,
                            tones=tones)
    assert not free["contact"].any()
    for key in ("u", "i", "v"):
        np.testing.assert_array_equal(free[key], linear[key])
    assert np.all(free["force"] == 0)


def dense_steps(model, e, de, dt, wall):
    """The stepper's reference: each record stepped with the dense one-step maps of
    :meth:`ModalTransducer.step_matrices` (no eigenbasis), by the switching rule of
    :class:`TipLoad`. Returns u, v, F, i ``(B, n)`` and contact."""
    bsz, n = wall.batch, len(e)
    maps = (model.step_matrices(dt, np.zeros(bsz), np.zeros(bsz)),
            model.step_matrices(dt, wall.stiffness, wall.damping))
    ns = 2 * model.n_modes + 1
    slope = np.diff(e, append=e[-1]) / dt
    out, contact = np.empty((4, bsz, n)), np.empty((bsz, n), bool)
    for b in range(bsz):
        z = np.zeros(ns + 4)
        z[ns + 2], engaged = wall.offset[b], bool(wall.initial_state()[b])
        for k in range(n):
            z[ns], z[ns + 1], z[ns + 3] = e[k], slope[k], de[k]
            res = maps[engaged][b] @ z
            if engaged:
                new = res[ns + 2] >= 0
            else:
                u = res[ns] - wall.offset[b]
                new = u > 0 and wall.stiffness[b] * u + wall.damping[b] * res[ns + 1] > 0
            if new != engaged:
                engaged, z[ns - 1] = bool(new), 0.0
                res = maps[engaged][b] @ z
            out[:, b, k], contact[b, k] = res[ns:], engaged
            z[:ns] = res[:ns]
    return out, contact


@pytest.mark.parametrize("n_modes", [3, 6])
def test_eigenbasis_stepper_equals_dense_stepping_through_contacts(n_modes):
    """The stepper (each regime diagonal, a change of basis at every switch) against the dense
    exact maps stepped one by one: the same contacts at the same samples, the same outputs to
    rounding, for stiff and soft, damped and undamped walls, touched on many probe peaks."""
    model = ModalTransducer.from_beam(build("micro"), n_modes)
    fs = 26880
    t = np.arange(int(0.12 * fs)) / fs
    tones = [(2 * np.pi, 9.5 * np.sin(2 * np.pi * t)), (W_H, 0.02 * np.cos(W_H * t))]
    e = tones[0][1] + tones[1][1]
    de = 9.5 * 2 * np.pi * np.cos(2 * np.pi * t) - 0.02 * W_H * np.sin(W_H * t)
    wall = Wall([2e-6, 4.5e-6, -0.1e-6, 1.0], [5.0, 3.0, 8.0, 5.0], [1e-4, 0.0, 3e-4, 1e-4])
    ref, ref_contact = dense_steps(model, e, de, 1 / fs, wall)
    ref[3] += model.loss_current(e, tones)  # added after stepping, whatever the stepper
    got = model.simulate(e, 1 / fs, wall, drive_rate=de, dtype=np.float64, tones=tones)
    switches = np.abs(np.diff(ref_contact.astype(int))).sum(1)
    assert switches[0] > 4 and switches[1] > 2 and switches[3] == 0, switches
    np.testing.assert_array_equal(got["contact"], ref_contact)
    for j, key in enumerate(("u", "v", "force", "i")):
        scale = np.abs(ref[j]).max()
        assert np.abs(got[key] - ref[j]).max() < 1e-9 * scale, key


def test_the_answer_does_not_depend_on_the_threads():
    model = ModalTransducer.from_beam(build("micro"), 3)
    fs = 26880
    t = np.arange(2000) / fs
    tones = [(2 * np.pi, 9.5 * np.sin(2 * np.pi * t)), (W_H, 0.02 * np.cos(W_H * t))]
    e = tones[0][1] + tones[1][1]
    gaps = np.linspace(0.2e-6, 3e-6, 70)
    one, two = (model.simulate(e, 1 / fs, Wall(gaps, 5.0, 1e-4), threads=n, tones=tones)
                for n in (1, 2))
    assert one["contact"].any()
    for key in one:
        np.testing.assert_array_equal(one[key], two[key])


def test_single_mode_impact_oscillator_matches_its_closed_form():
    """u'' + w0² u = E0 - F from rest under a step E0, against a stiff undamped wall at g:
    the first impact at ``cos w0 t1 = 1 - g w0²/E0``; in contact it oscillates about
    ``(E0 + k g)/(w0² + k)`` at ``wc = sqrt(w0² + k)`` and leaves after ``2 φ / wc``,
    ``φ = atan2(v1/wc, g - y_eq)``, at the speed it came in (elastic),
    ``y_eq + hypot(g - y_eq, v1/wc)`` at its deepest."""
    w0, e0, g, k = 2 * np.pi * 100.0, 20.0, 30e-6, 4e7
    model = ModalTransducer(np.array([w0]), np.array([0.0]), np.array([1.0]), np.array([1.0]))
    fs = 2e6
    n = int(0.02 * fs)
    out = model.simulate(np.full(n, e0), 1 / fs, Wall([g], k, 0.0), dtype=np.float64)
    t1 = np.arccos(1 - g * w0**2 / e0) / w0
    v1 = e0 / w0 * np.sin(w0 * t1)
    wc = np.sqrt(w0**2 + k)
    y_eq = (e0 + k * g) / (w0**2 + k)
    t2 = t1 + 2 * np.arctan2(v1 / wc, g - y_eq) / wc
    edges = np.flatnonzero(np.diff(out["contact"][0].astype(int)))
    assert len(edges) >= 2
    on, off = (edges[:2] + 1) / fs
    assert abs(on - t1) <= 1.5 / fs and abs(off - t2) <= 1.5 / fs, (on - t1, off - t2)
    v_out = out["v"][0, edges[1] + 2]
    assert abs(abs(v_out) / v1 - 1) < 0.01 and v_out < 0
    deepest = y_eq + np.hypot(g - y_eq, v1 / wc)
    assert abs((np.max(out["u"][0]) - g) / (deepest - g) - 1) < 0.01


def test_loads_refuse_bad_parameters():
    with pytest.raises(ValueError, match="stiffness must be in"):
        Wall([1e-6], -1.0, 0.0)
    with pytest.raises(ValueError, match="gap must be finite"):
        Wall([np.nan], 1.0, 0.0)
    with pytest.raises(ValueError, match="n_modes must be in"):
        ModalTransducer.from_beam(build("micro"), 0)
    with pytest.raises(ValueError, match="dt must be in"):
        ModalTransducer.from_beam(build("micro"), 2).simulate(np.zeros(4), 0.0, Wall([1], 1, 0))
    with pytest.raises(ValueError, match="drive: shape"):
        ModalTransducer.from_beam(build("micro"), 2).simulate(np.zeros((3, 4)), 1e-5,
                                                              Wall([1, 2], 1, 0))


def test_dielectric_loss_current_is_omega_cp_tan_delta_e_at_every_drive_tone():
    """Constant tanδ (physics.md §9): the loss current, the lossy model's current less the
    lossless one's, is ``ω_k Cp tanδ E_k`` in phase with each tone (5 %), for the onset drive
    (1 Hz whisk, 420 Hz probe, lead-in ramp) and the texture drive (35-37 Hz per record); not
    one conductance ``ω_ref Cp tanδ`` for all (420× too much at the 1 Hz whisk)."""
    from wtml.scenes.onset import OnsetScene
    from wtml.scenes.texture import TextureScene
    from wtml.signals import phasor_lsq

    onset = OnsetScene()
    model = onset.transducer()
    lossless = dataclasses.replace(model, loss_tangent=0.0)
    tones = onset.drive_tones(lead=True)
    e, de = onset.drive_voltage(lead=True)
    rate = onset.acquisition.sample_rate_hz
    wall = Wall([1.0], 5.0, 1e-4)
    loss = np.subtract(*(m.simulate(e, 1 / rate, wall, drive_rate=de, record=("i",),
                                    dtype=np.float64, tones=[(w, x) for w, x, _ in tones])["i"]
                         for m in (model, lossless)))[0]
    n_lead = len(e) - onset.n_samples
    t = onset.times()
    cp_tan = model.capacitance * model.loss_tangent
    for w, x, _ in tones:
        got = phasor_lsq(loss[n_lead:], t, w / (2 * np.pi))
        want = w * cp_tan * phasor_lsq(x[n_lead:], t, w / (2 * np.pi))
        assert abs(got / want - 1) < 0.05, (w, got, want)
    (w_whisk, e_whisk, _), (w_probe, e_probe, _) = tones
    whisk = np.max(np.abs(loss[n_lead:] - w_probe * cp_tan * e_probe[n_lead:]))  # 1 Hz part
    assert 0.8e-9 < whisk < 0.9e-9, whisk  # physics.md §9: 0.86 nA, not 360 nA

    texture = TextureScene()
    macro = texture.transducer()
    hz, volts = np.array([35.0, 36.3, 37.0]), np.array([8.0, 10.0, 12.0])
    e, de, n_lead = texture.drive_voltage(volts, hz)
    rate = texture.acquisition.sample_rate_hz * texture.oversample
    free = LinearTipLoad(np.zeros(3), np.zeros(3))
    loss = np.subtract(*(m.simulate(e, 1 / rate, free, drive_rate=de, record=("i",),
                                    dtype=np.float64, tones=[(2 * np.pi * hz, e)])["i"]
                         for m in (macro, dataclasses.replace(macro, loss_tangent=0.0))))
    t = np.arange(e.shape[1] - n_lead) / rate
    for r in range(3):
        got = phasor_lsq(loss[r, n_lead:], t, hz[r])
        want = 2 * np.pi * hz[r] * macro.capacitance * macro.loss_tangent * phasor_lsq(
            e[r, n_lead:], t, hz[r])
        assert abs(got / want - 1) < 0.05, (hz[r], got, want)


def test_the_loss_current_needs_tones_that_add_up_to_the_drive(micro):
    fs = 26880
    t = np.arange(200) / fs
    e = 9.5 * np.sin(2 * np.pi * t) + 0.02 * np.cos(W_H * t)
    with pytest.raises(ValueError, match="tones: the drive's tones"):
        micro.simulate(e, 1 / fs, Wall([1.0], 5.0, 0.0))
    with pytest.raises(ValueError, match="tones: their sum differs"):
        micro.simulate(e, 1 / fs, Wall([1.0], 5.0, 0.0), tones=[(W_H, e - 1e-6)])
    with pytest.raises(ValueError, match=r"tones\[0\] omega must be in"):
        micro.loss_current(e, [(-1.0, e)])
    micro.simulate(e, 1 / fs, Wall([1.0], 5.0, 0.0), record=("u",))  # no current: no tones


@pytest.mark.parametrize(("preset", "n_modes"), [("micro", 3), ("macro", 14)])
def test_modal_ze_is_the_beams_up_to_the_damping_model_at_every_frequency(preset, n_modes):
    """The dielectric part of the modal T is the beam's, Cp (1 - j tanδ), at every ω: what
    is left of the free-tip Ze's difference from 1 Hz to 5 kHz is the damping model (§9: 1.3 %
    at the micro preset's 420 Hz), not a conductance right at one frequency only."""
    beam = build(preset)
    model = ModalTransducer.from_beam(beam, n_modes)
    w = 2 * np.pi * np.geomspace(1.0, 5000.0, 40)
    tb, tm = beam.transduction_matrix(w), model.transduction_matrix(w)
    err = np.abs(tm[:, 0, 1] / tm[:, 1, 1] / (tb[:, 0, 1] / tb[:, 1, 1]) - 1)
    assert np.max(err) < 0.015, np.max(err)
    assert err[0] < 3e-3  # at 1 Hz, where one conductance right at 420 Hz was 99 % off
    np.testing.assert_allclose(model.capacitance * (1 - 1j * model.loss_tangent),
                               complex(beam.capacitance), rtol=1e-12)
