"""The daemon: wires config, job store, watcher, printer link, runner, control and MQTT."""

from __future__ import annotations

import asyncio
import concurrent.futures
import contextlib
import importlib.util
import logging
import random
import signal
import time
from pathlib import Path

from drivers.link.backoff import Backoff, reconnect
from drivers.link.responses import Response
from drivers.link.streamer import HALTED, LinkError, Streamer
from hostd.api import PrinterInfo, Snapshot, Temperature, Temps
from hostd.app.addons import Addons
from hostd.app.memory import release_after_job, release_again, release_once_ended
from hostd.config import Config
from hostd.jobs.intake import Intake
from hostd.jobs.jobfolder import LOAD_SUFFIX, split_name
from hostd.jobs.joblife import JobLife
from hostd.jobs.jobstate import HubState, Interrupted, PrinterError
from hostd.jobs.jobstore import Job, JobStore
from hostd.jobs.loadcheck import load_analysis_modules
from hostd.jobs.speculate import Speculation
from hostd.jobs.watcher import Watcher
from hostd.printing.activejob import ActiveJob
from hostd.printing.controller import DaemonController
from hostd.printing.printer import printer_link
from hostd.printing.printjob import PrintJob, printer_settings
from hostd.printing.sources import warm_up
from hostd.publishing.status import StatusHub

log = logging.getLogger("hostd.app.daemon")

STORE_FILE = "jobs.sqlite3"
SOCKET_FILE = "hostd.sock"
# reopening the printer link after it failed: the same jittered exponential policy as the
# MQTT bridge's and the streamer's port reconnects (1 s doubling to 30 s, each wait drawn
# from half to all of it)
RECONNECT = Backoff(initial_s=1.0, maximum_s=30.0)


class _Stop(Exception):
    """Raised inside the task group to end it on SIGINT or SIGTERM."""


class Daemon:
    """One printer's daemon. ``await Daemon(config).run()`` until a signal stops it."""

    def __init__(self, config: Config) -> None:
        self.config = config
        config.state.folder.mkdir(parents=True, exist_ok=True)
        config.jobs.folder.mkdir(parents=True, exist_ok=True)
        self.store = JobStore(config.state.folder / STORE_FILE)
        self.hub = StatusHub(Snapshot(
            state=HubState.OFFLINE.value,
            printer=PrinterInfo(config.printer.id, config.printer.port),
        ))
        # the one writer of the jobs' states, lent to whatever changes a job
        self.life = JobLife(self.store, self.hub)
        # the printer booted (a `start`) since a job last streamed: its buffers were lost
        self.printer_reset = False
        self.intake = Intake(config, self.life)
        self.addons = Addons(config, self.store, self.hub)
        self.current: ActiveJob | None = None  # the print in progress: what it owns
        self.link: Streamer | None = None
        self.speculation = Speculation()
        self.controller = DaemonController(
            self.life, self.intake, lambda: self.current, self.queue_changed,
            self.emergency_stop,
        )
        self._wake = asyncio.Event()
        self._stop = asyncio.Event()
        self._late_release: asyncio.Task[bool] | None = None  # see release_once_ended

    async def run(self) -> None:
        """Serve until SIGINT or SIGTERM; the job printing is left at its last checkpoint."""
        loop = asyncio.get_running_loop()
        for signum in (signal.SIGINT, signal.SIGTERM):
            loop.add_signal_handler(signum, self._stop.set)
        for job in self.life.recover():
            if job.state == "interrupted":
                log.warning("job %s %s was interrupted after layer %d; resume it with "
                            "`hostd resume %s`", job.id, job.name, job.layer, job.id)
        for job in self.store.interrupted():
            self.life.publish(Interrupted(job.id, job.name, job.layer))
        self.intake.recover_incoming()
        self.intake.outcomes.settle()
        self.queue_changed()
        executor = concurrent.futures.ThreadPoolExecutor(
            self.config.runner.workers, thread_name_prefix="hostd-slice"
        )
        executor.submit(self._warm_up)
        try:
            async with asyncio.TaskGroup() as group:
                group.create_task(self._until_stopped(), name="signals")
                group.create_task(self._serve_optional(), name="services")
                watcher = Watcher(self.config.jobs.folder, self.config.jobs.settle_s, self._take,
                                  on_still=self._still, on_seen=_seen)
                group.create_task(watcher.run(self._stop), name="watcher")
                group.create_task(self._print_loop(executor), name="printer")
        except* _Stop:
            pass
        finally:
            executor.shutdown(wait=True, cancel_futures=True)
            for signum in (signal.SIGINT, signal.SIGTERM):
                loop.remove_signal_handler(signum)
            self._notify("STOPPING=1")
            self.addons.close()
            self.store.close()
            log.info("stopped")

    def _warm_up(self) -> None:
        """Slice a small cube's first layer so that the first job does not pay first uses."""
        started = time.monotonic()
        try:
            warm_up(self.config.slicing, self.config.printer.bed)
        except Exception:  # settings a cube cannot take are the jobs' to report
            log.debug("slicer warm-up skipped", exc_info=True)
            return
        log.info("slicer warmed up in %.2f s", time.monotonic() - started)

    async def _until_stopped(self) -> None:
        await self._stop.wait()
        log.info("stopping: no further line is sent")
        raise _Stop

    async def _take(self, path: Path) -> None:
        if await self.intake.take(path) is None:
            self.speculation.forget()  # refused: a plan made ahead of it is not needed
        self.queue_changed()

    def _still(self, path: Path) -> None:
        """A model has held still for half its settle time: when it will be the next job
        on an idle printer, begin its whole-model pass now (see :mod:`hostd.jobs.speculate`);
        a load case beside it is checked now, whatever the printer does."""
        self.intake.check_ahead(path)
        link = self.link
        if link is None or self.current is not None or self.store.queued():
            return
        if self.store.interrupted():
            return
        stem, suffix = split_name(path.name)
        if suffix != ".stl" or any(path.with_name(stem + extra).exists()
                                   for extra in (".toml", LOAD_SUFFIX)):
            return  # its own settings or load case: the job's pass reads them
        settings = printer_settings(self.config, self.config.slicing.to_mapping(),
                                    link.capable, link.motion)
        if self.speculation.begin(path, settings, self.config.printer.bed):
            log.debug("whole-model pass of %s begun while it settles", path.name)

    def queue_changed(self) -> None:
        """Publish what waits and the interrupted jobs, and wake the print loop."""
        self.life.publish_queue(self.current.job.id if self.current is not None else None)
        self._wake.set()

    def _next_job(self) -> Job | None:
        """The next queued job: a resume first; none while a job is interrupted.

        An interrupted job's part is still on the bed, so new jobs wait until it is
        resumed or removed.
        """
        queue = self.store.queued()
        for job in queue:
            if job.resume_from is not None or job.layer >= 0:
                return job
        if self.store.interrupted():
            return None
        return queue[0] if queue else None

    async def _print_loop(self, executor: concurrent.futures.Executor) -> None:
        """Keep the printer connected and print queued jobs one after another.

        The link is opened through :func:`drivers.link.backoff.reconnect` (the one reconnect
        loop, also the streamer's): at once at start, after a wait once a link failed.
        """
        rng = random.Random()
        failed_before = False
        while True:
            async with contextlib.AsyncExitStack() as stack:
                link = await reconnect(
                    lambda: stack.enter_async_context(
                        printer_link(self.config, self._printer_booted)),
                    RECONNECT, errors=(LinkError, OSError), wait_first=failed_before,
                    failed=self._offline, rng=rng)
                self._attach(link)
                try:
                    await self._serve_queue(link, executor)
                except (LinkError, OSError) as exc:
                    self._offline(exc, None)
                    failed_before = True
                finally:
                    self.link = None

    def _offline(self, exc: Exception, wait: float | None) -> None:
        """The link failed or could not be opened: state offline until it is back."""
        then = "retrying" if wait is None else f"retrying in {wait:.1f} s"
        log.error("printer link: %s; %s", exc, then)
        self.life.printer_offline(
            PrinterInfo(self.config.printer.id, self.config.printer.port, False), str(exc))
        self.queue_changed()

    async def emergency_stop(self) -> bool:
        """``M112`` now; the link then fails and is opened again. False without a printer."""
        link = self.link
        if link is None:
            return False
        log.error("emergency stop requested")
        await link.emergency_stop()
        self._wake.set()  # an idle print loop notices the halted link and opens it again
        return True

    def _attach(self, link: Streamer) -> None:
        self.link = link
        link.on_temperature = self._temperature
        link.on_error = self._printer_error
        self.life.printer_online(
            PrinterInfo(self.config.printer.id, self.config.printer.port, True))

    def _printer_booted(self) -> None:
        self.printer_reset = True

    async def _serve_queue(self, link: Streamer, executor: concurrent.futures.Executor) -> None:
        while True:
            if link.state == HALTED:
                raise LinkError(link.error or "the printer halted")
            job = self._next_job()
            if job is None:
                self._wake.clear()
                await self._wake.wait()
                continue
            replay = self.config.runner.replay_lines if self.printer_reset else 0
            self.printer_reset = False
            active = self.current = ActiveJob(job, self.life)
            self.queue_changed()
            try:
                await PrintJob(active, self.config, self.intake, executor, replay=replay,
                               speculation=self.speculation).run(link)
            except (LinkError, asyncio.CancelledError):
                raise
            except Exception as exc:  # a bug met by one job must not stop the service
                log.exception("job %s %s: internal error", job.id, job.name)
                with contextlib.suppress(Exception):
                    self.intake.fail(self.store.get(job.id), f"internal error: {exc!r}")
            finally:
                eta = active.runner.eta if active.runner is not None else None
                active.release()  # whoever still holds it, nothing of the print stays
                self.current = active = None
                release_after_job()  # see hostd.app.memory: RSS stays flat job after job
                if eta is not None and eta.measuring:  # a cancel: it measures on
                    self._late_release = asyncio.create_task(
                        release_once_ended(eta.wait_measured, lambda: self.current is None))
                else:
                    self._late_release = asyncio.create_task(
                        release_again(lambda: self.current is None))
                eta = None
                self.life.idle()
                self.queue_changed()

    def _printer_error(self, text: str) -> None:
        log.warning("printer: %s", text)
        self.life.publish(PrinterError(text))

    def _temperature(self, report: Response) -> None:
        temps = self.hub.current.temps
        values = report.temperatures or {}
        self.hub.update(temps=Temps(
            hotend=_heater(values.get("T", values.get("T0")), temps.hotend),
            bed=_heater(values.get("B"), temps.bed),
        ))

    async def _serve_optional(self) -> None:
        """The control socket, MQTT bridge and systemd notifications, when installed."""
        async with asyncio.TaskGroup() as group:
            if _available("hostd.publishing.control"):
                from hostd.publishing.control import serve_control

                group.create_task(
                    serve_control(self.config.state.folder / SOCKET_FILE, self.hub,
                                  self.controller),
                    name="control-socket",
                )
            if self.config.mqtt.enabled and _available("hostd.publishing.mqtt"):
                from hostd.publishing.mqtt import MqttBridge

                bridge = MqttBridge(self.config.mqtt, self.config.printer.id, self.hub,
                                    self.controller, extras=self.addons.mqtt_extras)
                group.create_task(bridge.run(), name="mqtt")
            if self.config.farm.enabled:
                from hostd.farm.agent import FarmAgent

                group.create_task(FarmAgent(self).run(), name="farm")
            if _available("hostd.app.sdnotify"):
                from hostd.app import sdnotify

                await asyncio.sleep(0)
                sdnotify.notify("READY=1")
                group.create_task(sdnotify.watchdog(self.hub), name="sdnotify")

    def _notify(self, message: str) -> None:
        if _available("hostd.app.sdnotify"):
            from hostd.app import sdnotify

            with contextlib.suppress(OSError):
                sdnotify.notify(message)


def _seen(path: Path) -> None:
    """A job name newly seen in the folder: a load case's job will need the analysis'
    modules, loaded from now on while it and its model settle."""
    if path.name.lower().endswith(LOAD_SUFFIX):
        load_analysis_modules()


def _heater(reading: tuple[float, float | None] | None, last: Temperature) -> Temperature:
    if reading is None:
        return last
    actual, target = reading
    return Temperature(float(actual), last.target if target is None else float(target))


def _available(module: str) -> bool:
    return importlib.util.find_spec(module) is not None
