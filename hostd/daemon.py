"""The daemon: wires config, job store, watcher, printer link, runner, control and MQTT."""

from __future__ import annotations

import asyncio
import concurrent.futures
import contextlib
import importlib.util
import logging
import signal
from pathlib import Path

from drivers.responses import Response
from drivers.streamer import LinkError, Streamer
from hostd.addons import Addons
from hostd.api import InterruptedJob, PrinterInfo, Snapshot, Temperature, Temps
from hostd.config import Config
from hostd.controller import DaemonController
from hostd.intake import Intake
from hostd.jobstore import Job, JobStore
from hostd.printer import printer_link
from hostd.printjob import PrintJob
from hostd.sources import warm_up
from hostd.status import StatusHub
from hostd.watcher import Watcher

log = logging.getLogger("hostd.daemon")

STORE_FILE = "jobs.sqlite3"
SOCKET_FILE = "hostd.sock"


class _Stop(Exception):
    """Raised inside the task group to end it on SIGINT or SIGTERM."""


class Daemon:
    """One printer's daemon. ``await Daemon(config).run()`` until a signal stops it."""

    def __init__(self, config: Config) -> None:
        self.config = config
        config.state.folder.mkdir(parents=True, exist_ok=True)
        config.jobs.folder.mkdir(parents=True, exist_ok=True)
        self.store = JobStore(config.state.folder / STORE_FILE)
        self.hub = StatusHub(
            Snapshot(state="offline", printer=PrinterInfo(config.printer.id, config.printer.port))
        )
        self.intake = Intake(config, self.store, self.hub)
        self.addons = Addons(config, self.store, self.hub)
        self.current: PrintJob | None = None
        self.controller = DaemonController(
            self.store, self.hub, self.intake, lambda: self.current, self.queue_changed
        )
        self._wake = asyncio.Event()
        self._stop = asyncio.Event()

    async def run(self) -> None:
        """Serve until SIGINT or SIGTERM; the job printing is left at its last checkpoint."""
        loop = asyncio.get_running_loop()
        for signum in (signal.SIGINT, signal.SIGTERM):
            loop.add_signal_handler(signum, self._stop.set)
        for job in self.store.recover():
            if job.state in ("slicing", "heating") and job.layer < 0:
                # nothing was extruded yet: the bed is clear, start it again from the top
                self.store.transition(job.id, "queued", note="restarted: nothing printed yet")
                log.warning("job %s %s was stopped before printing; queued again",
                            job.id, job.name)
                continue
            log.warning("job %s %s was interrupted after layer %d; resume it with "
                        "`hostd resume %s`", job.id, job.name, job.layer, job.id)
        for job in self.store.interrupted():
            self.hub.event("interrupted", id=job.id, name=job.name, layer=job.layer)
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
                watcher = Watcher(self.config.jobs.folder, self.config.jobs.settle_s, self._take)
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
        try:
            warm_up(self.config.slicing, self.config.printer.bed)
        except Exception:  # settings a cube cannot take are the jobs' to report
            log.debug("slicer warm-up skipped", exc_info=True)

    async def _until_stopped(self) -> None:
        await self._stop.wait()
        log.info("stopping: no further line is sent")
        raise _Stop

    async def _take(self, path: Path) -> None:
        await self.intake.take(path)
        self.queue_changed()

    def queue_changed(self) -> None:
        """Publish the queue and the interrupted jobs, and wake the print loop."""
        self.hub.update(
            queue=tuple(job.name for job in self.store.queued()
                        if self.current is None or job.id != self.current.job.id),
            interrupted=tuple(
                InterruptedJob(job.id, job.name, job.layer) for job in self.store.interrupted()
            ),
        )
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
        """Keep the printer connected and print queued jobs one after another."""
        delay = 1.0
        while True:
            try:
                async with printer_link(self.config) as link:
                    delay = 1.0
                    self._attach(link)
                    await self._serve_queue(link, executor)
            except (LinkError, OSError) as exc:
                log.error("printer link: %s; retrying in %.0f s", exc, delay)
                self.hub.update(state="offline", error=str(exc),
                                printer=PrinterInfo(self.config.printer.id,
                                                    self.config.printer.port, False))
                self.queue_changed()
                await asyncio.sleep(delay)
                delay = min(delay * 2, 30.0)

    def _attach(self, link: Streamer) -> None:
        link.on_temperature = self._temperature
        link.on_error = self._printer_error
        self.hub.update(state="idle", error=None,
                        printer=PrinterInfo(self.config.printer.id, self.config.printer.port, True))

    async def _serve_queue(self, link: Streamer, executor: concurrent.futures.Executor) -> None:
        while True:
            job = self._next_job()
            if job is None:
                self._wake.clear()
                await self._wake.wait()
                continue
            self.current = PrintJob(job, self.config, self.store, self.hub, self.intake, executor)
            self.queue_changed()
            try:
                await self.current.run(link)
            except (LinkError, asyncio.CancelledError):
                raise
            except Exception as exc:  # a bug met by one job must not stop the service
                log.exception("job %s %s: internal error", job.id, job.name)
                with contextlib.suppress(Exception):
                    self.intake.fail(self.store.get(job.id), f"internal error: {exc!r}")
            finally:
                self.current = None
                self.hub.update(state="idle", job=None)
                self.queue_changed()

    def _printer_error(self, text: str) -> None:
        log.warning("printer: %s", text)
        self.hub.event("error", source="printer", message=text)

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
            if _available("hostd.control"):
                from hostd.control import serve_control

                group.create_task(
                    serve_control(self.config.state.folder / SOCKET_FILE, self.hub,
                                  self.controller),
                    name="control-socket",
                )
            if self.config.mqtt.enabled and _available("hostd.mqtt"):
                from hostd.mqtt import MqttBridge

                bridge = MqttBridge(self.config.mqtt, self.config.printer.id, self.hub,
                                    self.controller, extras=self.addons.mqtt_extras)
                group.create_task(bridge.run(), name="mqtt")
            if _available("hostd.sdnotify"):
                from hostd import sdnotify

                await asyncio.sleep(0)
                sdnotify.notify("READY=1")
                group.create_task(sdnotify.watchdog(self.hub), name="sdnotify")

    def _notify(self, message: str) -> None:
        if _available("hostd.sdnotify"):
            from hostd import sdnotify

            with contextlib.suppress(OSError):
                sdnotify.notify(message)


def _heater(reading: tuple[float, float | None] | None, last: Temperature) -> Temperature:
    if reading is None:
        return last
    actual, target = reading
    return Temperature(float(actual), last.target if target is None else float(target))


def _available(module: str) -> bool:
    return importlib.util.find_spec(module) is not None
