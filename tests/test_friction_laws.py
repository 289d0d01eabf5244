"""The texture scene's friction laws (physics.md §12): Stribeck and LuGre against their limits
and closed forms, the stepper against a slow per-record reference, convergence in the step, the
fit to Table 4.10 and the scene's mixture."""

from dataclasses import replace

import numpy as np
import pytest
from scipy.optimize import brentq

from wtml.physics.beam_presets import build
from wtml.physics.friction import LAWS, Friction, describing_function, grains, pad_grains
from wtml.physics.modal import ModalTransducer
from wtml.scenes import SceneError
from wtml.scenes.texture import (
    LUGRE_OVERSAMPLE,
    NOMINAL_ANGLE_DEG,
    NOMINAL_N,
    TABLE_4_10_RMS_SPEED,
    THESIS_GRADES,
    TextureScene,
    fit_friction_law,
    nominal_response,
)
from wtml.schema import build as build_config

F0 = 36.0
PRESS = NOMINAL_N * np.cos(np.deg2rad(NOMINAL_ANGLE_DEG))


@pytest.fixture(scope="module")
def macro() -> ModalTransducer:
    # without dielectric loss: its current is linear in E, added after stepping (test_modal)
    return replace(ModalTransducer.from_beam(build("macro"), 14), loss_tangent=0.0)


def tone(rate: float, seconds: float, volts: float = 10.0):
    t = np.arange(int(round(seconds * rate))) / rate
    w = 2 * np.pi * F0
    return t, volts * np.sin(w * t), volts * w * np.cos(w * t)


def phasor(x: np.ndarray, t: np.ndarray, start: float) -> np.ndarray:
    sel = t >= start
    return 2 * np.mean(x[..., sel] * np.exp(-2j * np.pi * F0 * t[sel]), axis=-1)


def one_of_each(mu=0.61, presliding=2e-7, damping=0.0, positions=None, impulses=None,
                slip=0.01):
    """Three records: Coulomb, Stribeck (μ_s/μ_c 1.25, v_s 3.2 mm/s), LuGre on that curve."""
    stiff = 1.25 * mu * PRESS / presliding
    return Friction(np.full(3, mu), NOMINAL_N, np.deg2rad(NOMINAL_ANGLE_DEG), slip, 0.0,
                    positions, impulses, law=[0, 1, 2], static_ratio=[1.0, 1.25, 1.25],
                    stribeck_speed=3.16e-3, bristle_stiffness=stiff, bristle_damping=damping)


def test_stribeck_with_equal_coefficients_is_coulomb(macro):
    v = np.linspace(-0.5, 0.5, 2001)[None, :] * np.ones((2, 1))
    kw = dict(mu=[0.4, 0.8], normal_force=3.3e-4, angle=0.2, slip_speed=4e-3, viscous=1e-4,
              stribeck_speed=2e-3)
    coulomb, stribeck = Friction(**kw, law=0), Friction(**kw, law=1, static_ratio=1.0)
    np.testing.assert_allclose(stribeck.force(v), coulomb.force(v), rtol=1e-12, atol=0)
    t, e, de = tone(51200.0, 0.05)
    a = macro.simulate(e, t[1], coulomb, drive_rate=de, dtype=np.float64)
    b = macro.simulate(e, t[1], stribeck, drive_rate=de, dtype=np.float64)
    for key in ("u", "v", "force", "i"):
        np.testing.assert_allclose(b[key], a[key], rtol=1e-12, atol=1e-12 * np.abs(a[key]).max())


def test_lugre_steady_sliding_is_the_stribeck_curve_plus_viscous():
    v = np.array([-0.3, -4e-3, -1e-3, 2e-4, 1e-3, 3e-3, 0.05, 0.4])
    load = Friction(np.full(len(v), 0.6), 3.3e-4, 0.1, viscous=2e-4, law=2, static_ratio=1.4,
                    stribeck_speed=3e-3, bristle_stiffness=3e3, bristle_damping=0.01)
    dt = 1e-6
    path = np.broadcast_to(v[:, None], (len(v), 40000))  # 40 ms: many pre-sliding lengths
    got = load.sweep(path, dt)[:, -1]
    mu = 0.6 * (1 + 0.4 * np.exp(-(v / 3e-3) ** 2))
    expected = mu * 3.3e-4 * np.cos(0.1) * np.sign(v) + 2e-4 * v
    np.testing.assert_allclose(got, expected, rtol=1e-9)
    np.testing.assert_allclose(load.force(v), expected, rtol=1e-12)


def test_lugre_presliding_is_a_spring_of_stiffness_sigma0():
    """A displacement a thousandth of the pre-sliding distance, there and half back: F = σ0 x
    (σ1 = σ2 = 0), to the order of x over the pre-sliding distance."""
    sig0 = 2e3
    load = Friction([0.6], 3.3e-4, 0.0, law=2, static_ratio=1.2, stribeck_speed=3e-3,
                    bristle_stiffness=sig0)
    reach = 1e-3 * 0.6 * 1.2 * 3.3e-4 / sig0
    dt, n = 1e-6, 4000
    t = np.arange(n) * dt
    x = reach * np.sin(2 * np.pi * t / (n * dt)) ** 2 * np.where(t < n * dt / 2, 1, 0.75)
    v = np.gradient(x, dt)
    xs = np.concatenate([[0.0], np.cumsum(0.5 * (v[1:] + v[:-1]) * dt)])  # trapezoid path
    got = load.sweep(v[None], dt)[0]
    np.testing.assert_allclose(got, sig0 * xs, rtol=0, atol=3e-3 * sig0 * reach)


@pytest.mark.parametrize("law", [0, 1, 2])
def test_work_per_cycle_is_the_closed_form_and_the_describing_function(law):
    """Prescribed sliding x = A sin ωt: the work per cycle ∮F dx is 4 μ N A for Coulomb and
    ``π A V · describing_function`` (Dawson's rise) for Stribeck and LuGre in steady sliding
    (a pre-sliding distance 1e-5 of A); the fundamental in phase with v is that function."""
    amp, w = 1e-3, 2 * np.pi * F0
    speed = amp * w
    vs, ratio, mu = 0.08, 1.5 if law else 1.0, 0.6
    load = Friction([mu], NOMINAL_N, 0.0, slip_speed=1e-6, law=law, static_ratio=ratio,
                    stribeck_speed=vs, bristle_stiffness=ratio * mu * NOMINAL_N / 1e-8)
    n = 200000  # per cycle
    dt = 1 / (F0 * n)
    t = np.arange(2 * n) * dt
    v = speed * np.cos(w * t)
    f = load.sweep(v[None], dt)[0, n:]  # the second cycle
    work = np.sum(f * v[n:]) * dt
    expected = np.pi * amp * speed * describing_function(load.coulomb, speed, ratio, vs)
    if law == 0:
        np.testing.assert_allclose(expected, 4 * mu * NOMINAL_N * amp, rtol=1e-12)
    tol = 1e-4 if law == 2 else 1e-8  # LuGre: its pre-sliding, 1e-5 of A
    np.testing.assert_allclose(work, expected, rtol=tol)
    in_phase = 2 * np.mean(f * np.cos(w * t[n:]))
    np.testing.assert_allclose(in_phase / speed, expected / (np.pi * amp * speed), rtol=tol)


def test_step_halving_converges_at_second_order_for_each_law(macro):
    """No grains: the current's fundamental at the steps 1/51.2k, 1/102.4k, 1/204.8k; each
    halving shrinks the change about four times (order 2 of the held force)."""
    answers = []
    for rate in (51200.0, 102400.0, 204800.0):
        t, e, de = tone(rate, 0.75)
        out = macro.simulate(e, 1 / rate, one_of_each(), drive_rate=de, record=("i",),
                             dtype=np.float64)
        answers.append(phasor(out["i"], t, 0.5))
    first, second = np.abs(answers[0] - answers[1]), np.abs(answers[1] - answers[2])
    order = np.log2(first / second)
    assert np.all((order > 1.7) & (order < 2.6)), order


def test_halving_the_step_moves_the_phasors_less_than_the_noise(macro):
    """With grains, each law at the texture scene's step (LuGre at its own): the current's
    fundamental at that step and at half of it differ by less than the phasor noise of the
    scene's current channel over a 0.25 s window."""
    scene = TextureScene()
    pos, imp = pad_grains([grains(np.random.default_rng(1), 35e-6, 5e-3, spread=0.33,
                                  asperity=0.2, pressing_n=PRESS)] * 3)
    load = one_of_each(positions=pos, impulses=imp)
    window = int(0.25 * scene.acquisition.sample_rate_hz)
    noise = scene.acquisition.i_noise_a * np.sqrt(2 / window)
    for laws, over in (([0, 1], scene.oversample), ([2], LUGRE_OVERSAMPLE)):
        answers = []
        for rate in (scene.acquisition.sample_rate_hz * over,
                     2 * scene.acquisition.sample_rate_hz * over):
            t, e, de = tone(rate, 0.75)
            sub = Friction(load.mu[laws], NOMINAL_N, load.angle[laws], 0.01, 0.0,
                           pos[laws], imp[laws], law=load.law[laws],
                           static_ratio=load.static_ratio[laws], stribeck_speed=3.16e-3,
                           bristle_stiffness=load.bristle_stiffness[laws])
            out = macro.simulate(e, 1 / rate, sub, drive_rate=de, record=("i",),
                                 dtype=np.float64)
            answers.append(phasor(out["i"], t, 0.5))
        change = np.abs(answers[0] - answers[1])
        assert np.all(change < noise) and np.all(change > 0), (laws, change / noise)


def reference(model, e, de_out, dt, load: Friction) -> np.ndarray:
    """A slow per-record stepper on the full state (``step_matrices``, no eigenbasis): the
    grains as the production stepper lands them, Coulomb and Stribeck held at their mid-step
    extrapolation, LuGre's held force solved by Brent's method with z's closed form. Returns
    (u, v, F, i) ``(4, B, n)``."""
    n_steps = e.shape[-1]
    de_step = np.diff(e, append=e[-1]) / dt
    ns = 2 * model.n_modes + 1
    out = np.empty((4, load.batch, n_steps))
    for b in range(load.batch):
        m = model.step_matrices(dt, [0.0], [0.0], force_input=True)[0]
        step, outs = m[:ns], m[ns:]
        code, c, vr = load.law[b], load.coulomb[b], load.slip_speed[b]
        ratio, vst = load.static_ratio[b], load.stribeck_speed[b]
        s0, s1, s2 = load.bristle_stiffness[b], load.bristle_damping[b], load.viscous[b]

        def g(v, c=c, ratio=ratio, vst=vst):
            return c * (1 + (ratio - 1) * np.exp(-(v / vst) ** 2))

        def bristle(u, z, g=g, s0=s0, s1=s1, s2=s2):  # (mean force, z at the end)
            if u == 0:
                return s0 * z, z
            x = s0 * abs(u) * dt / g(u)
            zss = g(u) * np.sign(u) / s0
            z1 = zss + (z - zss) * np.exp(-x)
            mean = zss + (z - zss) * (-np.expm1(-x)) / x
            return s0 * mean + s1 * (z1 - z) / dt + s2 * u, z1

        def outputs(x, k, force, outs=outs):
            return outs @ np.concatenate([x, [e[k], 0.0, force, de_out[k]]])

        x, z, last = np.zeros(ns), 0.0, 0.0
        ptr = np.searchsorted(load.positions[b], 0.0)
        for k in range(n_steps):
            y = outputs(x, k, 0.0)
            reach = y[0] + y[1] * dt
            kick = 0.0
            while ptr < load.positions.shape[1] and load.positions[b, ptr] <= reach:
                kick, ptr = kick + load.impulses[b, ptr], ptr + 1
            while ptr > 0 and load.positions[b, ptr - 1] > reach:
                kick, ptr = kick - load.impulses[b, ptr - 1], ptr - 1
            v = y[1]
            if code == 2:
                now = s0 * z + s1 * (v - s0 * abs(v) * z / g(v)) + s2 * v
            else:
                now = (g(v) if code == 1 else c) * np.tanh(v / vr) + s2 * v
            out[:, b, k] = outputs(x, k, now + kick / dt)
            advance = step @ np.concatenate([x, [e[k], de_step[k], 0.0, 0.0]])
            per_force = step[:, ns + 2]
            if code == 2:
                nxt = min(k + 1, n_steps - 1)

                def v_next(f, nxt=nxt, advance=advance, per_force=per_force, kick=kick):
                    return outputs(advance + per_force * (f + kick / dt), nxt, 0.0)[1]

                def gap(f, v=v, z=z, v_next=v_next):
                    return f - bristle(0.5 * (v + v_next(f)), z)[0]

                top = 4 * c * ratio + 1e-12
                held = brentq(gap, -top, top, xtol=1e-18, rtol=1e-14)
                z = bristle(0.5 * (v + v_next(held)), z)[1]
            else:
                held = now if k == 0 else 1.5 * now - 0.5 * last
            last = now
            x = advance + per_force * (held + kick / dt)
    return out


def test_stepper_agrees_with_a_slow_per_record_reference(macro):
    """Two records of each law (one with grains 4 µm apart), a drive with a 400 Hz part so
    that the tip turns several times: the numba stepper in the eigenbasis against the
    reference on the full state."""
    rate, n = 102400.0, 1500
    t = np.arange(n) / rate
    e = 10 * np.sin(2 * np.pi * F0 * t) + 4 * np.sin(2 * np.pi * 400 * t)
    de = 2 * np.pi * (10 * F0 * np.cos(2 * np.pi * F0 * t) + 1600 * np.cos(2 * np.pi * 400 * t))
    pos = np.arange(-40, 41) * 4e-6 + 1e-6
    imp = np.full(len(pos), 0.2 * PRESS * 4e-6)
    rows = [(pos, imp) if r % 2 else (np.array([np.inf]), np.zeros(1)) for r in range(6)]
    pos, imp = pad_grains(rows)
    load = Friction(np.full(6, 0.61), NOMINAL_N, np.deg2rad(NOMINAL_ANGLE_DEG), 0.01, 1e-4, pos,
                    imp, law=[0, 0, 1, 1, 2, 2], static_ratio=[1, 1, 1.3, 1.3, 1.3, 1.3],
                    stribeck_speed=2e-3, bristle_stiffness=[1, 1, 1, 1, 3e3, 1.4e4],
                    bristle_damping=[0, 0, 0, 0, 0.01, 0.0])
    got = macro.simulate(e, 1 / rate, load, drive_rate=de, dtype=np.float64)
    ref = reference(macro, e, de, 1 / rate, load)
    v = got["v"]
    assert np.all(np.sum(np.diff(np.sign(v), axis=1) != 0, axis=1) >= 3)  # the tip turns
    for row, key in enumerate(("u", "v", "force", "i")):
        scale = np.abs(ref[row]).max(axis=1, keepdims=True)
        assert np.all(np.abs(got[key] - ref[row]) <= 1e-9 * scale), key


@pytest.mark.parametrize("law", LAWS)
def test_each_law_reproduces_table_4_10_at_the_nominal_set_up(law):
    """Each law on its default line (the fit's) within the Coulomb fit's tolerance (10 %)."""
    r = nominal_response(TextureScene(), law=law)
    table = np.array(list(TABLE_4_10_RMS_SPEED.values()))
    assert np.all(np.abs(r["rms_speed"] / table - 1) < 0.10)
    assert np.all(np.diff(r["zm"].real) > 0)
    assert np.all(np.abs(r["zm"].imag) < 0.2 * r["zm"].real)


@pytest.mark.slow
@pytest.mark.parametrize("law", ["stribeck", "lugre"])
def test_default_lines_are_the_fit(law):
    """fit_friction_law for each law gives the scene's default line to its stated digits."""
    scene = TextureScene()
    fit = fit_friction_law(scene, law=law)
    mu_0, per_um = scene.friction.line(law)
    assert abs(fit["intercept"] - mu_0) < 1e-3 and abs(fit["slope"] - per_um) < 1e-4
    table = np.array(list(TABLE_4_10_RMS_SPEED.values()))
    np.testing.assert_allclose(fit["rms_speed"], table, rtol=1e-3)


def scene_with(law: dict, **kw) -> TextureScene:
    data = {"specimens_per_grade": 4, "oversample": LUGRE_OVERSAMPLE if "lugre" in law else 2,
            "drive": {"record_s": 0.05, "lead_s": 0.05}, "friction": {"law": law}, **kw}
    return build_config(TextureScene, data)


def test_mixture_is_drawn_per_specimen_and_leaves_coulomb_records_as_they_were():
    """A mixture draws a law per specimen (labelled per record) from the specimens' seeds:
    the records' other nuisance is as with Coulomb alone, and a Coulomb specimen's records are
    the same to the bit."""
    alone = scene_with({"coulomb": 1.0}, oversample=LUGRE_OVERSAMPLE)
    mixed = scene_with({"coulomb": 0.4, "stribeck": 0.3, "lugre": 0.3})
    a = alone.simulate(20, np.random.default_rng(5))
    b = mixed.simulate(20, np.random.default_rng(5))
    assert np.all(a["friction_law"] == 0) and set(b["friction_law"]) == {0, 1, 2}
    for key in ("whisk_v", "whisk_hz", "normal_force", "angle", "coupling", "grade"):
        np.testing.assert_array_equal(a[key], b[key])
    same = b["friction_law"] == 0
    for key in ("e", "i", "mu"):
        np.testing.assert_array_equal(a[key][same], b[key][same])
    assert np.all(np.isfinite(b["i"])) and not np.array_equal(a["i"][~same], b["i"][~same])


def test_a_span_of_viscous_friction_keeps_table_4_10_and_the_other_nuisance():
    """``friction.viscous_span``: each specimen draws its own c in [viscous, viscous + span]
    from its seeds (its records share it), its law's line moves with c (less Coulomb friction)
    and the records' other nuisance is the span-free scene's, draw for draw; at the span's top
    and middle the moved lines give the tip speeds of c = 0 (within 2 %), where the old line
    with the same c is > 5 % slower at the top."""
    plain = scene_with({"coulomb": 0.4, "stribeck": 0.3, "lugre": 0.3})
    spanned = replace(plain, friction=replace(plain.friction, viscous_span=1e-4))
    a = plain.simulate(20, np.random.default_rng(5))
    b = spanned.simulate(20, np.random.default_rng(5))
    assert np.all(a["viscous"] == 0) and np.all((b["viscous"] > 0) & (b["viscous"] < 1e-4))
    for key in ("whisk_v", "whisk_hz", "normal_force", "angle", "coupling", "grade",
                "friction_law", "asperity", "grain_m"):
        np.testing.assert_array_equal(a[key], b[key])
    spec = b["specimen"] - b["specimen"].min()
    for s in np.unique(spec):
        assert len(set(b["viscous"][spec == s])) == 1
    shift = spanned.mu(b["grain_m"] * 1e6, b["friction_law"], b["viscous"]) - spanned.mu(
        b["grain_m"] * 1e6, b["friction_law"])
    assert np.all(shift < 0)
    np.testing.assert_allclose(b["mu"] - a["mu"], shift, atol=1e-12)
    assert np.all(np.isfinite(b["i"])) and not np.array_equal(a["i"], b["i"])

    scene = TextureScene()
    grain = np.array(list(THESIS_GRADES.values()))
    table = np.array(list(TABLE_4_10_RMS_SPEED.values()))
    for law in LAWS:
        at_0 = nominal_response(scene, law=law)["rms_speed"]  # the line's own, within 4 %
        for c in (5e-5, 1e-4):
            at_c = replace(scene, friction=replace(scene.friction, viscous=c))
            speed = nominal_response(at_c, mu=scene.mu(grain, law, c), law=law)["rms_speed"]
            assert np.all(np.abs(speed / at_0 - 1) < 0.02), (c, law)
            assert np.all(np.abs(speed / table - 1) < 0.10), (c, law)
    old = nominal_response(replace(scene, friction=replace(scene.friction, viscous=1e-4)))
    assert np.all(old["rms_speed"] < 0.95 * nominal_response(scene)["rms_speed"])


def test_a_specimen_s_viscous_c_reaches_its_load_its_bristles_and_the_ablations(monkeypatch):
    """With a span, the Friction a specimen's records are stepped with has its own c, LuGre's
    bristle stiffness comes from its moved line, the middle-grade ablation's μ is the moved
    line's at c, ``nominal`` records are the span-free scene's to the bit, and a span whose
    moved line reaches μ <= 0 is a scene error naming the field."""
    plain = scene_with({"lugre": 1.0})
    spanned = replace(plain, friction=replace(plain.friction, viscous_span=1e-4))
    spec = spanned.specimens(np.random.default_rng(3))
    which = np.arange(len(spec["grade"]))
    n = len(which)
    load = spanned.friction_load(spec, which, np.full(n, NOMINAL_N), np.full(n, 0.1))
    np.testing.assert_array_equal(load.viscous, spec["viscous"])
    moved = spanned.mu(spec["grain_um"], spec["law"], spec["viscous"])
    stiffness = (spec["static_ratio"] * moved * NOMINAL_N * np.cos(np.deg2rad(NOMINAL_ANGLE_DEG))
                 / spec["presliding_m"])
    np.testing.assert_allclose(load.bristle_stiffness, stiffness, rtol=1e-12)

    seen = []
    step = type(spanned).friction_load
    monkeypatch.setattr(type(spanned), "friction_load",
                        lambda self, *a, **k: seen.append((k["mu"], a[0], a[1])) or step(
                            self, *a, **k))
    spanned.simulate(5, np.random.default_rng(4), mean_friction=False)
    (mu, own, rows), = seen
    middle = np.median(list(THESIS_GRADES.values()))
    np.testing.assert_allclose(mu, spanned.mu(middle, own["law"][rows], own["viscous"][rows]))
    assert np.all(mu < spanned.mu(middle, own["law"][rows]))
    monkeypatch.undo()

    a = plain.simulate(5, np.random.default_rng(6), nominal=True)
    b = spanned.simulate(5, np.random.default_rng(6), nominal=True)
    for key in ("e", "i", "mu", "viscous"):
        np.testing.assert_array_equal(a[key], b[key])
    with pytest.raises(SceneError, match=r"viscous_span.*lugre.*μ = "):
        scene_with({"lugre": 1.0}, friction={"law": {"lugre": 1.0}, "viscous_span": 2e-4,
                                             "lugre": {"mu_0_per_c": -4000.0}})
    with pytest.raises(SceneError, match="viscous_span"):
        scene_with({"coulomb": 1.0}, friction={"viscous_span": 1e-3})


@pytest.mark.slow
@pytest.mark.parametrize("law", LAWS)
def test_default_line_shifts_are_the_fit_at_1e_4(law):
    """Each law's ``mu_0_per_c`` and ``mu_per_um_per_c`` are the secant of its lines fitted to
    Table 4.10 at c = 0 and c = 1e-4 N·s/m (to 1 % of the shift)."""
    scene = TextureScene()
    bottom, top = (fit_friction_law(replace(scene, friction=replace(scene.friction, viscous=c)),
                                    law=law) for c in (0.0, 1e-4))
    per_c = scene.friction.line_shift(law)
    assert abs((top["intercept"] - bottom["intercept"]) / 1e-4 - per_c[0]) < 0.01 * abs(per_c[0])
    assert abs((top["slope"] - bottom["slope"]) / 1e-4 - per_c[1]) < 0.01 * abs(per_c[1])


def test_bad_law_config_is_a_scene_error_naming_the_allowed_laws():
    with pytest.raises(SceneError, match=r"friction.law: unknown law 'dahl'.*coulomb"):
        scene_with({"dahl": 1.0})
    with pytest.raises(SceneError, match="friction.law.stribeck"):
        scene_with({"stribeck": -1.0})
    with pytest.raises(SceneError, match="oversample"):
        scene_with({"lugre": 1.0}, oversample=2)
    with pytest.raises(ValueError, match="law"):
        Friction([0.5], 1e-3, law=3)
    with pytest.raises(ValueError, match="bristle_stiffness"):
        Friction([0.5], 1e-3, law=2, bristle_stiffness=0.0)


def test_default_scene_is_coulomb_only():
    scene = replace(TextureScene(), specimens_per_grade=1)
    spec = scene.specimens(np.random.default_rng(0))
    assert np.all(spec["law"] == 0) and np.all(spec["static_ratio"] == 1.0)


def test_slip_span_draws_each_specimens_regularisation_and_changes_nothing_else():
    """``friction.slip_span`` draws each specimen's v_r log-uniform in [slip_speed/span,
    slip_speed] (how sharply the force turns at a reversal: the nuisance that spans a bristle's
    pre-sliding without being LuGre); its draws come after every other, so the records'
    other nuisance is unchanged, and span 1 is the fixed v_r of before."""
    law = {"coulomb": 0.5, "stribeck": 0.5}
    fixed = scene_with(law, oversample=6)
    spanned = scene_with(law, oversample=6, friction={"law": law, "slip_span": 4.0})
    a, b = (s.specimens(np.random.default_rng(3)) for s in (fixed, spanned))
    np.testing.assert_array_equal(a["slip_speed"], 0.01)
    assert np.all((b["slip_speed"] >= 0.0025) & (b["slip_speed"] <= 0.01))
    assert b["slip_speed"].min() < 4e-3 and b["slip_speed"].max() > 6e-3
    for key in set(a) - {"slip_speed"}:
        np.testing.assert_array_equal(a[key], b[key])
    ra, rb = (s.simulate(20, np.random.default_rng(5)) for s in (fixed, spanned))
    for key in ("whisk_v", "whisk_hz", "normal_force", "angle", "coupling", "grade", "mu"):
        np.testing.assert_array_equal(ra[key], rb[key])
    assert np.all(np.isfinite(rb["i"])) and not np.array_equal(ra["i"], rb["i"])


def test_slip_span_below_the_stable_step_is_a_scene_error():
    law = {"coulomb": 1.0}
    with pytest.raises(SceneError, match=r"friction.slip_span.*oversample 2"):
        scene_with(law, friction={"law": law, "slip_span": 4.0})
    scene_with(law, friction={"law": law, "slip_span": 1.3})  # 7.7 mm/s: held at oversample 2
    with pytest.raises(SceneError, match=r"friction.slip_speed.*oversample 1"):  # no span
        scene_with(law, oversample=1)  # 19.5 µs: the 22 modes hold 10.6 mm/s at least


def test_least_slip_speed_marks_where_the_explicit_friction_step_chatters(monkeypatch):
    """Coulomb records at the scene's step (oversample 2, 22 modes) against the same stepped 8×
    finer: at the least v_r the band above 5 kHz holds the finer records' power (within 1 %);
    at a sixth of it the explicit step chatters there (several times the power): what the
    scene's own guard refuses to step (``check_stepped``, switched off here to show it). The
    least v_r grows with the modes kept (their velocity under a held force) and is close to
    ``dt Σφb²`` times the worst force where every mode is slow."""
    from scipy.signal import welch

    from wtml.scenes import SceneError
    from wtml.scenes.texture import TextureScene

    worst = {"normal_force": [4.1e-4, 4.1e-4], "angle_deg": [5.0, 5.0]}
    base = scene_with({"coulomb": 1.0}, contact=worst, drive={"record_s": 0.1, "lead_s": 0.05})
    least = base.least_slip_speed()

    def high_band(slip_speed, oversample):
        scene = replace(base, oversample=oversample,
                        friction=replace(base.friction, slip_speed=slip_speed, asperity=0.0))
        i = scene.simulate(5, np.random.default_rng(0))["i"].astype(float)
        f, p = welch(i, fs=scene.acquisition.sample_rate_hz, nperseg=512)
        return p[:, f > 5e3].sum()

    assert high_band(least, 2) == pytest.approx(high_band(least, 16), rel=0.01)
    with pytest.raises(SceneError, match="friction.slip_speed: the device does not hold"):
        high_band(least / 6, 2)
    monkeypatch.setattr(TextureScene, "check_stepped", lambda *args: None)
    assert high_band(least / 6, 2) > 3 * high_band(least / 6, 16)
    fewer = replace(base, n_modes=14)
    assert fewer.least_slip_speed() < 0.8 * least
    model = fewer.transducer()
    slow = fewer.worst_force() * np.sum(model.tip**2) / (2 * fewer.acquisition.sample_rate_hz)
    assert fewer.least_slip_speed() == pytest.approx(slow, rel=0.05)


@pytest.mark.parametrize("n_modes", [14, 21])
def test_the_largest_stable_slope_is_where_the_linearised_loop_stops_decaying(n_modes):
    """Iterating the exact step under the force held at its mid-step extrapolation, F = s
    (1.5 v_k - 0.5 v_(k-1)) against the motion, from a disturbed state: 2 % below the
    bisected slope the state decays over the last 1500 steps, 2 % above it grows by e^10 or
    more (the eigenvalues' verdict against iteration); the one-slope test a scene runs on each
    device it steps (``holds_slope``) agrees with the bisection on either side of it."""
    from wtml.physics.friction import holds_slope, largest_stable_slope

    model = ModalTransducer.from_beam(build("macro"), n_modes)
    dt = 1 / 102400
    slope = largest_stable_slope(model, dt)
    maps = model.step_matrices(dt, 0.0, 0.0, force_input=True)[0]
    ns = maps.shape[1] - 4
    a, b, c = maps[:ns, :ns], maps[:ns, ns + 2], maps[ns + 1, :ns]

    def late_growth(s, steps=3000):  # ln of the state's growth over the last half
        x = np.random.default_rng(0).normal(size=ns)
        v_before, logs = c @ x, []
        for _ in range(steps):
            v = c @ x
            x = a @ x - np.sign(c @ b) * s * b * (1.5 * v - 0.5 * v_before)
            norm = np.linalg.norm(x)
            x, v_before = x / norm, v / norm
            logs.append(np.log(norm))
        return sum(logs[steps // 2:])

    assert late_growth(0.98 * slope) < 0 < 10 < late_growth(1.02 * slope)
    assert holds_slope(model, dt, 0.999 * slope) and not holds_slope(model, dt, 1.001 * slope)


def test_the_worst_force_is_the_largest_force_at_rest_the_scene_draws():
    """texture.yaml: Stribeck's 1.5 × (μ(P280) and three μ spreads) at 4.1e-4 N and 5°; a line
    that falls with grain size peaks at the finest grade; the FEPA grades reach 82 µm, so
    more; a LuGre-only scene has no explicit friction step; a viscous c past the step's
    largest slope leaves no v_r it holds."""
    thesis = scene_with({"coulomb": 0.5, "stribeck": 0.5})
    assert thesis.worst_force() == pytest.approx(  # μ_c three spreads up, times the ratio
        1.5 * (0.488 + 0.0039 * 52.2 + 3 * 0.005) * 4.1e-4 * np.cos(np.radians(5.0)), rel=1e-3)
    falling = scene_with({"coulomb": 1.0}, friction={"law": {"coulomb": 1.0}, "mu_0": 0.9,
                                                     "mu_per_um": -0.005})
    assert falling.worst_force() == pytest.approx(  # a line that falls: the finest grade's
        (0.9 - 0.005 * 15.3 + 0.015) * 4.1e-4 * np.cos(np.radians(5.0)), rel=1e-3)
    with pytest.raises(SceneError, match=r"friction.slip_speed.*must be >= inf"):
        scene_with({"coulomb": 1.0}, friction={"law": {"coulomb": 1.0}, "viscous": 0.1})
    assert scene_with({"coulomb": 1.0}).worst_force() < 0.7 * thesis.worst_force()
    assert scene_with({"coulomb": 0.5, "stribeck": 0.5},
                      grades="fepa").worst_force() > 1.1 * thesis.worst_force()
    lugre = scene_with({"lugre": 1.0})
    assert lugre.worst_force() == 0.0 and lugre.least_slip_speed() == 0.0


def test_the_scene_of_every_law_family_is_texture_yaml_but_for_its_friction():
    """``configs/scenes/texture_laws.yaml`` (docs/texture.md, "Trained across every law family")
    is the shipped texture scene with every law in its mixture and a span of viscous friction,
    at LuGre's oversampling, and nothing else changed: the two stay one scene apart."""
    from pathlib import Path

    import yaml

    from wtml.scenes import load_scene

    shipped, laws = (yaml.safe_load(Path(f"configs/scenes/{name}.yaml").read_text())
                     for name in ("texture", "texture_laws"))
    for data in (shipped, laws):
        data["friction"].pop("law"), data["friction"].pop("viscous_span", None)
        data.pop("oversample"), data.pop("name")
    assert shipped == laws
    scene = load_scene("configs/scenes/texture_laws.yaml")
    assert np.all(scene.friction.weights > 0) and len(scene.friction.weights) == 3
    assert scene.friction.viscous_span == 2e-4 and scene.oversample == 4
