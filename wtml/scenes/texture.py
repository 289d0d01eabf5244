"""The texture scene: the macro WT's tip sweeping sandpaper (thesis §4.5, physics.md §11).

The macro WT is driven at ``whisk_v`` volts and ``whisk_hz`` (nominal 10 V at 36 Hz); its tip
slides on a specimen under a normal force N at a contact angle θ, with the friction of
:mod:`wtml.physics.friction`. The friction law's dependence on the mean grain size d is stated
here and fitted to the thesis (:func:`fit_friction_law`, printed by ``wtml fidelity``):

    μ(d) = mu_0 + mu_per_um · d/µm,     a(d) = asperity · d / 35 µm

Each specimen (``specimens_per_grade`` per grade per shard, so a shard's specimens are its own
and a split by shard holds out specimens) draws its own Coulomb coefficient
(``μ(d) + N(0, mu_spread)``), asperity factor (log-normal ``asperity_spread``), grain-size
spread and grain positions. Each record draws the nuisance: whisking amplitude and frequency,
N, θ, and the device's coupling (calibration error, times the temperature drift of
``acquisition.effects``). Both channels go through a 24-bit ADC with noise and the effects of
:mod:`wtml.signals.acquisition`; the current through an I-V converter.

Manufacturing spread (``spread``, :class:`~wtml.physics.spread.DeviceSpread`): each record's
transducer is drawn around the preset (``min(device.devices, n)`` devices per call of
:meth:`TextureScene.simulate`, records assigned to them at random), each its own modal model
``ModalTransducer.from_beam(build(preset, factors=...), n_modes)`` (its whisker in
:attr:`TextureScene.whisker_elements` elements). The user calibrates their
own device (physics.md §4), so each record carries its device's calibrated T at the
calibration frequencies (:attr:`TextureScene.calibration_hz`, or a decoder's where
:meth:`TextureScene.simulate` is given them) as ``t`` ``(n, K, 2, 2)``: the
decoder's input; the calibration error and the temperature drift stay on top of it. All widths
zero (the default) draws nothing: the records are today's, bit for bit.

Each specimen also draws its friction law from the mixture ``friction.law`` (Coulomb, Stribeck
or LuGre, each with its own line μ_c(d) fitted to Table 4.10 and its shape drawn as nuisance:
:class:`StribeckLaw`, :class:`LuGreLaw`; and with ``friction.viscous_span`` its own viscous
part c, each line moved with c so that the tip's speeds still meet Table 4.10:
:class:`FrictionLaw`).

``grades: thesis`` holds the five sandpapers of the thesis as classes; ``grades: fepa`` the ten
other FEPA P-grades (the regression test of unseen grain sizes; their class label is -1).
Labels: ``grade`` (class index), ``grain_m`` (the grade's mean grain size, m), ``specimen``
(an id unique within the dataset), and the nuisance drawn (``friction_law``: the law's code,
its index in :data:`~wtml.physics.friction.LAWS`). Stored: ``e`` (V) and ``i`` (A)
float32 ``(n, n_samples)``, 2 × 4 bytes × 51200 = 410 kB per 1 s record.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from typing import ClassVar

import numpy as np
from scipy.signal import resample_poly

from wtml.device_calibration import StoredCalibration
from wtml.devices import BeamDevice, shipped
from wtml.interface import OutputRange
from wtml.physics.beam import BeamTransducer
from wtml.physics.beam_presets import build, whisker_mesh_error
from wtml.physics.friction import (
    LAWS,
    Friction,
    grains,
    holds_slope,
    largest_stable_slope,
    pad_grains,
)
from wtml.physics.modal import ModalTransducer
from wtml.physics.spread import DeviceSpread, draw_factors
from wtml.physics.twoport import flat_parts
from wtml.scenes.onset import Acquisition, check_shard_memory
from wtml.schema import SceneError, bounded, field_range, mixture, one_of, overrides
from wtml.signals.excitation import lead_in

THESIS_GRADES = {"P1200": 15.3, "P800": 21.8, "P400": 35.0, "P320": 46.2, "P280": 52.2}
"""The five specimens of the thesis (Table 4.9): mean grain size, µm."""
FEPA_GRADES = {"P2500": 8.4, "P2000": 10.3, "P1500": 12.6, "P1000": 18.3, "P600": 25.8,
               "P500": 30.2, "P360": 40.5, "P240": 58.5, "P220": 68.0, "P180": 82.0}
"""The other FEPA P-grades (physics.md §11), unseen in training: mean grain size, µm."""
TABLE_4_10_RMS_SPEED = {"P1200": 0.361, "P800": 0.335, "P400": 0.293, "P320": 0.242,
                        "P280": 0.213}
"""The thesis's RMS tip speed per grade at 10 V, 36 Hz (Table 4.10), m/s."""
NOMINAL_V, NOMINAL_HZ, NOMINAL_N, NOMINAL_ANGLE_DEG = 10.0, 36.0, 3.3e-4, 10.0
"""The thesis's set-up (§4.5): drive amplitude V, whisking frequency Hz, normal force N and
contact angle, degrees."""


@dataclass(frozen=True)
class TextureDrive:
    """Whisking voltage amplitude (V) and frequency (Hz) ranges (uniform; nominal 10 V at
    36 Hz), the recorded length and the unrecorded lead-in (raised-cosine ramp), s."""

    whisk_v: tuple[float, float] = bounded(0.1, 200.0, default=(8.0, 12.0))
    whisk_hz: tuple[float, float] = bounded(1.0, 1e3, default=(35.0, 37.0))
    record_s: float = bounded(0.05, 10.0, default=1.0)
    lead_s: float = bounded(0.0, 5.0, default=1.0)


@dataclass(frozen=True)
class Contact:
    """Normal force (N) and contact angle (degrees) ranges (uniform)."""

    normal_force: tuple[float, float] = bounded(0.0, 1.0, default=(2.5e-4, 4.1e-4))
    angle_deg: tuple[float, float] = bounded(0.0, 80.0, default=(5.0, 15.0))


@dataclass(frozen=True)
class StribeckLaw:
    """The Stribeck law ``μ(v) = μ_c + (μ_s − μ_c) exp(−(v/v_s)²)`` (physics.md §12): its own
    line ``μ_c(d) = mu_0 + mu_per_um · d/µm`` (fitted to Table 4.10 at the nominal set-up by
    :func:`fit_friction_law` with the shape at the middle of its ranges) and each specimen's
    shape: ``static_ratio`` μ_s/μ_c (uniform) and ``stribeck_speed`` v_s (m/s, log-uniform),
    the ranges of physics.md §12. The default line is the fit's (intercept 0.4884, slope
    0.003875 /µm: the Coulomb law's to 1e-5, the tip sliding at ~100 v_s at the nominal set-up).
    ``mu_0_per_c`` and ``mu_per_um_per_c``: how the fitted line moves per N·s/m of viscous
    friction beyond the scene's ``viscous`` (:attr:`FrictionLaw.viscous_span`; the defaults
    are the secant of the fits at c = 0 and 1e-4, so they hold for ``viscous`` 0 and a span up
    to ~2e-4 (the fit at 2e-4 is within 0.005 of the secant's line): less Coulomb friction
    for the same tip speeds).
    """

    mu_0: float = bounded(-1.0, 2.0, default=0.488)
    mu_per_um: float = bounded(-1.0, 1.0, default=0.0039)
    mu_0_per_c: float = bounded(-1e5, 1e5, default=-1202.0)
    mu_per_um_per_c: float = bounded(-1e4, 1e4, default=10.42)
    static_ratio: tuple[float, float] = bounded(1.0, 3.0, default=(1.0, 1.5))
    stribeck_speed: tuple[float, float] = bounded(1e-5, 1.0, default=(1e-3, 1e-2))


@dataclass(frozen=True)
class LuGreLaw(StribeckLaw):
    """The LuGre law (physics.md §12) on the Stribeck curve: as :class:`StribeckLaw`, and each
    specimen's bristles: ``presliding_m``, the pre-sliding distance ``μ_s N cos θ / σ0`` at
    the nominal N and θ (m, log-uniform; it sets the stiffness σ0, a property of the
    specimen), and ``bristle_damping`` σ1 (N·s/m, uniform: up to about 0.15 of the critical
    damping of a 1e3 N/m bristle on the tip's modal mass ``1/Σφb²`` ≈ 1 mg at 14 modes,
    0.63 mg at the 21 kept since 30 Nov: the range was chosen at 14). σ2 is ``viscous``.
    The default line is the fit's (intercept 0.4862, slope 0.003869 /µm), and its shift per c.
    """

    mu_0: float = bounded(-1.0, 2.0, default=0.486)
    mu_per_um: float = bounded(-1.0, 1.0, default=0.0039)
    mu_0_per_c: float = bounded(-1e5, 1e5, default=-1192.0)
    mu_per_um_per_c: float = bounded(-1e4, 1e4, default=10.40)
    presliding_m: tuple[float, float] = bounded(1e-9, 1e-4, default=(2e-8, 2e-6))
    bristle_damping: tuple[float, float] = bounded(0.0, 1.0, default=(0.0, 0.01))


UNSTABLE_STEP = "does not hold the explicit friction step"
"""What :meth:`TextureScene.check_stepped`'s refusal says of the device (callers that step
finer on it match it)."""
MESH_TOLERANCE = 0.005
"""The most a natural frequency below the scene's Nyquist may move when the whisker's finite
elements are doubled (:func:`~wtml.physics.beam_presets.whisker_mesh_error`): 0.5 %, a third
of what the device spread's moduli move them by."""
LUGRE_OVERSAMPLE = 4
"""The least ``oversample`` for LuGre records: the bristle rings on the tip at up to ~11 kHz
while it sticks (σ0 ≈ 1.4e4 N/m), excited by the grains at each reversal; at 102.4 kS/s
halving the step moves the current's fundamental by up to ~3 × a 0.25 s window's noise, at
204.8 kS/s by less than it."""


@dataclass(frozen=True)
class FrictionLaw:
    """The friction law against grain size (see the module docstring) and each specimen's
    deviations from it: ``mu_0`` and ``mu_per_um`` (the Coulomb law's line μ(d)), ``asperity``
    a at 35 µm, ``slip_speed`` v_s (m/s; the regularisation v_r of Coulomb and Stribeck),
    ``slip_span``: each Coulomb or Stribeck specimen's own v_r, log-uniform in ``[slip_speed /
    slip_span, slip_speed]`` (how sharply its force turns over at each reversal: the surface's
    pre-sliding compliance, a nuisance; 1: every specimen at ``slip_speed``),
    ``viscous`` c (N·s/m); ``viscous_span``: each specimen's own c, uniform in ``[viscous,
    viscous + viscous_span]``, its law's line moved by ``(c − viscous) · (mu_0_per_c +
    mu_per_um_per_c · d/µm)`` so that it still meets Table 4.10 (Table 4.10 fixes the
    fundamental's in-phase force, not the share of it that grows with speed: a nuisance the
    thesis's numbers leave open; 0: every specimen at ``viscous``); ``mu_spread`` (std of μ),
    ``asperity_spread`` (log-normal σ of a), ``grain_spread`` (range of the coefficient of
    variation of grain spacing and size).

    ``law``: the mixture each specimen's law is drawn from, ``{name: weight}`` over
    :data:`~wtml.physics.friction.LAWS` (default Coulomb only); ``stribeck`` and ``lugre``
    those laws' own lines and shapes. Every law has the same asperities.
    """

    mu_0: float = bounded(-1.0, 2.0, default=0.488)
    mu_per_um: float = bounded(-1.0, 1.0, default=0.0039)
    asperity: float = bounded(0.0, 10.0, default=0.2)
    slip_speed: float = bounded(1e-4, 1.0, default=0.01)
    slip_span: float = bounded(1.0, 100.0, default=1.0)
    viscous: float = bounded(0.0, 1.0, default=0.0)
    viscous_span: float = bounded(0.0, 2e-4, default=0.0)
    mu_0_per_c: float = bounded(-1e5, 1e5, default=-1202.0)
    mu_per_um_per_c: float = bounded(-1e4, 1e4, default=10.42)
    mu_spread: float = bounded(0.0, 0.5, default=0.005)
    asperity_spread: float = bounded(0.0, 1.0, default=0.08)
    grain_spread: tuple[float, float] = bounded(0.05, 1.5, default=(0.25, 0.4))
    law: dict = field(default_factory=lambda: {"coulomb": 1.0})
    stribeck: StribeckLaw = field(default_factory=StribeckLaw)
    lugre: LuGreLaw = field(default_factory=LuGreLaw)

    def check(self, path: str) -> None:
        pre = path + "." if path else ""
        mixture(pre + "law", self.law, LAWS)
        if self.viscous_span == 0:
            return
        for law in [law for law, weight in self.law.items() if weight > 0]:
            (mu_0, per_um), per_c = self.line(law), self.line_shift(law)
            least = min(mu_0 + per_um * d + self.viscous_span * (per_c[0] + per_c[1] * d)
                        for d in (min(FEPA_GRADES.values()), max(FEPA_GRADES.values())))
            if least <= 0:  # the line moved to the span's top is no friction there
                raise SceneError(f"{pre}viscous_span: at c = {self.viscous + self.viscous_span:g}"
                                 f" N·s/m {law}'s line moved by its per-c shift gives μ = "
                                 f"{least:.3g} <= 0 within the FEPA grades (8.4-82 µm); "
                                 "narrow the span")

    @property
    def weights(self) -> np.ndarray:
        """Each law's probability, in the order of :data:`LAWS`."""
        return mixture("friction.law", self.law, LAWS)

    def own(self, law: str):
        """What holds ``law``'s line: this law (Coulomb's), ``stribeck`` or ``lugre``."""
        return {"coulomb": self, "stribeck": self.stribeck, "lugre": self.lugre}[law]

    def line(self, law: str) -> tuple[float, float]:
        """``(mu_0, mu_per_um)`` of ``law``'s μ_c(d)."""
        return self.own(law).mu_0, self.own(law).mu_per_um

    def line_shift(self, law: str) -> tuple[float, float]:
        """``(mu_0_per_c, mu_per_um_per_c)``: how ``law``'s line moves per N·s/m of viscous
        friction beyond ``viscous``."""
        return self.own(law).mu_0_per_c, self.own(law).mu_per_um_per_c

    def shape(self, code: np.ndarray, rng: np.random.Generator | None) -> dict[str, np.ndarray]:
        """Each specimen's shape for its law ``code`` ``(n,)``: ``static_ratio``,
        ``stribeck_speed`` (m/s), ``presliding_m`` (m) and ``bristle_damping`` (N·s/m); drawn
        from ``rng`` (per specimen, uniform or log-uniform as documented), or with ``rng``
        None the middle of each range (the geometric one for the log-uniform). Coulomb
        specimens get μ_s/μ_c = 1; shapes a law does not use are its defaults' middles."""
        n = len(code)

        def draw(pair, log=False):
            lo, hi = (np.log(pair[0]), np.log(pair[1])) if log else pair
            x = rng.uniform(lo, hi, n) if rng is not None else np.full(n, 0.5 * (lo + hi))
            return np.exp(x) if log else x

        out = {}
        for key, log in (("static_ratio", False), ("stribeck_speed", True),
                         ("presliding_m", True), ("bristle_damping", False)):
            stri = draw(getattr(self.stribeck, key, getattr(self.lugre, key)), log)
            lug = draw(getattr(self.lugre, key), log)
            out[key] = np.where(code == 2, lug, stri)
        out["static_ratio"] = np.where(code == 0, 1.0, out["static_ratio"])
        out["slip_speed"] = (self.slip_speed * np.ones(n) if rng is None or self.slip_span == 1
                             else draw((self.slip_speed / self.slip_span, self.slip_speed), True))
        return out


@dataclass(frozen=True)
class TextureScene:
    """A texture scene (``configs/scenes/texture.yaml``)."""

    OUTPUTS: ClassVar[tuple[str, ...]] = ("grain", "log_sigma", "probabilities")
    """What a texture decoder returns per window: the mean grain size (m), the std of its
    natural log, and the five thesis grades' probabilities ``(batch, 5)``."""
    UNITS: ClassVar[dict[str, str]] = {"grain": "m", "log_sigma": "1", "probabilities": "1"}
    INPUT_KEYS: ClassVar[tuple[str, ...]] = ("e", "i", "t", "t")
    """The array each of :meth:`decoder_inputs` comes from."""

    name: str = "texture"
    task: str = one_of("texture", default="texture")
    seed: int = bounded(0, 2**32 - 1, default=0)
    samples: int = bounded(1, 10**7, default=240)
    shards: int = bounded(1, 10**5, default=6)
    grades: str = one_of("thesis", "fepa", default="thesis")
    specimens_per_grade: int = bounded(1, 1000, default=2)
    device: BeamDevice = field(default_factory=shipped("macro"))
    n_modes: int = bounded(1, 40, default=22)
    whisker_elements: int = bounded(1, 512, default=32)
    """The whisker's finite elements in the beam the modes come from: 32 hold the macro WT's
    modes below 25.6 kHz within 0.06 % of twice as many; the 8 of the other scenes left modes
    13-22 (9.6-29 kHz) 1.5-12 % high (checked: :data:`MESH_TOLERANCE`)."""
    reach_m: float = bounded(1e-4, 0.1, default=5e-3)
    drive: TextureDrive = field(default_factory=TextureDrive)
    contact: Contact = field(default_factory=Contact)
    friction: FrictionLaw = field(default_factory=FrictionLaw)
    acquisition: Acquisition = overrides(lambda: Acquisition(
        sample_rate_hz=51200.0, e_full_scale_v=20.0, i_full_scale_a=1e-4, e_noise_v=1e-4,
        i_noise_a=2e-8))
    """The texture bench's acquisition; a scene's ``acquisition:`` changes only the keys it
    names (:func:`~wtml.schema.overrides`)."""
    calibration_error: float = bounded(0.0, 0.2, default=0.01)
    spread: DeviceSpread = field(default_factory=DeviceSpread)
    calibration: StoredCalibration | None = None
    """The device's own calibration (``wtml calibrate``'s ``.npz``, over
    :attr:`calibration_hz`): the T every record carries, instead of the model's with
    ``calibration_error``; the records still come from the device's model."""
    oversample: int = bounded(1, 16, default=2)
    """The simulation steps at ``oversample`` × the sampling rate (the asperities' impulses
    land on the step grid: at 102.4 kS/s halving the step moves the current's phasor by less
    than a 0.25 s window's noise, at 51.2 kS/s by about twice it); records are then decimated
    by a polyphase FIR (``scipy.signal.resample_poly``)."""

    @staticmethod
    def decoder_inputs(arrays: Mapping[str, np.ndarray]) -> tuple[np.ndarray, ...]:
        """What the decoder takes, from a dataset's (or :meth:`simulate`'s) arrays: ``e``
        (V), ``i`` (A), each ``(n, n_samples)``, and each record's calibrated T at the
        frequencies it was made with (the scene's :attr:`calibration_hz` unless
        :meth:`simulate` was given others) as ``t_re, t_im`` ``(n, n_cal, 4)`` float32 (t11, t12,
        t21, t22)."""
        return arrays["e"], arrays["i"], *flat_parts(arrays["t"])

    @staticmethod
    def targets(arrays: Mapping[str, np.ndarray]) -> np.ndarray:
        """The training targets, ``(n, 2)``: the grade's class index and the grain size, m."""
        return np.stack([arrays["grade"], arrays["grain_m"]], -1)

    @staticmethod
    def target_keys(n_targets: int) -> tuple[str, ...]:
        """The array each of the ``n_targets`` columns of :meth:`targets` comes from."""
        return ("grade", "grain_m")

    def check(self, path: str) -> None:
        pre = path + "." if path else ""
        if self.calibration is not None:
            self.calibration.check_scene(pre, "calibration", "calibration_error",
                                         self.calibration_error, not self.spread.none,
                                         self.calibration_hz)
        self.spread.check_device(pre, self.device)
        if self.shards > self.samples:
            raise SceneError(f"{pre}shards: {self.shards} shards for {self.samples} samples; "
                             "must be <= samples")
        check_shard_memory(pre, self.samples, self.shards, self.n_samples, self.oversample)
        if self.drive.lead_s * self.acquisition.sample_rate_hz < 64:
            raise SceneError(f"{pre}drive.lead_s: at least 64 samples "
                             f"({64 / self.acquisition.sample_rate_hz:g} s) for the decimation")
        if self.friction.law.get("lugre", 0) > 0 and self.oversample < LUGRE_OVERSAMPLE:
            raise SceneError(f"{pre}oversample: LuGre friction (friction.law.lugre > 0) needs "
                             f"oversample >= {LUGRE_OVERSAMPLE} (its bristle resolved), got "
                             f"{self.oversample}")
        f, least = self.friction, self.least_slip_speed()
        if f.slip_speed / f.slip_span < least * (1 - 1e-9):
            key = "slip_span" if f.slip_span > 1 else "slip_speed"
            raise SceneError(f"{pre}friction.{key}: the least v_r, slip_speed/slip_span = "
                             f"{f.slip_speed / f.slip_span:g} m/s, must be "
                             f">= {least:.3g} m/s at oversample {self.oversample} (the explicit "
                             "friction step's stability: raise oversample)")
        top = self.modal_band_hz()[1]
        mesh = whisker_mesh_error(self.device, top, self.whisker_elements)
        if mesh > MESH_TOLERANCE:
            raise SceneError(f"{pre}whisker_elements: at {self.whisker_elements} the modes "
                             f"below {top:g} Hz move by {100 * mesh:.2g} % "
                             f"when they are doubled; at most {100 * MESH_TOLERANCE:g} %: "
                             "raise whisker_elements (a texture scene stored before 30 Nov had "
                             "8: generate its dataset, train and export again)")
        if self.drive.whisk_hz[1] >= self.acquisition.sample_rate_hz / 8:
            raise SceneError(f"{pre}drive.whisk_hz: must stay below an eighth of the sample "
                             f"rate ({self.acquisition.sample_rate_hz / 8:g} Hz)")
        if self.acquisition.effects.base.enabled:
            raise SceneError(f"{pre}acquisition.effects.base.enabled: the texture scene does "
                             "not move its specimen with the base (its normal force would "
                             "follow it); only the onset scene models base motion")

    # --- the model -----------------------------------------------------------------------
    @property
    def grade_table(self) -> dict[str, float]:
        """Grade name -> mean grain size, µm, of this scene's specimens."""
        return THESIS_GRADES if self.grades == "thesis" else FEPA_GRADES

    def one_specimen_each(self, n: int) -> TextureScene:
        """This scene with ``n // grades`` specimens of each grade (at least one), so that
        ``n`` records of it are each their own specimen, every grade as often: independent
        draws of the specimen population, where the scene's own few specimens per shard (8 of
        each grade in the shipped scene) make many records worth about as many specimens.
        Held-out sets draw so: on 1600 fresh records of one shard's 40 specimens the main
        job's texture decoder's ECE read 2.2 %, on 1600 specimens 0.9 % (29 Nov)."""
        return replace(self, specimens_per_grade=max(1, n // len(self.grade_table)))

    def simulate_independent(self, n: int, rng: np.random.Generator, **kwargs
                             ) -> dict[str, np.ndarray]:
        """:meth:`simulate` of ``n`` records, each its own specimen
        (:meth:`one_specimen_each`); ``kwargs`` as :meth:`simulate`'s."""
        return self.one_specimen_each(n).simulate(n, rng, **kwargs)

    def output_ranges(self) -> dict[str, OutputRange]:
        """The grain size over the thesis's five grades (15.3-52.2 µm), 15 % of its log span
        beyond still in domain (a factor 1.2: about twice the decoder's own RMS error, so a
        window of the finest or coarsest grade is not flagged for its estimate's scatter);
        physically positive and below 1 mm."""
        sizes = list(THESIS_GRADES.values())
        return {"grain": OutputRange(min(sizes) * 1e-6, max(sizes) * 1e-6, (0.0, 1e-3),
                                     margin=0.15, log=True)}

    @staticmethod
    def class_names() -> tuple[str, ...]:
        """The classes a texture decoder names: the thesis's five grades, finest first."""
        return tuple(THESIS_GRADES)

    def transducer(self, factors: dict[str, float] | None = None) -> ModalTransducer:
        """The calibrated modal model: the preset's, or with ``factors`` (actual / nominal,
        :func:`~wtml.physics.spread.draw_factors`) a device off it."""
        return ModalTransducer.from_beam(self.beam(factors), self.n_modes)

    def beam(self, factors: dict[str, float] | None = None) -> BeamTransducer:
        """The device's finite-element beam (:attr:`whisker_elements` in its whisker), with
        ``factors`` a device off it, that :meth:`transducer` reduces to its modes."""
        return build(self.device, factors=factors, whisker_elements=self.whisker_elements)

    def modal_band_hz(self) -> tuple[float, float]:
        """The band (Hz) that ``n_modes: auto`` holds the modal model to
        (:mod:`wtml.scenes.modes`): the slowest whisk up to the sampling rate's Nyquist, the
        band the decoder reads. The asperities' impulses arrive at |v|/d, 4-33 kHz at the
        thesis's speeds, and ring every mode there: a model cut at 10 kHz (the top of the
        thesis's measured spectra, 14 modes) leaves the current above 13 kHz at 0.1-1 % of
        its power, and a decoder trained on it flags every record of the full model."""
        return self.drive.whisk_hz[0], self.acquisition.sample_rate_hz / 2

    def worst_force(self) -> float:
        """N: the largest force at rest of the scene's Coulomb and Stribeck draws, ``μ_s N
        cos θ``: each law's line three ``mu_spread`` above it (Stribeck's then times its
        largest ``static_ratio``), at whichever end of the scene's grain sizes and of its
        viscous span (which moves the line) is larger, at the largest normal force and the
        smallest contact angle (4.3e-4 N for texture.yaml: 1.5 × (0.69 + 0.015) at P280, N
        cos θ = 4.1e-4 cos 5° N); 0 where the mixture holds neither law (LuGre is stepped
        implicitly). With the v_r it is divided by, the slope at rest of the force that the
        explicit step feeds back (:meth:`least_slip_speed`)."""
        f, sizes = self.friction, (min(self.grade_table.values()),
                                   max(self.grade_table.values()))
        mus = [ratio * (line.mu_0 + line.mu_per_um * d
                        + dc * (line.mu_0_per_c + line.mu_per_um_per_c * d) + 3 * f.mu_spread)
               for name, line, ratio in (("coulomb", f, 1.0),
                                         ("stribeck", f.stribeck, f.stribeck.static_ratio[1]))
               if f.law.get(name, 0) > 0 for d in sizes for dc in (0.0, f.viscous_span)]
        if not mus:
            return 0.0
        c = self.contact
        return max(mus) * c.normal_force[1] * float(np.cos(np.radians(c.angle_deg[0])))

    def least_slip_speed(self, oversample: int | None = None) -> float:
        """The least regularisation v_r (m/s) the explicit Coulomb/Stribeck step holds at
        ``oversample`` × the sampling rate (default the scene's own): the force's slope at
        rest, :meth:`worst_force` / v_r plus the largest viscous c, at most the nominal
        model's :func:`~wtml.physics.friction.largest_stable_slope` (the linearised loop's
        limit); inf where c alone passes it. 7.5e-3 m/s at the shipped 22 modes and 102.4
        kS/s (4.4e-3 at 14 modes: the higher modes add velocity to the feedback)."""
        force = self.worst_force()
        if force == 0:
            return 0.0
        dt = 1 / (self.acquisition.sample_rate_hz * (oversample or self.oversample))
        room = (largest_stable_slope(self.transducer(), dt)
                - self.friction.viscous - self.friction.viscous_span)
        return force / room if room > 0 else math.inf

    def check_stepped(self, models: list[ModalTransducer], dt: float) -> None:
        """Refuse to step records of ``models`` (the devices a call drew) at ``dt`` (s) where
        the explicit friction step does not hold one of them (:func:`holds_slope` at the
        slope :meth:`least_slip_speed` bounds): the scene's check holds the nominal device,
        and the spread moves the bound (±1.6 % at the shipped 22 modes; 9.1 to 14.3 mm/s at
        every mode of the beam and oversample 3).

        Raises:
            SceneError: ``friction.slip_speed``, naming the device and ``oversample``.
        """
        force = self.worst_force()
        if force == 0:
            return
        f = self.friction
        slope = force / (f.slip_speed / f.slip_span) + f.viscous + f.viscous_span
        for k, model in enumerate(models):
            if not holds_slope(model, dt, slope):
                who = ("the device" if len(models) == 1
                       else f"device {k} of the {len(models)} drawn from the spread")
                raise SceneError(f"friction.slip_speed: {who} {UNSTABLE_STEP} "
                                 f"at oversample {self.oversample} "
                                 f"({self.n_modes} modes; a slope of {slope:.3g} N·s/m at "
                                 "rest): raise oversample")

    def stepped_stably(self, least: float | None = None) -> TextureScene:
        """The scene at the least ``oversample``, its own or more, whose explicit friction
        step holds the v_r ``least`` (m/s; default the scene's least,
        ``slip_speed / slip_span``): :meth:`least_slip_speed` is not monotonic in the step
        once a mode rings near the step's rate (30 modes of the macro WT: 37.9 mm/s at 2,
        48.1 at 3, 10.7 at 4), so each step is tried in turn. It holds the nominal device:
        :meth:`check_stepped` refuses, when records are made, a drawn device it does not.

        Raises:
            SceneError: ``friction.slip_span``, where no step up to the finest (16) holds it.
        """
        f = self.friction
        least = f.slip_speed / f.slip_span if least is None else least
        finest = int(field_range(self, "oversample")[1])
        for step in range(self.oversample, finest + 1):
            if self.least_slip_speed(step) <= least * (1 + 1e-9):
                return replace(self, oversample=step)
        raise SceneError(f"friction.slip_span: a least v_r of {least:g} m/s is below what the "
                         f"finest step (oversample {finest}) holds at {self.n_modes} modes, "
                         f"{self.least_slip_speed(finest):.3g} m/s")

    CALIBRATION_POINTS: ClassVar[int] = 5

    @property
    def calibration_hz(self) -> np.ndarray:
        """The frequencies (Hz) at which a user's calibrated T enters the decoder,
        ``(CALIBRATION_POINTS,)``: evenly over the whisking range widened on each side by a
        quarter of it or 1 % of its middle (the larger; the ω the graph measures from a
        noisy window strays a little). The graph interpolates T between them by the
        polynomial through all five (the macro preset's T is smooth there, its modes being
        in the transducer's forms' denominators: 1e-7 of each element on 35-37 Hz)."""
        lo, hi = self.drive.whisk_hz
        pad = max(0.25 * (hi - lo), 0.005 * (hi + lo))
        return np.linspace(lo - pad, hi + pad, self.CALIBRATION_POINTS)

    def calibrated_t(self, model: ModalTransducer, frequency_hz=None) -> np.ndarray:
        """``model``'s T at ``frequency_hz`` (Hz, ``(K,)``; None: :attr:`calibration_hz`),
        complex ``(K, 2, 2)``: what its user's calibration gives (the scene's ``calibration``
        where it has one)."""
        freq = self.calibration_hz if frequency_hz is None else np.asarray(frequency_hz, float)
        if freq.ndim != 1 or not len(freq):
            raise ValueError(f"frequency_hz: the calibration frequencies (Hz), one axis, got "
                             f"shape {freq.shape}")
        if self.calibration is not None:
            return self.calibration.t_at(freq)
        return model.transduction_matrix(2 * np.pi * freq)

    def devices(self, n: int, rng: np.random.Generator
                ) -> tuple[list[ModalTransducer], np.ndarray]:
        """The records' devices: ``min(device.devices, n)`` modal models drawn from the
        spread and each record's index into them ``(n,)``; with no spread, the preset alone
        and nothing drawn from ``rng``."""
        if self.spread.none:
            return [self.transducer()], np.zeros(n, int)
        k = min(self.spread.devices, n)
        factors = draw_factors(self.device, self.spread.widths(self.device), k, rng,
                               self.spread.posterior)
        models = [self.transducer({p: float(v[j]) for p, v in factors.items()})
                  for j in range(k)]
        return models, rng.permutation(np.arange(n) % k)

    @property
    def n_samples(self) -> int:
        return int(round(self.drive.record_s * self.acquisition.sample_rate_hz))

    def mu(self, grain_um, law="coulomb", viscous=None) -> np.ndarray:
        """The law's Coulomb coefficient μ_c at mean grain size ``grain_um`` (µm): ``law`` a
        name of :data:`~wtml.physics.friction.LAWS` or an array of codes, ``viscous`` c (N·s/m;
        None: ``friction.viscous``), the line moved for it (:class:`FrictionLaw`; broadcast)."""
        grain_um = np.asarray(grain_um, float)
        names = [law] if isinstance(law, str) else LAWS
        pick = 0 if isinstance(law, str) else np.asarray(law)
        lines = np.array([self.friction.line(name) for name in names])[pick]
        mu = lines[..., 0] + lines[..., 1] * grain_um
        if viscous is None:
            return mu
        shift = np.array([self.friction.line_shift(name) for name in names])[pick]
        extra = np.asarray(viscous, float) - self.friction.viscous
        return mu + extra * (shift[..., 0] + shift[..., 1] * grain_um)

    def asperity(self, grain_um) -> np.ndarray:
        """The law's asperity factor a at ``grain_um`` (µm)."""
        return self.friction.asperity * np.asarray(grain_um, float) / 35.0

    def drive_voltage(self, volts, hz) -> tuple[np.ndarray, np.ndarray, int]:
        """E (V) and dE/dt (V/s) of each record at the simulation rate (``oversample`` × the
        sampling rate), ``(B, n_lead + oversample · n_samples)``, lead-in first, and the
        lead-in's length in steps. The tone is ``volts · sin(2π hz t)``."""
        rate = self.acquisition.sample_rate_hz * self.oversample
        n_lead = int(round(self.drive.lead_s * rate))
        t = np.arange(-n_lead, self.n_samples * self.oversample) / rate
        w = 2 * np.pi * np.asarray(hz, float)[:, None]
        a = np.asarray(volts, float)[:, None]
        e, de = a * np.sin(w * t), a * w * np.cos(w * t)
        if n_lead:
            e, de = lead_in(t, e, de, self.drive.lead_s)
        return e, de, n_lead

    def decimate(self, x: np.ndarray) -> np.ndarray:
        """From the simulation rate to the sampling rate, along the last axis."""
        if self.oversample == 1:
            return x
        return resample_poly(x, 1, self.oversample, axis=-1)

    def specimens(self, rng: np.random.Generator) -> dict[str, np.ndarray]:
        """This shard's specimens, ``specimens_per_grade`` of each grade: ``grade`` (index),
        ``grain_um``, ``mu``, ``asperity``, ``spread``, ``seed``, ``law`` (code) and its shape
        (:meth:`FrictionLaw.shape`) each ``(n_specimens,)``. The law and its shape are drawn
        from the specimens' seeds, so that ``rng`` is drawn from as with Coulomb alone; a
        specimen's μ deviates from its own law's line by the same draw. With
        ``friction.viscous_span`` each specimen also draws its ``viscous`` c (N·s/m) from its
        seeds, after its shape, and its line moves with it (:meth:`mu`)."""
        f = self.friction
        sizes = np.array(list(self.grade_table.values()))
        grade = np.repeat(np.arange(len(sizes)), self.specimens_per_grade)
        n = len(grade)
        spec = {"grade": grade, "grain_um": sizes[grade],
                "mu": self.mu(sizes[grade]) + f.mu_spread * rng.standard_normal(n),
                "asperity": self.asperity(sizes[grade]) * np.exp(
                    f.asperity_spread * rng.standard_normal(n)),
                "spread": rng.uniform(*f.grain_spread, n),
                "seed": rng.integers(0, 2**32 - 1, n)}
        own = np.random.default_rng([*spec["seed"].tolist(), len(LAWS)])
        spec["law"] = own.choice(len(LAWS), n, p=f.weights)
        spec["mu"] = np.where(spec["law"] == 0, spec["mu"], spec["mu"] - self.mu(
            spec["grain_um"]) + self.mu(spec["grain_um"], spec["law"]))
        spec.update(f.shape(spec["law"], own))
        if f.viscous_span > 0:
            spec["viscous"] = f.viscous + own.uniform(0.0, f.viscous_span, n)
            spec["mu"] = spec["mu"] + self.mu(spec["grain_um"], spec["law"], spec["viscous"]) \
                - self.mu(spec["grain_um"], spec["law"])
        return spec

    def friction_load(self, spec: dict, which: np.ndarray, normal: np.ndarray,
                      angle: np.ndarray, *, asperities: bool = True,
                      mu: np.ndarray | None = None) -> Friction:
        """The records' friction: specimen ``which[r]`` under normal force ``normal[r]`` (N)
        and angle ``angle[r]`` (rad); ``mu`` overrides the specimens' Coulomb coefficients."""
        f, rows = self.friction, []
        for r, s in enumerate(which):
            if asperities:
                rows.append(grains(np.random.default_rng(int(spec["seed"][s])),
                                   spec["grain_um"][s] * 1e-6, self.reach_m,
                                   spread=spec["spread"][s], asperity=spec["asperity"][s],
                                   pressing_n=normal[r] * np.cos(angle[r])))
            else:
                rows.append((np.array([np.inf]), np.zeros(1)))
        pos, imp = pad_grains(rows)
        coulomb = spec["mu"][which] if mu is None else mu
        return Friction(np.clip(coulomb, 0.0, None), normal, angle,
                        spec.get("slip_speed", np.full(len(spec["mu"]), f.slip_speed))[which],
                        self.specimen_viscous(spec)[which], pos, imp, **self.law_shape(spec, which))

    def specimen_viscous(self, spec: dict) -> np.ndarray:
        """Each specimen's viscous c (N·s/m) ``(n_specimens,)``: its own draw, or the
        scene's ``friction.viscous``."""
        return spec.get("viscous", np.full(len(spec["law"]), self.friction.viscous))

    def law_shape(self, spec: dict, which: np.ndarray) -> dict[str, np.ndarray]:
        """The keyword arguments of :class:`~wtml.physics.friction.Friction` for the law of
        specimen ``which[r]``: its code and shape, σ0 set by its pre-sliding distance at the
        nominal N and θ on its law's line μ_s(d)."""
        law, ratio = spec["law"][which], spec["static_ratio"][which]
        stiffness = (ratio * np.clip(self.mu(spec["grain_um"][which], law,
                                             self.specimen_viscous(spec)[which]), 1e-3, None)
                     * NOMINAL_N * np.cos(np.deg2rad(NOMINAL_ANGLE_DEG))
                     / spec["presliding_m"][which])
        return {"law": law, "static_ratio": ratio,
                "stribeck_speed": spec["stribeck_speed"][which],
                "bristle_stiffness": stiffness,
                "bristle_damping": spec["bristle_damping"][which]}

    def simulate(self, n: int, rng: np.random.Generator, *, batch: int = 8,
                 asperities: bool = True, mean_friction: bool = True,
                 nominal: bool = False, calibration_hz=None) -> dict[str, np.ndarray]:
        """``n`` records spread evenly over this shard's specimens.

        ``asperities=False`` leaves the grains out; ``mean_friction=False`` gives every
        specimen the Coulomb coefficient of the law at the middle grade (the ablations of the
        bench); ``nominal`` fixes the set-up at the thesis's (10 V, 36 Hz, 3.3e-4 N, 10°, the
        calibrated device, no specimen deviations); ``calibration_hz`` (Hz, ``(K,)``) gives
        ``t`` at those frequencies instead of this scene's :attr:`calibration_hz`, which
        follow its whisking range: records of a narrower range, fed to a decoder trained on
        a wider one, must carry T at the decoder's frequencies (its metadata's), or the graph
        interpolates T from the wrong ones.

        Returns ``e``, ``i`` (see the module docstring), ``t`` (each record's device's
        calibrated T at those frequencies, complex ``(n, K, 2, 2)``), the labels and the
        nuisance drawn. ``batch`` records are stepped at a time (every draw is made before,
        so the records do not depend on it): the oversampled run's arrays take ~8 MB a
        record, and 8 at a time steps as fast as 64 (40 records: 3.0 s against 3.5 s, peak
        memory +175 MB against +330 MB, one thread)."""
        spec = self.specimens(rng)
        if nominal:
            spec.pop("viscous", None)
            spec["mu"] = self.mu(spec["grain_um"], spec["law"])
            spec["asperity"] = self.asperity(spec["grain_um"])
            spec.update(self.friction.shape(spec["law"], None))
        n_spec = len(spec["grade"])
        which = np.arange(n) % n_spec
        d, c, a = self.drive, self.contact, self.acquisition
        volts = rng.uniform(*d.whisk_v, n)
        hz = rng.uniform(*d.whisk_hz, n)
        normal = rng.uniform(*c.normal_force, n)
        angle = np.deg2rad(rng.uniform(*c.angle_deg, n))
        scale = 1 + self.calibration_error * rng.standard_normal(n)
        scale = scale * a.effects.coupling_scale(n, rng)  # temperature drift
        volts = volts * a.effects.drive_scale(n, rng)  # the drive DAC's amplitude error
        if nominal:
            volts, hz, normal = (np.full(n, NOMINAL_V), np.full(n, NOMINAL_HZ),
                                 np.full(n, NOMINAL_N))
            angle, scale = np.full(n, np.deg2rad(NOMINAL_ANGLE_DEG)), np.ones(n)
        mid = self.mu(np.median(list(THESIS_GRADES.values())), spec["law"][which],
                      self.specimen_viscous(spec)[which])
        mu = None if mean_friction else mid
        models, device = (self.devices(n, rng) if not nominal
                          else ([self.transducer()], np.zeros(n, int)))
        dt = 1 / (a.sample_rate_hz * self.oversample)
        self.check_stepped(models, dt)
        cur = np.empty((n, self.n_samples))
        vel = np.empty((n, self.n_samples), np.float32)
        volt = np.empty((n, self.n_samples))
        for start in range(0, n, batch):
            sl = slice(start, min(n, start + batch))
            e, de, n_lead = self.drive_voltage(volts[sl], hz[sl])
            for d in np.unique(device[sl]):  # records of one device stepped together
                own = np.flatnonzero(device[sl] == d)
                rows = own + start if len(own) < len(e) else sl
                load = self.friction_load(spec, which[rows], normal[rows], angle[rows],
                                          asperities=asperities,
                                          mu=None if mu is None else mu[rows])
                e_d = e if len(own) == len(e) else e[own]
                out = models[d].simulate(e_d, dt, load,
                                         drive_rate=de if len(own) == len(e) else de[own],
                                         coupling_scale=scale[rows], record=("v", "i"),
                                         dtype=np.float64,
                                         tones=[(2 * np.pi * hz[rows], e_d)])
                for dst, x in ((cur, out["i"]), (vel, out["v"]), (volt, e_d)):
                    dst[rows] = self.decimate(x[:, n_lead - 64 * self.oversample:])[:, 64:]
        # the op-amp's e_n through Cp (fA): the first device's Cp stands for all of them
        e_rec, i_rec = a.record(volt, cur, models[0].capacitance, rng)
        t = np.stack([self.calibrated_t(m, calibration_hz) for m in models])[device]
        grade = spec["grade"][which] if self.grades == "thesis" else np.full(n, -1)
        return {"e": e_rec, "i": i_rec, "t": t,
                "grade": grade, "grain_m": spec["grain_um"][which] * 1e-6,
                "specimen": rng.integers(0, 2**62) + which, "mu": spec["mu"][which],
                "asperity": spec["asperity"][which], "friction_law": spec["law"][which],
                "viscous": self.specimen_viscous(spec)[which],
                "whisk_v": volts, "whisk_hz": hz,
                "normal_force": normal, "angle": angle, "coupling": scale,
                "rms_speed": np.sqrt(np.mean(vel.astype(float) ** 2, axis=1))}


def fit_friction_law(scene: TextureScene, *, iterations: int = 6, law: str = "coulomb") -> dict:
    """Fit μ (μ_c for Stribeck and LuGre, their shape at the middle of its ranges) per thesis
    grade so that the simulated RMS tip speed at the nominal set-up matches Table 4.10 (secant
    steps on all five at once, asperities included), then a line μ(d).

    Returns ``mu_per_grade``, ``intercept``, ``slope`` (per µm), ``r2`` of the line and the
    achieved ``rms_speed`` per grade (m/s).
    """
    sizes = np.array(list(THESIS_GRADES.values()))
    target = np.array(list(TABLE_4_10_RMS_SPEED.values()))

    def speeds(mu: np.ndarray) -> np.ndarray:
        return nominal_response(scene, mu=mu, law=law)["rms_speed"]

    mu0, mu1 = scene.mu(sizes, law), scene.mu(sizes, law) + 0.05
    s0, s1 = speeds(mu0), speeds(mu1)
    for _ in range(iterations):
        slope = (s1 - s0) / np.where(mu1 != mu0, mu1 - mu0, 1.0)
        mu2 = mu1 + (target - s1) / np.where(slope != 0, slope, -1.0)
        mu0, s0, mu1, s1 = mu1, s1, mu2, speeds(mu2)
        if np.all(np.abs(s1 / target - 1) < 1e-4):
            break
    line = np.polyfit(sizes, mu1, 1)
    fit = np.polyval(line, sizes)
    r2 = 1 - np.sum((mu1 - fit) ** 2) / np.sum((mu1 - mu1.mean()) ** 2)
    return {"mu_per_grade": mu1, "intercept": float(line[1]), "slope": float(line[0]),
            "r2": float(r2), "rms_speed": s1}


def nominal_response(scene: TextureScene, *, mu: np.ndarray | None = None,
                     law: str = "coulomb") -> dict[str, np.ndarray]:
    """The five thesis grades at the nominal set-up (10 V, 36 Hz, 3.3e-4 N, 10°) under friction
    ``law`` (a name of :data:`~wtml.physics.friction.LAWS`; its shape at the middle of its
    ranges), the law's own parameters (``mu`` overrides μ_c per grade), no noise, at the
    simulation rate (LuGre's at least :data:`LUGRE_OVERSAMPLE` × the sampling rate): the
    fundamental phasors of the tip's force and velocity over the recorded part (``force``,
    ``velocity``, complex, N and m/s), ``zm`` = F/V and ``rms_speed`` (m/s), each ``(5,)``;
    ``e``, ``i``, ``v`` (the records, ``(5, n)``) and ``rate`` (Hz) for the spectra."""
    if law not in LAWS:
        raise ValueError(f"law: one of {list(LAWS)}, got {law!r}")
    if law == "lugre" and scene.oversample < LUGRE_OVERSAMPLE:
        scene = replace(scene, oversample=LUGRE_OVERSAMPLE)
    sizes = np.array(list(THESIS_GRADES.values()))
    rate = scene.acquisition.sample_rate_hz * scene.oversample
    rows = []
    for k, d in enumerate(sizes):
        rows.append(grains(np.random.default_rng(1000 + k), d * 1e-6, scene.reach_m,
                           spread=float(np.mean(scene.friction.grain_spread)),
                           asperity=float(scene.asperity(d)),
                           pressing_n=NOMINAL_N * np.cos(np.deg2rad(NOMINAL_ANGLE_DEG))))
    pos, imp = pad_grains(rows)
    code = np.full(len(sizes), LAWS.index(law))
    spec = {"grain_um": sizes, "law": code, **scene.friction.shape(code, None)}
    load = Friction(scene.mu(sizes, law) if mu is None else mu, NOMINAL_N,
                    np.deg2rad(NOMINAL_ANGLE_DEG), scene.friction.slip_speed,
                    scene.friction.viscous, pos, imp,
                    **scene.law_shape(spec, np.arange(len(sizes))))
    e, de, n_lead = scene.drive_voltage(np.array([NOMINAL_V]), np.array([NOMINAL_HZ]))
    out = scene.transducer().simulate(e[0], 1 / rate, load, drive_rate=de[0],
                                      record=("v", "force", "i"), dtype=np.float64,
                                      tones=[(2 * np.pi * NOMINAL_HZ, e[0])])
    keep = slice(n_lead, e.shape[1])
    basis = np.exp(-2j * np.pi * NOMINAL_HZ * np.arange(e.shape[1] - n_lead) / rate)
    force = 2 * np.mean(out["force"][:, keep] * basis, axis=1)
    vel = 2 * np.mean(out["v"][:, keep] * basis, axis=1)
    return {"force": force, "velocity": vel, "zm": force / vel,
            "rms_speed": np.sqrt(np.mean(out["v"][:, keep] ** 2, axis=1)),
            "e": np.broadcast_to(e[0, keep], (5, e.shape[1] - n_lead)), "i": out["i"][:, keep],
            "v": out["v"][:, keep], "rate": rate}
