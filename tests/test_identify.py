"""Identification of a device from its measurements (wtml.physics.identify, physics.md §13).

Every "measurement" here is simulated: a hidden "true" device is the micro preset with some
named parameters off by 5–15 %, its Ze computed by the beam model and given circular complex
noise (``wtml.signals.noise.complex_noise``) at the stated relative level.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from wtml.devices import load_device
from wtml.files import FileError, sha256
from wtml.physics.beam_presets import build, sphere_mass
from wtml.physics.identify import (
    IdentificationError,
    contact_ze,
    fit_device,
    free_ze,
    nominal_values,
    with_segment_losses,
    with_tip_mass,
)
from wtml.physics.measured import (
    ContactSweep,
    Measurements,
    Sweep,
    read_csv,
    read_s1p,
    read_sweep,
    write_csv,
    write_s1p,
)
from wtml.signals.noise import complex_noise

TRUTH = {"bimorph.length": 1.08, "coupling": 0.92, "loss_factor": 1.12, "tan_delta": 0.90}
"""The hidden device: 8 % longer bimorph, 8 % weaker coupling, 12 % more structural loss and
10 % less dielectric loss than the micro preset (the fit's starting point, factor 1)."""
FREE = {"bimorph.length": (0.8, 1.2), "coupling": (0.8, 1.2), "loss_factor": (0.5, 2.0),
        "tan_delta": (0.5, 2.0)}
WIDE = np.geomspace(250, 3000, 300)
"""Through the first two bimorph modes (≈343 and ≈2170 Hz on the true device) and the
whisker's own mode (≈1556 Hz, k² ≈ 1e-3: visible at 1e-4 noise)."""
NARROW = np.geomspace(200, 1000, 200)
"""Through the first resonance only (the whisker mode is outside)."""


def micro(factors):
    return build("micro", factors=factors)


def measure(tr, f, sigma, rng, contacts=()):
    free = Sweep(f, complex_noise(free_ze(tr, 2 * np.pi * f), sigma, rng), sigma=sigma)
    pins = tuple(ContactSweep(d, Sweep(f, complex_noise(contact_ze(tr, 2 * np.pi * f, d), sigma,
                                                        rng), sigma=sigma))
                 for d in contacts)
    return Measurements(free, contacts=pins)


@pytest.fixture(scope="module")
def in_family():
    """The true device in the fit's own model family (one loss factor), 1e-4 noise, fitted
    from factor 1."""
    rng = np.random.default_rng(0)
    m = measure(micro(TRUTH), WIDE, 1e-4, rng)
    return fit_device(micro, FREE, m, nominal=nominal_values("micro"))


def test_fitted_back_within_standard_errors(in_family):
    fit = in_family
    for name, value in TRUTH.items():
        err = fit.factors[name] - value
        assert abs(err) < 3 * fit.standard_errors[name], (name, err, fit.standard_errors[name])
        assert fit.standard_errors[name] < 0.01  # all four determined to better than 1 %
    assert 0.7 < fit.reduced_chi2 < 1.3  # the stated 1e-4 is the noise


def test_other_loss_model_is_fitted_back_where_it_can_be():
    """The truth's whisker has its own loss factor (0.035, against the bimorph's 0.0224): a
    loss model the fit (one loss factor for every segment) cannot follow. What the test
    claims, measured: the geometry, coupling and tanδ come back within 2 standard errors
    (those grow with the misfit, s² ≫ 1 says it); the one loss factor comes back as the
    bimorph's (the whisker's own mode, k² ≈ 1e-3, weighs little), within 1 % of it."""
    rng = np.random.default_rng(1)
    true = with_segment_losses(micro(TRUTH), {"whisker": 0.035})
    fit = fit_device(micro, FREE, measure(true, WIDE, 1e-4, rng), vector_fit=False)
    for name in ("bimorph.length", "coupling", "tan_delta"):
        assert abs(fit.factors[name] - TRUTH[name]) < 2 * fit.standard_errors[name], name
    assert fit.factors["loss_factor"] == pytest.approx(TRUTH["loss_factor"], rel=0.01)
    assert fit.reduced_chi2 > 10  # the model-form misfit shows, and is said
    assert any(n.startswith("reduced χ²") and "does not follow" in n for n in fit.notes)


def test_standard_errors_cover_the_truth_at_their_nominal_rate():
    """40 noise draws at 1e-4 relative, each fitted (from the truth: the minimum, not the
    path, is under test). Of the 160 normalised errors (fit - truth)/SE, a Gaussian puts 68 %
    within 1 and 95 % within 2; allowed: 55–82 % and ≥ 88 % (160 draws, four per repeat and
    correlated, give a binomial spread of ~4 points on the first; the floor of the variance at
    the stated noise, max(s², 1), can only over-cover)."""
    rng = np.random.default_rng(7)
    f = np.geomspace(250, 3000, 200)
    clean = free_ze(micro(TRUTH), 2 * np.pi * f)
    z = []
    for _ in range(40):
        m = Measurements(Sweep(f, complex_noise(clean, 1e-4, rng), sigma=1e-4))
        fit = fit_device(micro, FREE, m, start=TRUTH, smoothing=(), vector_fit=False)
        z += [(fit.factors[n] - TRUTH[n]) / fit.standard_errors[n] for n in FREE]
    z = np.abs(np.array(z))
    assert 0.55 <= (z < 1).mean() <= 0.82
    assert (z < 2).mean() >= 0.88


WHISKER_TRUTH = {"bimorph.length": 1.05, "whisker.length": 1.06, "whisker.modulus": 0.93}
WHISKER = {"whisker.length": (0.8, 1.2), "whisker.modulus": (0.8, 1.2),
           "whisker.thickness": (0.8, 1.2)}


def test_unidentifiable_request_is_refused_naming_the_parameter():
    """A sweep through the first resonance only (200–1000 Hz), at an impedance analyser's
    1e-3: the whisker is seen only as a load on the bimorph's tip (its mass, ~2e-3 of the
    bimorph's, and a flexibility correction ~(f/1556 Hz)²), which does not separate its
    length, modulus and thickness: refused, naming the worst (measured: standard errors
    0.8–3 in factor units against a range 0.4 wide, the bimorph's length still 5e-5).
    What is *not* refused, measured: the whisker's length alone, even from this sweep (1 % at
    1e-3, 0.1 % at 1e-4: its mass shifts the resonance), and all three with a sweep through
    the whisker's own mode at 1e-4; the issue's example of an unidentifiable request (the
    whisker's length without contacts) is identifiable in wtml's physics at these noise
    levels."""
    rng = np.random.default_rng(2)
    m = measure(micro(WHISKER_TRUTH), NARROW, 1e-3, rng)
    free = {"bimorph.length": (0.8, 1.2)} | WHISKER
    with pytest.raises(IdentificationError,
                       match=r"^whisker\.(length|modulus|thickness): standard error") as err:
        fit_device(micro, free, m, vector_fit=False)
    line = str(err.value)
    assert "\n" not in line and "exceeds its range 0.8–1.2" in line
    fit = fit_device(micro, free, m, vector_fit=False, refuse=False)
    assert fit.unidentifiable[0] == line
    assert fit.standard_errors["bimorph.length"] < 1e-3  # the bimorph is still determined


def test_pins_at_known_places_identify_the_whisker():
    """Three rigid pins at 0.5, 1.5, 2.5 mm from the tip (the thesis's contacts), each
    stiffening the bimorph by ~3EI/(L-d)³, with the same narrow sweep at 1e-3: the whisker's
    length and modulus (thickness held) come back within 3 standard errors, each known to
    better than 0.1 % (measured: 5e-5 and 2e-4)."""
    rng = np.random.default_rng(3)
    m = measure(micro(WHISKER_TRUTH), NARROW, 1e-3, rng, contacts=(0.5e-3, 1.5e-3, 2.5e-3))
    free = {"bimorph.length": (0.8, 1.2), "whisker.length": (0.8, 1.2),
            "whisker.modulus": (0.8, 1.2)}
    fit = fit_device(micro, free, m, vector_fit=False)
    for name, value in WHISKER_TRUTH.items():
        assert abs(fit.factors[name] - value) < 3 * fit.standard_errors[name], name
        assert fit.standard_errors[name] < 1e-3, name
    assert fit.reduced_chi2 < 1.3


def test_tip_sphere_matters_on_the_fluid_device():
    """The fluid preset with its glass sphere, 3 % heavier than stated (a sphere's mass is known
    to a few % at best): held at the stated mass, the fit is biased beyond its standard error
    and its reduced χ² says so; with the tip mass's factor free (``"tip_mass"``) it comes back
    with the bimorph's length and coupling, each within 3 standard errors (measured: the
    sphere's mass to 1.4e-5)."""
    rng = np.random.default_rng(4)
    mass = sphere_mass("fluid")

    def fluid(factors):
        return build("fluid", factors=factors)

    truth = {"bimorph.length": 1.07, "coupling": 0.95, "tip_mass": 1.03}
    true = with_tip_mass(fluid({"bimorph.length": 1.07, "coupling": 0.95}), 1.03 * mass)
    m = measure(true, np.geomspace(40, 400, 200), 1e-4, rng)
    free = {"bimorph.length": (0.8, 1.2), "coupling": (0.8, 1.2)}
    held = fit_device(fluid, free, m, tip_mass=mass, vector_fit=False)
    assert held.reduced_chi2 > 10
    assert abs(held.factors["bimorph.length"] - 1.07) > 3 * held.standard_errors[
        "bimorph.length"]
    fit = fit_device(fluid, free | {"tip_mass": (0.8, 1.2)}, m, tip_mass=mass,
                     vector_fit=False)
    for name, value in truth.items():
        assert abs(fit.factors[name] - value) < 3 * fit.standard_errors[name], name
    assert fit.reduced_chi2 < 1.3
    si = fit.report()["parameters"]["tip_mass"]["si"]
    assert si["unit"] == "kg" and si["value"] == pytest.approx(1.03 * mass, rel=1e-3)
    with pytest.raises(IdentificationError, match=r"^free\.tip_mass: a factor of tip_mass"):
        fit_device(fluid, {"tip_mass": (0.8, 1.2)}, m)


def test_resonance_table_and_vector_fitting_agree(in_family):
    """Measured against fitted at each resonance and antiresonance of the free sweep (the
    same peak estimator on both: frequency within 2e-4, peak-width Q within 5 %, k² within
    1 %), and scikit-rf's rational fit of the measured sweep against the fitted device's own
    poles (the same quantity): within 5e-4 in frequency and 3 % in Q (measured: 3e-4 and
    1.3 % at worst, on the whisker's weak mode; 1e-5 and 0.3 % on the bimorph's)."""
    rows = in_family.table
    kinds = [r["kind"] for r in rows]
    assert kinds.count("resonance") >= 2 and kinds.count("antiresonance") >= 2
    for r in rows:
        assert r["fitted_hz"] == pytest.approx(r["measured_hz"], rel=2e-4)
        assert r["fitted_q"] == pytest.approx(r["measured_q"], rel=0.05)
        assert r["vf_hz"] == pytest.approx(r["pole_hz"], rel=5e-4)
        assert r["vf_q"] == pytest.approx(r["pole_q"], rel=0.03)
        if "measured_k2" in r:
            assert r["fitted_k2"] == pytest.approx(r["measured_k2"], rel=0.01)
    first = next(r for r in rows if r["kind"] == "resonance")
    assert first["measured_k2"] > 0.04  # the bimorph's first mode, k² ≈ 0.054


def test_report_is_json_with_provenance_and_a_bode_plot(tmp_path):
    rng = np.random.default_rng(5)
    tr = micro(TRUTH)
    ze = complex_noise(free_ze(tr, 2 * np.pi * NARROW), 1e-4, rng)
    path = write_csv(tmp_path / "free.csv", NARROW, ze)
    m = Measurements(read_csv(path, sigma=1e-4), hue0=tr.static_tip_displacement_per_volt(),
                     hue0_sigma=0.01)
    free = {"bimorph.length": (0.8, 1.2), "coupling": (0.8, 1.2)}
    fit = fit_device(micro, free, m, fixed={"loss_factor": 1.12, "tan_delta": 0.9},
                     nominal=nominal_values("micro"))
    report = json.loads(json.dumps(fit.report(), allow_nan=False))
    assert report["provenance"]["files"] == [{"role": "free", "path": str(path),
                                              "sha256": sha256(path)}]
    length = report["parameters"]["bimorph.length"]
    assert length["si"]["unit"] == "m"
    free_length = load_device("micro").bimorph.free_length
    assert length["si"]["value"] == pytest.approx(length["factor"] * free_length)
    assert report["residual_rms"]["hue0"] < 0.01
    png = fit.plot(tmp_path / "bode.png")
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


@pytest.mark.parametrize("form", ["ri", "ma"])
def test_csv_round_trip(tmp_path, form):
    ze = free_ze(micro({}), 2 * np.pi * NARROW)
    got = read_sweep(write_csv(tmp_path / "z.csv", NARROW, ze, form=form))
    np.testing.assert_array_equal(got.frequency_hz, NARROW)
    np.testing.assert_allclose(got.ze, ze, rtol=1e-14)


def test_s1p_round_trip(tmp_path):
    ze = free_ze(micro({}), 2 * np.pi * NARROW)
    path = write_s1p(tmp_path / "z.s1p", NARROW, ze)
    got = read_sweep(path)
    np.testing.assert_allclose(got.frequency_hz, NARROW, rtol=1e-15)
    np.testing.assert_allclose(got.ze, ze, rtol=1e-13)
    assert got.sha256 == sha256(path)
    # an S-parameter file at 50 Ω (what most analysers write) reads as the same Ze
    s = (ze - 50) / (ze + 50)
    text = "# Hz S RI R 50\n" + "".join(f"{float(f)!r} {float(v.real)!r} {float(v.imag)!r}\n"
                                         for f, v in zip(NARROW, s, strict=True))
    (tmp_path / "s.s1p").write_text(text)
    np.testing.assert_allclose(read_s1p(tmp_path / "s.s1p").ze, ze, rtol=1e-6)


@pytest.mark.parametrize("text, message", [
    ("frequency_hz,re_ohm\n1,2\n", "the header must name frequency_hz with re_ohm, im_ohm"),
    ("frequency_hz,re_ohm,im_ohm\n1,2,3\n2,x,3\n", "line 3: column 're_ohm' = 'x' is not a number"),
    ("frequency_hz,re_ohm,im_ohm\n1,2,3\n2,3\n", "line 3: no value in column 'im_ohm'"),
    ("frequency_hz,re_ohm,im_ohm\n2,2,3\n1,2,3\n", "line 3: column 'frequency_hz' = 1 must be"),
    ("frequency_hz,re_ohm,im_ohm\n1,nan,3\n2,2,3\n", "line 2: column 're_ohm' = 'nan' must be "
                                                     "finite"),
    ("frequency_hz,magnitude_ohm,phase_deg\n1,-2,3\n2,2,3\n", "line 2: column 'magnitude_ohm'"),
    ("# comment only\n", "empty"),
    ("frequency_hz,re_ohm,im_ohm\n1,2,3\n", "1 data line(s)"),
])
def test_csv_refusals_name_file_line_and_column(tmp_path, text, message):
    path = tmp_path / "bad.csv"
    path.write_text(text)
    with pytest.raises(FileError) as err:
        read_csv(path)
    line = str(err.value)
    assert line.startswith(f"{path}: ") and message in line and "\n" not in line


def test_s1p_refusals_are_one_line(tmp_path):
    bad = tmp_path / "bad.s1p"
    bad.write_text("# Hz S RI R 50\n1 0.1\nnot numbers at all\n")
    with pytest.raises(FileError) as err:
        read_s1p(bad)
    assert str(err.value).startswith(f"{bad}: ") and "\n" not in str(err.value)
    two = tmp_path / "two.s2p"
    two.write_text("# Hz S RI R 50\n1 0 0 0 0 0 0 0 0\n")
    with pytest.raises(FileError, match="one-port .s1p"):
        read_s1p(two)
    with pytest.raises(FileError, match="no such Touchstone file"):
        read_s1p(tmp_path / "missing.s1p")
    with pytest.raises(FileError, match="must be .csv"):
        read_sweep(tmp_path / "z.txt")


def test_bad_requests_are_refused():
    m = Measurements(Sweep(NARROW, free_ze(micro({}), 2 * np.pi * NARROW)))
    with pytest.raises(IdentificationError, match=r"^free\.coupling: range must be"):
        fit_device(micro, {"coupling": (1.2, 0.8)}, m)
    with pytest.raises(IdentificationError, match=r"^fixed\.coupling: is also free"):
        fit_device(micro, {"coupling": (0.8, 1.2)}, m, fixed={"coupling": 1.0})
    with pytest.raises(FileError, match="strictly increasing"):
        Sweep(NARROW[::-1], np.ones(NARROW.size))


def test_clamped_sweep_and_tip_velocity_enter_the_fit():
    """A clamped-tip sweep and the tip velocity per volt at three frequencies (a vibrometer,
    1 %) alongside the free sweep: every term is fitted (each residual at its noise) and the
    truth comes back within 3 standard errors; a tip velocity 10 % off the device's is
    answered by a larger reduced χ² and its own residual (the sweeps, 800 points at 1e-4,
    keep the parameters), not hidden."""
    from wtml.physics.identify import clamped_ze
    from wtml.physics.measured import TipVelocity
    from wtml.physics.twoport import drive_voltage

    rng = np.random.default_rng(6)
    tr = micro(TRUTH)
    fv = np.array([100.0, 343.0, 600.0])
    v = drive_voltage(tr.transduction_matrix(2 * np.pi * fv), 0.0, 1.0)[1]
    base = measure(tr, NARROW, 1e-4, rng)
    clamped = Sweep(NARROW, complex_noise(clamped_ze(tr, 2 * np.pi * NARROW), 1e-4, rng),
                    sigma=1e-4)
    m = Measurements(base.free, clamped=clamped, tip_velocity=TipVelocity(fv, v, sigma=0.01))
    fit = fit_device(micro, FREE, m, vector_fit=False)
    for name, value in TRUTH.items():
        assert abs(fit.factors[name] - value) < 3 * fit.standard_errors[name], name
    rms = fit.residual_rms()
    assert set(rms) == {"free", "clamped", "tip_velocity"}
    assert rms["clamped"] < 3e-4 and rms["tip_velocity"] < 1e-3
    off = Measurements(base.free, clamped=clamped, tip_velocity=TipVelocity(fv, 1.1 * v))
    worse = fit_device(micro, FREE, off, vector_fit=False)
    # three terms ~9.5σ off among ~800 residuals: +0.34 on the reduced χ² (0.98 -> 1.32)
    assert worse.reduced_chi2 > fit.reduced_chi2 + 0.2
    assert worse.residual_rms()["tip_velocity"] > 0.03


def test_load_measurements_from_files(tmp_path):
    """Every input of §2 from files (a free .csv, a clamped .s1p, a pin's sweep, a tip
    velocity CSV), their sha256 in the report's provenance; a bad tip velocity refused with
    one line naming the line and column."""
    from wtml.physics.identify import clamped_ze
    from wtml.physics.measured import load_measurements, read_tip_velocity

    tr = micro({})
    w = 2 * np.pi * NARROW
    free = write_csv(tmp_path / "free.csv", NARROW, free_ze(tr, w))
    clamped = write_s1p(tmp_path / "clamped.s1p", NARROW, clamped_ze(tr, w))
    pin = write_csv(tmp_path / "pin.csv", NARROW, contact_ze(tr, w, 1e-3, 2e4), form="ma")
    tip = tmp_path / "tip.csv"
    tip.write_text("# vibrometer\nfrequency_hz,velocity_m_s_per_v\n100,2.1e-4\n300,1.1e-3\n")
    m = load_measurements(free, sigma=1e-4, clamped=clamped, contacts=[(1e-3, pin, 2e4)],
                          tip_velocity=tip, hue0=1.3e-6)
    assert m.contacts[0].stiffness == 2e4 and m.clamped.sigma == 1e-4
    np.testing.assert_allclose(m.contacts[0].sweep.ze, contact_ze(tr, w, 1e-3, 2e4),
                               rtol=1e-13)
    assert [f["role"] for f in m.files()] == ["free", "clamped", "contact at 1 mm",
                                              "tip velocity"]
    assert all(f["sha256"] == sha256(f["path"]) for f in m.files())
    tip.write_text("frequency_hz,velocity_m_s_per_v\n100,-2e-4\n")
    with pytest.raises(FileError, match=r"tip\.csv: line 2: column 'velocity_m_s_per_v' = "
                                        r"-0\.0002 must be > 0$"):
        read_tip_velocity(tip)
    with pytest.raises(ValueError, match=r"^contacts\[0\]: give \(distance_m, path\)"):
        load_measurements(free, contacts=[(1e-3,)])


def test_a_parameter_the_measurements_do_not_see_is_refused_as_singular():
    """A model in which a free parameter changes nothing (here a ``make`` that ignores the
    coupling) has a zero column in J: JᵀJ is singular and the refusal names that parameter."""
    m = Measurements(Sweep(NARROW, free_ze(micro({}), 2 * np.pi * NARROW), sigma=1e-4))

    def blind(factors):
        return micro({k: v for k, v in factors.items() if k != "coupling"})

    with pytest.raises(IdentificationError, match=r"^coupling: JᵀJ is singular"):
        fit_device(blind, {"bimorph.length": (0.8, 1.2), "coupling": (0.8, 1.2)}, m,
                   vector_fit=False)


@pytest.mark.slow
def test_every_micro_parameter_from_a_wide_sweep_and_three_pins():
    """All nine named parameters of the micro device free, each 5–15 % off: a sweep through
    the whisker's own mode (250–3000 Hz) at 1e-4 and three rigid pins identify every one
    (measured on three random devices: standard errors 2e-6 to 5e-4, the truth within 3 of
    them, 9–17 s a fit)."""
    from wtml.physics.beam_presets import device_parameters

    rng = np.random.default_rng(12)
    names = list(device_parameters("micro"))
    free = {n: (0.8, 1.25) for n in names} | {"loss_factor": (0.5, 2.0),
                                                "tan_delta": (0.5, 2.0)}
    truth = {n: 1 + rng.choice([-1, 1]) * rng.uniform(0.05, 0.15) for n in names}
    m = measure(micro(truth), WIDE, 1e-4, rng, contacts=(0.5e-3, 1.5e-3, 2.5e-3))
    fit = fit_device(micro, free, m, vector_fit=False)
    for name, value in truth.items():
        assert abs(fit.factors[name] - value) < 3 * fit.standard_errors[name], name
        assert fit.standard_errors[name] < 1e-3, name
