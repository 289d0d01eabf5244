"""Contact laws at the tip, stepped implicitly: limits of the family, closed forms of an
impact, step halving, the numba stepper against a slow per-record reference, and the linear
law against the exact switched wall."""


import numpy as np
import pytest
from scipy.linalg import expm
from scipy.optimize import brentq

from tests.conftest import whisk
from wtml.physics.contact import LAWS, ContactWall, hertz_constant
from wtml.physics.modal import ModalTransducer, Wall

FS = 26880.0


def run(model, load, fs, **kw):
    e, de = whisk(fs, **kw)
    return model.simulate(e, 1 / fs, load, drive_rate=de, dtype=np.float64)


def test_n1_power_law_and_alpha0_hunt_crossley_are_their_limits(micro):
    """n = 1 power law is the undamped linear law; α = 0 Hunt–Crossley is the power law: the
    force functions to 1e-9 and the stepped records to 1e-9."""
    rng = np.random.default_rng(0)
    delta, rate = rng.uniform(-2e-6, 5e-6, (4, 50)), rng.normal(0, 1e-3, (4, 50))
    gaps, k, d_ref, n = [3e-6, 5e-6, 3e-6, 5e-6], [5.0, 3.0, 8.0, 5.0], 1e-6, [1.0, 1.0, 1.3, 1.5]
    pairs = [(ContactWall(gaps, "power", k, d_ref, n=1.0), ContactWall(gaps, "linear", k)),
             (ContactWall(gaps, "hunt_crossley", k, d_ref, n=n, alpha=0.0),
              ContactWall(gaps, "power", k, d_ref, n=n))]
    for a, b in pairs:
        fa, fb = a.force(delta, rate), b.force(delta, rate)
        assert np.abs(fa - fb).max() <= 1e-9 * np.abs(fb).max()
        ra, rb = run(micro, a, FS), run(micro, b, FS)
        assert rb["contact"].sum() > 100
        np.testing.assert_array_equal(ra["contact"], rb["contact"])
        for key in ("u", "v", "force", "i"):
            assert np.abs(ra[key] - rb[key]).max() <= 1e-9 * np.abs(rb[key]).max(), key


@pytest.mark.parametrize("law", LAWS)
def test_no_force_at_zero_or_negative_penetration_and_never_tensile(law):
    wall = ContactWall([0.0] * 3, law, [5.0, 1.0, 50.0], [1e-6, 1e-7, 1e-4], n=[1.0, 1.2, 1.5],
                       alpha=[0.0, 1.0, 100.0], k_mount=[10.0, 2.0, 51.0],
                       damping=[0.0, 1e-4, 1.0])
    delta = np.array([0.0, -1e-12, -1e-6, -1.0])[None].repeat(3, 0)
    for rate in (-1.0, 0.0, 1.0):
        assert np.all(wall.force(delta, rate) == 0.0)
    inside = np.array([1e-9, 1e-6, 1e-4])[None].repeat(3, 0)
    assert np.all(wall.force(inside, -1e3) >= 0.0) and np.all(wall.force(inside, 0.0) > 0.0)


def test_the_family_shares_its_tangent_at_the_reference_penetration():
    """Every law's tangent dF/dδ at δ_ref (δ' = 0) is k_ref; the mount+Hertz law satisfies its
    series relation ``δ = F/k_m + (F/K_h)^(2/3)``."""
    k_ref, d_ref = np.array([5.0, 5.0, 5.0, 5.0, 3.0, 8.0]), np.array([1, 1, 1, 1, 0.3, 2]) * 1e-6
    wall = ContactWall(np.zeros(6), ["linear", "power", "hunt_crossley", "mount_hertz",
                                     "mount_hertz", "mount_hertz"], k_ref, d_ref, n=1.37,
                       alpha=0.5, k_mount=k_ref * [1, 1, 1, 1.2, 4.0, 1.01])
    h = d_ref * 1e-5
    tangent = (wall.force(d_ref + h) - wall.force(d_ref - h)) / (2 * h)
    np.testing.assert_allclose(tangent, k_ref, rtol=1e-7)
    mount = wall.law == 3
    delta = np.linspace(0.0, 5e-6, 11)[None] * np.ones((6, 1))
    f = wall.force(delta)[mount]
    k_h = hertz_constant(k_ref[mount], d_ref[mount], wall.k_mount[mount])
    back = f / wall.k_mount[mount, None] + (f / k_h[:, None]) ** (2 / 3)
    np.testing.assert_allclose(back, delta[mount], rtol=1e-12, atol=1e-20)


def impact(load_kwargs):
    """A mass-like impact: one undamped mode (1 kg at the tip, 1 Hz) pushed by a step force
    from rest reaches its equilibrium u_s = g at v = ω₁ u_s and hits a wall whose contact
    frequency is 100 ω₁ (its spring and the drive act 1e-4 as much as the wall during the
    contact). Returns the energy the impact took (J, from ``H = v²/2 + ω₁²(u - u_s)²/2``,
    conserved away from the wall) and v."""
    w1, u_s = 2 * np.pi, 1e-4
    model = ModalTransducer(np.array([w1]), np.array([0.0]), np.array([1.0]), np.array([1.0]))
    fs = 2e5
    n = int(0.3 * fs)
    out = model.simulate(np.full(n, w1**2 * u_s), 1 / fs, ContactWall([u_s], **load_kwargs),
                         dtype=np.float64)
    edges = np.flatnonzero(np.diff(out["contact"][0].astype(int)))
    assert len(edges) == 2  # one touch and one release within the record
    after = edges[1] + 5
    h = out["v"][0] ** 2 / 2 + w1**2 * (out["u"][0] - u_s) ** 2 / 2
    assert abs(h[0] - w1**2 * u_s**2 / 2) == 0.0
    return h[0] - h[after], w1 * u_s


def test_energy_dissipated_per_impact_matches_closed_forms():
    """Hunt–Crossley (any n): ``ΔE = (2/3) α m v³`` to first order in αv; a damped linear
    contact (``ζ = c / (2 √(k m))``), released when its force ``k δ + c δ'`` turns tensile:
    ``ΔE = m (v² - δ'(t_r)²) / 2`` with ``δ'(t_r) = v e^{-ζω t_r}(cos ω_d t_r - ζω/ω_d sin ω_d
    t_r)`` and ``ω_d t_r = π - atan(2ζ ω_d / (ω (1 - 2ζ²)))``."""
    wc, d_ref = 200 * np.pi, 1e-6
    for n in (1.0, 1.5):
        loss, v = impact({"law": "hunt_crossley", "k_ref": wc**2, "delta_ref": d_ref, "n": n,
                          "alpha": 1.0})
        assert abs(loss / (2 / 3 * 1.0 * v**3) - 1) < 2e-3, (n, loss / (2 / 3 * v**3))
    zeta = 0.05
    loss, v = impact({"law": "linear", "k_ref": wc**2, "damping": 2 * zeta * wc})
    wd = wc * np.sqrt(1 - zeta**2)
    tr = (np.pi - np.arctan(2 * zeta * wd / (wc * (1 - 2 * zeta**2)))) / wd
    v_out = v * np.exp(-zeta * wc * tr) * (np.cos(wd * tr) - zeta * wc / wd * np.sin(wd * tr))
    want = (v**2 - v_out**2) / 2
    assert abs(loss / want - 1) < 5e-3, loss / want


STEP_LAWS = [("linear", {}), ("power", {"n": 1.5}), ("hunt_crossley", {"n": 1.5, "alpha": 1.0}),
             ("mount_hertz", {"k_mount": 7.0})]


def halving(model, law, kwargs, factors=(1, 2, 4), fine=16):
    """Max error of u and F over a fast whisk into a wall (g = 4 µm, k_ref = 5 N/m at
    δ_ref = 1 µm) at the steps ``dt/f`` against ``dt/fine``, relative to their maxima."""
    load = ContactWall([4e-6], law, 5.0, 1e-6, **kwargs)
    ref = run(model, load, FS * fine, seconds=800 / FS)
    errs = []
    for f in factors:
        got = run(model, load, FS * f, seconds=800 / FS)
        errs.append([np.abs(got[key][0] - ref[key][0, ::fine // f]).max()
                     / np.abs(ref[key]).max() for key in ("u", "force")])
    return np.array(errs)


@pytest.mark.parametrize("law,kwargs", STEP_LAWS, ids=[x[0] for x in STEP_LAWS])
def test_step_halving_converges_at_second_order(micro, law, kwargs):
    """The force held linearly over the step and solved at its end (trapezoidal in F): errors
    at dt, dt/2, dt/4 (26880 Hz down) against dt/16 fall by ~4 per halving."""
    errs = halving(micro, law, kwargs)
    ratio = errs[:-1] / errs[1:]
    assert np.all(ratio > 3.3) and np.all(ratio < 5.5), (errs, ratio)


def reference_steps(model, e, de, dt, wall):
    """The slow reference: each record on its own with its own exact step of
    ``[q, q', E, Ė, F, Ḟ]`` (``expm``, no eigenbasis), F linear over each step, and the force
    at each sample from brentq on ``F - f(δ(F), δ'(F))``. Returns u, v, F, i ``(B, n)``."""
    n_m, bsz, n = model.n_modes, wall.batch, len(e)
    a_r, b_r, d_r = model.residual
    a = np.zeros((2 * n_m + 4,) * 2)
    a[:n_m, n_m:2 * n_m] = np.eye(n_m)
    a[n_m:2 * n_m, :n_m] = -np.diag(model.omega_n**2)
    a[n_m:2 * n_m, n_m:2 * n_m] = -np.diag(2 * model.zeta * model.omega_n)
    a[n_m:2 * n_m, 2 * n_m], a[n_m:2 * n_m, 2 * n_m + 2] = model.coupling, -model.tip
    a[2 * n_m, 2 * n_m + 1] = a[2 * n_m + 2, 2 * n_m + 3] = 1.0
    step = expm(a * dt)[:2 * n_m]
    slope = np.diff(e, append=e[-1]) / dt
    out = np.zeros((4, bsz, n))
    for b in range(bsz):
        x, f_prev = np.zeros(2 * n_m), 0.0
        g = wall.gap[b, 0]
        one = ContactWall([g], int(wall.law[b]), wall.k_ref[b], wall.delta_ref[b], wall.n[b],
                          wall.alpha[b], wall.k_mount[b], wall.damping[b])
        for k in range(n):
            def state(f, k=k, x=x, f_prev=f_prev):
                if k == 0:
                    return x
                z = np.concatenate([x, [e[k - 1], slope[k - 1], f_prev, (f - f_prev) / dt]])
                return step @ z

            def outputs(f, k=k, f_prev=f_prev, state=state):
                s = state(f)
                u = model.tip @ s[:n_m] + b_r * e[k] - a_r * f
                v = model.tip @ s[n_m:] + b_r * de[k] - a_r * (f - f_prev) / dt
                return s, u, v

            def residual(f, outputs=outputs, one=one, g=g):
                _, u, v = outputs(f)
                return f - one.force(np.array([u - g]), np.array([v]))[0]

            top = -residual(0.0)
            f = 0.0 if top <= 0 else brentq(residual, 0.0, top, xtol=1e-22, rtol=1e-15)
            x, u, v = outputs(f)
            cur = (model.coupling @ x[n_m:] + (model.capacitance + d_r) * de[k]
                   - b_r * (f - f_prev) / dt)
            out[:, b, k], f_prev = (u, v, f, cur), f
    return out


def test_numba_stepper_matches_the_slow_per_record_reference(micro):
    """Every law, damped and undamped, a wall the tip rests past, through many touches."""
    e, de = whisk(FS, seconds=0.021, whisk_hz=20.0)
    wall = ContactWall([3e-6, 4e-6, 2e-6, 5e-6, -0.2e-6], list(LAWS) + ["power"],
                       [5.0, 3.0, 8.0, 5.0, 5.0], [1e-6, 2e-6, 0.5e-6, 1e-6, 1e-6],
                       n=[1.0, 1.5, 1.2, 1.0, 1.3], alpha=[0.0, 0.0, 0.7, 0.0, 0.0],
                       k_mount=[np.inf, np.inf, np.inf, 10.0, np.inf],
                       damping=[2e-4, 0.0, 0.0, 0.0, 0.0])
    ref = reference_steps(micro, e, de, 1 / FS, wall)
    got = micro.simulate(e, 1 / FS, wall, drive_rate=de, dtype=np.float64)
    assert np.all((ref[2] > 0).sum(1) > 50)
    np.testing.assert_array_equal(got["contact"], ref[2] > 0)
    for j, key in enumerate(("u", "v", "force", "i")):
        scale = np.abs(ref[j]).max(1, keepdims=True)
        assert np.all(np.abs(got[key] - ref[j]) <= 1e-9 * scale), key


def test_linear_law_approaches_the_exact_switched_wall(micro):
    """The undamped linear law against :class:`Wall` (exact between switches, switching at
    samples): at the scene's 26880 Hz u within 2e-3 and F within 2e-2 of their maxima, and the
    difference falls at least 3× per halving; damped (c up to 3e-4 N·s/m, a relaxation of
    ``c a_r / (1 + k a_r)`` ≈ 1 µs that the implicit step takes as backward Euler) u within
    1e-3 and falling."""
    gaps, k = [2e-6, 5e-6, 8e-6], [5.0, 3.0, 8.0]
    diffs = []
    for f in (1, 2, 4):
        e, de = whisk(FS * f, seconds=0.2, whisk_hz=2.0)
        rows = []
        for c in (0.0, 3e-4):
            a = micro.simulate(e, 1 / (FS * f), Wall(gaps, k, c), drive_rate=de,
                               dtype=np.float64)
            b = micro.simulate(e, 1 / (FS * f), ContactWall(gaps, "linear", k, damping=c),
                               drive_rate=de, dtype=np.float64)
            assert a["contact"].sum(1).min() > 100 * f
            rows += [np.abs(a[key] - b[key]).max() / np.abs(a[key]).max() for key in ("u", "force")]
        diffs.append(rows)
    diffs = np.array(diffs)  # (step, [u, F undamped, u, F damped])
    assert diffs[0, 0] < 2e-3 and diffs[0, 1] < 2e-2 and diffs[0, 2] < 1e-3, diffs
    assert np.all(diffs[:-1, :2] / diffs[1:, :2] > 3.0), diffs
    assert np.all(diffs[1:, 2] < diffs[:-1, 2]), diffs


def test_a_time_varying_gap_held_still_is_the_fixed_gap(micro):
    e, _ = whisk(FS, seconds=0.02)
    fixed = ContactWall([3e-6, 4e-6], "power", 5.0, 1e-6, n=1.4)
    moving = ContactWall(np.array([[3e-6], [4e-6]]) * np.ones(len(e)), "power", 5.0, 1e-6,
                         n=1.4)
    a, b = (micro.simulate(e, 1 / FS, w, dtype=np.float64) for w in (fixed, moving))
    assert a["contact"].any()
    for key in a:
        np.testing.assert_array_equal(a[key], b[key])
    with pytest.raises(ValueError, match="gap: shape"):
        micro.simulate(e, 1 / FS, ContactWall(np.zeros((2, 7)), "power", 5.0))


def test_contact_wall_refuses_bad_parameters():
    with pytest.raises(ValueError, match="law: unknown"):
        ContactWall([0.0], "hertz", 5.0)
    with pytest.raises(ValueError, match="n must be in"):
        ContactWall([0.0], "power", 5.0, n=2.0)
    with pytest.raises(ValueError, match="k_ref must be in"):
        ContactWall([0.0], "power", 0.0)
    with pytest.raises(ValueError, match="k_mount must be in"):
        ContactWall([0.0], "mount_hertz", 5.0, k_mount=4.0)
    with pytest.raises(ValueError, match="alpha must be in"):
        ContactWall([0.0], "hunt_crossley", 5.0, alpha=-0.1)
    with pytest.raises(ValueError, match="gap: finite"):
        ContactWall([np.nan], "linear", 5.0)


def test_the_scene_draws_laws_from_its_mixture_and_refuses_unknown_ones(tmp_path):
    from wtml.scenes import SceneError, load_scene

    path = tmp_path / "onset.yaml"
    path.write_text("task: onset\nwall:\n  law: {linear: 1.0, hertz: 1.0}\n")
    with pytest.raises(SceneError, match=r"wall.law: .*\['linear', 'power', 'hunt_crossley'"):
        load_scene(path)
    path.write_text("task: onset\nwall:\n  law: {power: 3, mount_hertz: 1, hunt_crossley: 0}\n")
    scene = load_scene(path)
    rng = np.random.default_rng(3)
    drawn = scene.draw_laws(4000, rng)
    share = np.bincount(drawn["law"], minlength=4) / 4000
    np.testing.assert_allclose(share, [0.0, 0.75, 0.0, 0.25], atol=0.03)
    power, mount = drawn["law"] == 1, drawn["law"] == 3
    w = scene.wall
    assert np.all((drawn["law_n"][power] >= w.power_n[0]) & (drawn["law_n"][power] <= 1.5))
    assert np.all(drawn["law_n"][mount] == 1.0) and np.all(drawn["law_alpha"] == 0.0)
    assert np.all((drawn["law_mount_fraction"][mount] >= w.mount_fraction[0])
                  & (drawn["law_mount_fraction"][mount] <= w.mount_fraction[1]))
    assert np.all(np.isfinite(drawn["law_delta_ref"]))
    # the default mixture (the linear wall alone) draws nothing: its records are unchanged
    path.write_text("task: onset\n")
    default = load_scene(path)
    before = rng.bit_generator.state
    drawn = default.draw_laws(5, rng)
    assert rng.bit_generator.state == before and np.all(drawn["law"] == 0)
    assert np.all(np.isnan(drawn["law_delta_ref"]))
