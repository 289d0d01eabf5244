"""The tasks wtml decodes, each declared once (issue 25 §1): its scene, its decoder, how it is
exported, what ``wtml predict`` makes of its measurements, and its stage of the main job. The
entry points iterate over :data:`TASKS` or look a task up by name (:func:`task`); nothing
outside a task's own modules switches on its name. A new task adds its own modules and one
entry here.

Each part is named by ``"module:attribute"`` and imported only when used (:meth:`Task.load`),
so this module imports nothing: the device runtime reads it without the training stack, and
the modules it names may import it without a cycle.
"""

from __future__ import annotations

from dataclasses import dataclass
from importlib import import_module
from typing import Any


@dataclass(frozen=True)
class Task:
    """One task.

    Attributes:
        name: the scenes' ``task`` key.
        what: one line on what it decodes.
        reads: what ``wtml predict`` takes: ``"measurements"`` (Ze on a frequency grid) or
            ``"recordings"`` (e and i in time, from any of the runtime's formats).
        scene: its scene class.
        decoder: its LightningModule (what a checkpoint of the task holds).
        export: ``(module, scene, out) -> {kind: path}``, writing its graphs into ``out``.
        rows: ``wtml predict``'s rows: ``(model_dir, input, *, calibration, reference)`` for
            measurements, ``(model_dir, input, *, calibration, profile)`` for recordings.
        pipeline: its stage of ``wtml pipeline``: ``(stages, *, max_epochs) -> results``.
        frontier: its problem for the frontier bench (:mod:`wtml.bench.frontier`):
            ``(data_dir, model_dir, *, threads) -> Problem``.
        evaluate: ``wtml evaluate``'s report of a checkpoint on its dataset's test shard:
            ``(checkpoint, data_dir, scene, split, test, where) -> markdown``; ``""``: the
            task has none (its bench has the numbers).
        measurement: a task that reads measurements: what its export and ``wtml pipeline``'s
            sample measurements are made of (a :class:`wtml.exporters.matrix.MatrixTask`);
            ``""`` for one that reads recordings.
        pipeline_s: its slice of the main job's wall-clock seconds on one thread, its bench
            included, no wait for another lane's bench and its warm part done ahead (the
            mean of three runs of the main job's stage lines, 29 Nov 11:23–11:58, two lanes;
            onset's generation and texture's FEPA set, which the warm-up took over after
            them, left out).
        bench_s: of those, its ``bench`` stage's (the slice's last). The main job's lanes
            start the slices in the order these predict ends first (:mod:`wtml.lanes`). An
            order that starts onset and fluid before texture was tried on 29 Nov and not
            kept: texture's bench then ran beside radial's training, not beside radial's idle
            wait (3 min 15 s to 4 min 03 s against 3 min 19–24 s), and the pairs that met
            peaked at 2.04–2.08 GB (docs/main-job.md). Texture's are kept from then
            though its export now takes ~27 s more and its bench ~55 s less (29 Nov night:
            271 s, bench 140 s, warm-up 68.5 s in all): on those the replay would start
            radial before fluid, 412 s against 418 s for this order, within the runs' drift,
            and put texture's bench beside radial's training again.
        warm: ``() -> None``: the work its slice would otherwise do when it first needs it
            that waits on nothing else (its JIT kernels compiled into numba's cache on disk,
            datasets only it reads generated under :func:`wtml.pipeline.generate_locked`),
            which the main job runs ahead in a lane of its own
            (:func:`wtml.pipeline.run_all`); ``""``: none.
        warm_s: that work's seconds on one core, with a cold cache (29 Nov).
    """

    name: str
    what: str
    reads: str
    scene: str
    decoder: str
    export: str
    rows: str
    pipeline: str
    frontier: str
    evaluate: str = ""
    measurement: str = ""
    pipeline_s: float = 60.0
    bench_s: float = 0.0
    warm: str = ""
    warm_s: float = 0.0

    def load(self, part: str) -> Any:
        """The object a part names (``"scene"``, ``"decoder"``, ``"export"``, ``"rows"``,
        ``"pipeline"``, ``"frontier"``, ``"evaluate"``, ``"measurement"``, ``"warm"``),
        imported now.

        Raises:
            ValueError: the task declares no such part (``""``).
        """
        if not getattr(self, part):
            raise ValueError(f"the {self.name} task has no {part!r} part")
        module, _, attribute = getattr(self, part).partition(":")
        return getattr(import_module(module), attribute)


TASKS = {t.name: t for t in (
    Task("fluid", "viscosity and density of a fluid from a sphere tip's Ze sweep",
         "measurements", "wtml.scenes.fluid:FluidScene", "wtml.decoders.fluid:FluidDecoder",
         "wtml.exporters.fluid:export_fluid", "wtml.runtime.predict:predict_file",
         "wtml.pipeline:run_fluid",
         "wtml.bench.fluid:frontier_problem", evaluate="wtml.bench.fluid:evaluate_checkpoint",
         measurement="wtml.exporters.fluid:FLUID", pipeline_s=42, bench_s=21),
    Task("radial", "a contact's distance from the tip along the whisker from Ze",
         "measurements", "wtml.scenes.radial:RadialScene", "wtml.decoders.radial:RadialDecoder",
         "wtml.exporters.radial:export_radial", "wtml.runtime.predict:predict_file",
         "wtml.pipeline:run_radial",
         "wtml.bench.radial:frontier_problem", evaluate="wtml.bench.radial:evaluate_checkpoint",
         measurement="wtml.exporters.radial:RADIAL", pipeline_s=277, bench_s=55),
    Task("onset", "contact onsets, detachments and the wall's horizontal location from e, i",
         "recordings", "wtml.scenes.onset:OnsetScene", "wtml.decoders.onset:OnsetDecoder",
         "wtml.exporters.onset:export_onset", "wtml.runtime.onset:predict_records",
         "wtml.pipeline:run_onset",
         "wtml.bench.onset:frontier_problem", pipeline_s=121, bench_s=37,
         warm="wtml.pipeline:warm_onset", warm_s=28),
    Task("texture", "a swept sandpaper's grade and grain size from e, i",
         "recordings", "wtml.scenes.texture:TextureScene",
         "wtml.decoders.texture:TextureDecoder", "wtml.exporters.texture:export_texture",
         "wtml.runtime.texture:predict_records", "wtml.pipeline:run_texture",
         "wtml.bench.texture:frontier_problem", pipeline_s=294, bench_s=180,
         warm="wtml.pipeline:warm_texture", warm_s=39),
)}
"""Every task, in the main job's order."""
UNNAMED = "fluid"
"""The task of a scene mapping without a ``task`` key (the first wtml's scenes were fluid
scenes and named none)."""


def task(name: str, where: str = "task") -> Task:
    """The task called ``name``.

    Raises:
        ValueError: no such task (``where`` names what gave it; the message lists the tasks).
    """
    if name not in TASKS:
        raise ValueError(f"{where}: {name!r} is not a task of this wtml (tasks: "
                         f"{', '.join(TASKS)})")
    return TASKS[name]
