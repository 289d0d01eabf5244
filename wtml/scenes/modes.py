"""``n_modes: auto``: a time-domain scene's number of modes chosen from a tolerance.

A scene file may say ``n_modes: auto`` instead of a count. The scene then keeps the fewest
modes whose modal model stays within ``modes_tolerance`` (relative; default
:data:`DEFAULT_TOLERANCE`) of the model with every mode kept, over ``modes_band_hz`` (Hz, a
``[low, high]`` pair; default the scene's own band, its ``modal_band_hz()``), by
:func:`wtml.physics.modal.fewest_modes`: the largest relative error of Ze with the tip free and
with it clamped, at :data:`POINTS_PER_DECADE` log-spaced frequencies per decade of the band.

The choice is made once, when the scene file is read (:func:`wtml.scenes.scene_from_dict`):
the scene holds the count it picked, so a dataset's scene (and its hash) is that of a file
naming the count, and ``modes_tolerance`` and ``modes_band_hz`` are not scene keys. They are
accepted only beside ``n_modes: auto``.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from wtml.schema import SceneError, bounded, build, field_range

DEFAULT_TOLERANCE = 0.01
"""``modes_tolerance`` when a scene says ``n_modes: auto`` alone: 1 % of Ze, within the
modal model's own damping-model difference from the beam (1.3 %, physics.md §9)."""
POINTS_PER_DECADE = 400
"""Log-spaced frequencies per decade of the band: a resonance of the shipped devices (ζ = 0.01,
half-power width 2 % of its frequency) spans several of them."""
AUTO = "auto"
PLACEHOLDER = 1
"""``n_modes`` while the scene is first built, before its count is picked: the count a check
that depends on it holds best (texture's friction step: one mode adds the least velocity
under a held force); :func:`with_auto_modes` checks the scene again at its count."""


@dataclass(frozen=True)
class AutoModes:
    """The keys of ``n_modes: auto`` (module docstring)."""

    modes_tolerance: float = bounded(1e-8, 0.5, default=DEFAULT_TOLERANCE)
    modes_band_hz: tuple[float, float] | None = bounded(1e-3, 1e7, default=None)

    def check(self, path: str) -> None:
        band = self.modes_band_hz
        if band is not None and not band[0] < band[1]:
            raise SceneError(f"{path + '.' if path else ''}modes_band_hz: low {band[0]:g} Hz "
                             f"must be below high {band[1]:g} Hz")

    def count(self, scene) -> tuple[int, np.ndarray, tuple[float, float]]:
        """The fewest modes for ``scene`` (its device, its band unless ``modes_band_hz``):
        the count, the errors of 1..count modes and the band (Hz)."""
        from wtml.physics.modal import fewest_modes

        band = self.modes_band_hz or scene.modal_band_hz()
        n, errors = fewest_modes(scene.beam(), band_omega(band),
                                 self.modes_tolerance)
        return n, errors, band


def band_omega(band_hz: tuple[float, float]) -> np.ndarray:
    """The band ``(low, high)`` Hz as :data:`POINTS_PER_DECADE` log-spaced angular
    frequencies per decade (at least 64), rad/s."""
    low, high = band_hz
    count = max(64, int(np.ceil(POINTS_PER_DECADE * np.log10(high / low))) + 1)
    return 2 * np.pi * np.geomspace(low, high, count)


def auto_request(cls: type, data: Mapping, path: str = "") -> tuple[dict, AutoModes | None]:
    """Split ``n_modes: auto`` and its keys off a scene mapping of class ``cls``.

    Returns the mapping without them (``n_modes`` :data:`PLACEHOLDER` until
    :func:`with_auto_modes`) and the request, or the mapping unchanged and None.

    Raises:
        SceneError: naming the key: ``n_modes`` neither a count nor ``auto``, a scene without
            modes given ``auto``, ``modes_tolerance`` or ``modes_band_hz`` without
            ``n_modes: auto``, or either out of its range.
    """
    pre = path + "." if path else ""
    extra = {k: data[k] for k in (f.name for f in dataclasses.fields(AutoModes)) if k in data}
    fields = {f.name: f for f in dataclasses.fields(cls)}
    value = data.get("n_modes")
    if "n_modes" not in fields and (extra or isinstance(value, str)):
        key = "n_modes" if isinstance(value, str) else sorted(extra)[0]
        raise SceneError(f"{pre}{key}: unknown key; allowed keys here: {sorted(fields)}")
    if isinstance(value, str):
        if value != AUTO:
            low, high = field_range(cls, "n_modes")
            raise SceneError(f"{pre}n_modes: must be an integer in [{low:g}, {high:g}] or "
                             f"'{AUTO}', got {value!r:.80}")
        rest = {k: v for k, v in data.items() if k != "n_modes" and k not in extra}
        return rest | {"n_modes": PLACEHOLDER}, build(AutoModes, extra, path)
    if extra:
        key = sorted(extra)[0]
        raise SceneError(f"{pre}{key}: only with n_modes: {AUTO} (n_modes is "
                         f"{value if value is not None else 'its default'})")
    return dict(data), None


def with_auto_modes(scene, request: AutoModes, path: str = ""):
    """``scene`` with the count ``request`` picks (:meth:`AutoModes.count`).

    The scene is checked again at its count (a check may depend on the modes: texture's
    friction step's stability).

    Raises:
        SceneError: ``n_modes`` when the count exceeds the scene's largest (its field's
            range): loosen ``modes_tolerance`` or narrow ``modes_band_hz``; or the scene's
            own check at that count.
    """
    n, errors, band = request.count(scene)
    high = field_range(scene, "n_modes")[1]
    if n > high:
        raise SceneError(f"{path + '.' if path else ''}n_modes: auto needs {n} modes to keep Ze "
                         f"within {request.modes_tolerance:g} over {band[0]:g}-{band[1]:g} Hz, "
                         f"more than the {high:g} a scene takes (at {high:g} modes: "
                         f"{errors[int(high) - 1]:.2g}); loosen modes_tolerance or narrow "
                         "modes_band_hz")
    scene = dataclasses.replace(scene, n_modes=n)
    scene.check(path)
    return scene
