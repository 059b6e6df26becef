"""One job from queue to outcome: whole-model pass, just-in-time run, G-code file, done/failed."""

from __future__ import annotations

import asyncio
import concurrent.futures
import contextlib
import logging
import threading
import time
from collections.abc import Iterable, Iterator, Mapping
from pathlib import Path

from drivers.link.motion import PrinterMotion
from drivers.link.streamer import LinkError, Streamer
from hostd.api import JobStatus
from hostd.config import Config
from hostd.jobs.filecheck import Fingerprint, fingerprint, wait_complete
from hostd.jobs.intake import Intake
from hostd.jobs.jobfolder import split_name, write_text
from hostd.jobs.jobstate import JobError, JobState, ModelRepaired, Started
from hostd.jobs.jobstore import Job
from hostd.jobs.schedule import LayerSchedule
from hostd.jobs.speculate import MadeAhead, Speculation
from hostd.printing.activejob import ActiveJob
from hostd.printing.endgcode import CANCEL_GCODE
from hostd.printing.eta import slicer_totals
from hostd.printing.printermotion import with_printer_motion
from hostd.printing.reentry import resume_line
from hostd.printing.runner import JobCancelled, JobRunner, Park, open_output, park_moves
from hostd.printing.sources import FileSource, LayerSource, SlicedSource
from slicer.errors import ModelError
from slicer.fea.tailor import Tailoring, find_load_case, tailored_plan
from slicer.output.annotate import write_annotated
from slicer.output.gcode import header_lines, summarize
from slicer.paths.arcs import for_printer
from slicer.planprocess import PlanProcess, plan_warnings
from slicer.settings import SettingsError, SliceSettings

log = logging.getLogger("hostd.job")


class PrintJob:
    """Carries one queued job through slicing, heating and printing to its outcome."""

    def __init__(
        self,
        active: ActiveJob,
        config: Config,
        intake: Intake,
        executor: concurrent.futures.Executor,
        replay: int = 0,
        speculation: Speculation | None = None,
    ) -> None:
        """``replay``: commands a resume goes back within its layer (0: the printer kept
        power, continue at the first command it did not acknowledge); ``speculation``:
        where a whole-model pass begun while the file settled may wait. What the print
        owns (schedule, source, runner) goes to ``active``, which commands reach."""
        self.active = active
        job = self.job = active.job
        self.speculation = speculation
        self.replay = replay
        self.life = active.life
        self.config = config
        self.store = active.life.store
        self.intake = intake
        self.executor = executor
        self.warned: list[str] = []  # the model's warnings logged so far
        self.tailoring: Tailoring | None = None  # the analysis and equal mass, for the summary
        self.analysis_file = ""  # the field file an analysis beside the print is writing
        # the slicing process being started (see _slice_apart), awaited when the print ends
        self._starting: asyncio.Future[None] | None = None
        # an analysis beside the print begins once the printer laid the first filament
        # (or a layer needs its field, or the job ends): see `tailored_plan`
        self.analysis_hold = threading.Event()
        stem, _suffix = split_name(job.name)
        self.home = Path(job.path).parent
        self.partial = self.home / f"{stem}.gcode.part"
        self.final = self.home / f"{stem}.gcode"

    @property
    def schedule(self) -> LayerSchedule | None:
        """The print's layer schedule (None for a G-code file, or before the pass)."""
        return self.active.schedule

    @property
    def source(self) -> LayerSource | None:
        """Where the print's layers come from, once the whole-model pass made it."""
        return self.active.source

    @property
    def runner(self) -> JobRunner | None:
        """The print's runner, once it streams."""
        return self.active.runner

    async def run(self, link: Streamer) -> str:
        """Print the job on ``link``; returns its final state (done, failed, cancelled).

        CancelledError (the daemon stopping) leaves the job interrupted at its last
        checkpoint. LinkError leaves it interrupted too, and is raised again.
        """
        try:
            return await self._run(link)
        finally:
            self.analysis_hold.set()  # an analysis held for this job is not held forever
            schedule = self.active.schedule
            if schedule is not None:  # its slicing process ends with the print
                await asyncio.shield(asyncio.to_thread(schedule.close))
            if self._starting is not None:  # (a child started after that is closed too)
                await asyncio.shield(self._starting)

    async def _run(self, link: Streamer) -> str:
        job = self.store.get(self.job.id)
        job = self.active.enter(JobState.SLICING, JobStatus(id=job.id, name=job.name,
                                                            layer=max(job.layer, 0)))
        first = job.resume_from or 0
        skip = 0
        if job.resume_from is not None and job.layer == first - 1 and job.kind == "stl":
            skip = resume_line(job.layer_lines, self.replay)
        resume = first > 0 or skip > 0
        try:
            first = job.resume_from if resume else 0
            schedule, source = await self._source(job, first or 0, resume, link)
            self.active.attach(schedule, source)
            output = await asyncio.to_thread(
                open_output, self.partial, job.gcode_bytes if resume else 0
            )
        except (ModelError, SettingsError, OSError) as exc:
            self.intake.fail(self.store.get(job.id), str(exc))
            return "failed"
        except asyncio.CancelledError:
            self._interrupted("stopped during the whole-model pass")
            raise
        try:
            runner = JobRunner(job, source, link, self.life, output,
                               first, write_preamble=not resume, park=self._park(),
                               skip=skip, end_gcode=CANCEL_GCODE)
            runner.waiting = self._waiting
            self.active.start(runner)
            link.begin_job()  # a link cancelled for the job before takes this one's lines
            verb = f"resumed at layer {first}, command {skip}" if resume else "started"
            log.info("job %s %s: %s, %d layers", job.id, job.name, verb, source.layer_count)
            self.life.publish(Started(job.id, job.name, source.layer_count,
                                      first if resume else None))
            try:
                await runner.run()
            except JobCancelled as exc:
                await self._cancelled(link, str(exc))
                return "cancelled"
            except (asyncio.CancelledError, LinkError) as exc:
                if self.active.emergency:
                    self.intake.fail(self.store.get(job.id), "emergency stop (M112)")
                else:
                    self._interrupted(f"stopped: {type(exc).__name__}")
                raise
            finally:
                source.close()
        finally:
            with contextlib.suppress(OSError):  # a full disk fails the flush again
                output.close()
        await self._log_late_warnings(job)
        try:
            await asyncio.to_thread(self._write_final, job)
        except OSError as exc:  # the print is over; only its files could not be written
            log.error("job %s %s: G-code file or summary not written: %s", job.id, job.name, exc)
        self.intake.finish(self.store.get(job.id))
        return "done"

    async def check_model(self, job: Job, resume: bool, digest: Fingerprint | None = None
                          ) -> Job:
        """The model is still the file that was taken: its size and hash again, before
        slicing.

        The bytes read now must be as many as were taken, with the same hash, and
        the file must still be that long once they are read (a writer that went on
        after the hash was read). A file its writer went on changing after it was
        taken (a writer the daemon could not see) is waited for until complete, and
        the job starts over from the complete file: the job returned has the new
        hash and size. A resumed job's model must not change: ModelError.
        ``digest``: the file's fingerprint, when read already.
        """
        path = Path(job.path)
        if digest is None:
            digest = await asyncio.to_thread(fingerprint, path)
        if digest.sha256 == job.sha256 and job.size in (-1, digest.size) and digest.still(path):
            return job
        if resume:
            raise ModelError(f"{job.name} changed after it was taken: the part on the bed "
                             "was printed from other bytes, so the job cannot resume")
        log.warning("job %s %s: the file changed after it was taken; waiting for it to be "
                    "complete, then starting over", job.id, job.name)
        await wait_complete(path, self.config.jobs.settle_s)
        digest = await asyncio.to_thread(fingerprint, path)
        job = self.store.set_digest(job.id, digest.sha256, digest.size)
        self.life.publish(JobError(job.id, f"{job.name} changed after it was taken; "
                                           f"started over from the complete file "
                                           f"({digest.size} bytes, sha256 "
                                           f"{digest.sha256[:12]})"))
        return job

    async def _source(self, job: Job, first: int, resume: bool, link: Streamer
                      ) -> tuple[LayerSchedule | None, LayerSource]:
        """The print's layer schedule (None for a G-code file) and its layer source."""
        if job.kind == "gcode":
            if resume:
                raise ModelError("a G-code job cannot be resumed mid-file")
            job = await self.check_model(job, resume)
            return None, await asyncio.to_thread(FileSource, Path(job.path))
        # the printer is known before slicing: arcs if its M115 reported Cap:ARCS:1
        # (gcode.arcs = "auto"), and the line budget of its wire (gcode.baud = 0)
        # and the acceleration its M503 reported, unless [slicing] or NAME.toml set one
        settings = printer_settings(self.config, job.settings, link.capable, link.motion)
        started = time.monotonic()
        # the model is hashed again beside the whole-model pass (hashing leaves the
        # interpreter free), and checked before any layer is sliced
        hashing = asyncio.ensure_future(asyncio.to_thread(fingerprint, Path(job.path)))
        error: ModelError | None = None
        ahead = await self._made_ahead(job, settings)
        try:
            if ahead is not None:
                plan, tailoring = ahead.plan, Tailoring(None, None)
            else:
                plan, tailoring = await asyncio.to_thread(
                    tailored_plan, Path(job.path), settings, self.config.printer.bed,
                    self.config.state.folder / "fea", None, background=True,
                    hold=self.analysis_hold,
                )
        except ModelError as exc:  # a file still being written may not parse yet
            error = exc
        finally:
            digest = await hashing
        checked = await self.check_model(job, resume, digest)
        if checked is not job:  # started over from the complete file
            job = checked
            plan, tailoring = await asyncio.to_thread(
                tailored_plan, Path(job.path), settings, self.config.printer.bed,
                self.config.state.folder / "fea", None, background=True,
                hold=self.analysis_hold,
            )
        elif error is not None:
            raise error
        self.tailoring = tailoring
        self.analysis_file = plan.settings.infill_file if tailoring.running is not None else ""
        for line in tailoring.lines():
            log.info("job %s %s: %s", job.id, job.name, line)
        settings = plan.settings
        log.info("job %s %s: whole-model pass %.2f s, %d layers, %d bodies", job.id, job.name,
                 time.monotonic() - started, plan.layer_count, plan.body_count)
        # outlines are cut lazily: repairs found in later layers are logged at the end
        self.warned = plan.warnings_so_far
        for warning in self.warned:
            log.warning("job %s %s: %s", job.id, job.name, warning)
            self.life.publish(ModelRepaired(job.id, job.name, warning))
        schedule = LayerSchedule(
            plan, settings, self.store.settings_changes(job.id),
            self.store.cancelled_objects(job.id),
        )
        if ahead is not None and ahead.plan is plan and ahead.first_layer is not None:
            schedule.made_ahead(0, ahead.first_layer)
        if self.config.runner.slice_process and tailoring.running is None:
            # (an analysis running beside the first layers is this process's to wait for)
            self._slice_apart(job, schedule)
        return schedule, SlicedSource(schedule, first, self.config.runner.lookahead,
                                      self.executor, resume, on_started=self.analysis_hold.set)

    def _slice_apart(self, job: Job, schedule: LayerSchedule) -> None:
        """Start, beside the first layer, the process that slices the job's layers
        (:mod:`slicer.planprocess`): the layers before it is ready, or all of them if it
        cannot start, are sliced in the daemon's threads."""
        self._starting = asyncio.ensure_future(
            asyncio.to_thread(self._start_process, job, schedule))

    def _start_process(self, job: Job, schedule: LayerSchedule) -> None:
        """(In a thread: starting a process takes some ms.)"""
        try:
            process = PlanProcess(job.path, schedule.base_settings, self.config.printer.bed,
                                  self.config.runner.workers, job.sha256)
        except (OSError, ValueError) as exc:
            log.warning("job %s %s: layers sliced in the daemon, no slicing process: %s",
                        job.id, job.name, exc)
            return
        log.info("job %s %s: layers sliced in process %s", job.id, job.name, process.pid)
        schedule.slice_in(process)

    async def _made_ahead(self, job: Job, settings: SliceSettings) -> MadeAhead | None:
        """The whole-model pass (and layer 0) begun while the file settled, if it fits
        this job."""
        if self.speculation is None:
            return None
        bed = self.config.printer.bed
        ahead = await self.speculation.take(Path(job.path), settings, bed)
        if ahead is None or find_load_case(job.path, settings) is not None:
            return None
        log.info("job %s %s: whole-model pass made while the file settled (%.2f s)",
                 job.id, job.name, ahead.seconds)
        return ahead

    def _waiting(self) -> str | None:
        """``"analysis"`` while a layer waits for the stress analysis running beside the
        first layers (the status snapshot's ``job.waiting_for``), else None."""
        if self.analysis_file:
            from slicer.fields.stress_pending import waited_for

            if waited_for(self.analysis_file):
                return "analysis"
        return None

    async def _log_late_warnings(self, job: Job) -> None:
        """Log the model's warnings found while slicing (every layer is cut by now)."""
        if self.schedule is None:
            return
        warnings = await asyncio.to_thread(self.schedule.on_plan, plan_warnings)
        for warning in warnings:
            if warning not in self.warned:
                log.warning("job %s %s: %s", job.id, job.name, warning)
                self.life.publish(ModelRepaired(job.id, job.name, warning))
        self.warned = warnings

    def _park(self) -> Park:
        """Pause moves for a sliced job: lift up to 5 mm, staying inside the build volume."""
        if self.schedule is None:
            return Park()  # a G-code file: its extrusion mode is unknown
        plan = self.schedule.base_plan
        top = plan.layer_z(plan.layer_count - 1) if plan.layer_count else 0.0
        return park_moves(min(5.0, self.config.printer.bed[2] - top - 1.0))

    async def _cancelled(self, link: Streamer, reason: str) -> None:
        """The link cancelled the job (``M108``, then ``CANCEL_GCODE`` after the lines in
        flight): wait until the printer took them, and open the link to the next job."""
        with contextlib.suppress(LinkError):
            await link.drain()
        if isinstance(self.source, SlicedSource):
            await self.source.settled()  # the layers in flight end with the job
        link.begin_job()
        job = self.store.get(self.job.id)
        self.intake.fail(job, reason, state="cancelled")

    def _interrupted(self, note: str) -> None:
        """Leave the job interrupted at its checkpoint, or queued again if nothing printed."""
        self.life.interrupt(self.job.id, note)

    def _write_final(self, job: Job) -> None:
        """NAME.gcode (header from the whole file, then the body) and NAME.summary.txt."""
        if job.kind == "gcode":
            summary_text = f"job {job.id} {job.name}: printed as is\n"
        elif self.runner.output_error is not None:
            summary_text = f"job {job.id} {job.name}: printed; {self.runner.output_error}\n"
        else:
            totals = slicer_totals(self.schedule)  # as `hostd slice` counts the same moves
            summary = totals[0] if totals else summarize(_lines(self.partial))
            settings = self.schedule.base_settings if self.schedule else SliceSettings()
            # in the slicing process, if any: the thumbnails cut every layer's outline
            self.schedule.on_plan(write_annotated, self.final, self.partial,
                                  header_lines(summary, settings), settings,
                                  totals[1] if totals else None)
            summary_text = (
                f"job {job.id} {job.name}\nlayers {summary.layers}\n"
                f"filament {summary.filament_mm:.0f} mm ({summary.filament_g:.1f} g)\n"
                f"estimated print time {summary.time_s:.0f} s\n"
            )
        if self.tailoring is not None:
            summary_text += "".join(f"{line}\n" for line in self.tailoring.lines())
        summary_text += f"sha256 {job.sha256}\nlines acknowledged {self.runner.lines_acked}\n"
        changes = self.schedule.changes if self.schedule else []
        cancelled = self.schedule.cancelled if self.schedule else []
        summary_text += "".join(f"from layer {first}: {c}\n" for first, c in changes)
        summary_text += "".join(f"body {b} cancelled from layer {f}\n" for b, f in cancelled)
        summary_text += "".join(f"model: {w}\n" for w in self.warned)
        write_text(self.final.with_name(f"{self.final.stem}.summary.txt"), summary_text)
        # the partial file stays until the job's folder is cleared: a crash before the
        # outcome is recorded resumes from it


def _lines(path: Path) -> Iterator[str]:
    with open(path, encoding="utf-8") as handle:
        for line in handle:
            yield line.rstrip("\n")


def printer_settings(
    config: Config, mapping: Mapping[str, object], capable: Iterable[str],
    motion: PrinterMotion | None = None,
) -> SliceSettings:
    """A job's slicing settings for the connected printer: arcs if its M115 reported
    ``Cap:ARCS:1`` (``gcode.arcs = "auto"``), the line budget of its wire, and the
    acceleration its ``M503`` reported (:mod:`hostd.printing.printermotion`)."""
    printer = config.printer
    baud = config.simulator.baud if printer.port == "sim" else printer.baud
    settings = for_printer(SliceSettings.from_mapping(dict(mapping)), capable, baud)
    return with_printer_motion(config, mapping, settings, motion)
