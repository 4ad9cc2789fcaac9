"""Each run's log file: ``<storage root>/logs/run-<time>.log``, INFO level, whatever the console shows."""

from __future__ import annotations

import logging
import os
import sys
import tempfile
from contextlib import contextmanager
from datetime import datetime
from pathlib import Path
from typing import Iterator

from mocapflow.pipeline.storage import LOG_FOLDER, Store

log = logging.getLogger(__name__)

FORMAT = "%(asctime)s %(levelname)s %(name)s: %(message)s"


class _LogFile(logging.FileHandler):
    """A log file created with its folder on the first record (a command refused before it runs writes none),
    starting with ``header``."""

    def __init__(self, path: str, header: str):
        super().__init__(path, encoding="utf-8", delay=True)
        self.header = header
        self.setLevel(logging.INFO)
        self.setFormatter(logging.Formatter(FORMAT))

    def _open(self):
        os.makedirs(os.path.dirname(self.baseFilename), exist_ok=True)
        stream = super()._open()
        stream.write(self.header + "\n")
        return stream

    failed = False  # the file could not be written (a full disk): records go to stderr instead

    def emit(self, record: logging.LogRecord) -> None:
        if self.failed:
            self._to_stderr(record)
            return
        try:
            super().emit(record)  # opens the file on the first record, outside logging's own error handling
        except OSError:
            self.handleError(record)

    def handleError(self, record: logging.LogRecord) -> None:
        """One line on stderr, then this record and the next ones there (never logging's own traceback)."""
        error = sys.exc_info()[1]
        self.failed = True
        self._drop_stream()
        sys.stderr.write(f"mocapflow: cannot write the run log {self.baseFilename} ({error}); logging to stderr "
                         "instead\n")
        self._to_stderr(record)

    def close(self) -> None:
        try:
            super().close()
        except OSError:  # flushing the last records to a full disk
            self.failed = True
            self.stream = None

    def _drop_stream(self) -> None:
        stream, self.stream = self.stream, None
        if stream is not None:
            try:
                stream.close()
            except OSError:
                return

    def _to_stderr(self, record: logging.LogRecord) -> None:
        try:
            sys.stderr.write(self.format(record) + "\n")
        except (OSError, ValueError):
            return


@contextmanager
def run_log(store: Store, command: str) -> Iterator[str]:
    """Write the INFO log of the enclosed run to a new file in ``store``'s ``logs/`` folder, created on its first
    record (or, where none came, with a closing line when the run ends without an error); yields its path (a URL
    where the root is not a local folder: the log is then written locally and copied there at the end), or None
    where the store is read-only (a run served from its cache writes nothing there)."""
    if not store.writable():
        log.info("no run log: the storage root %s is read-only", store.root)
        yield None
        return
    name = f"run-{datetime.now().strftime('%Y%m%d-%H%M%S-%f')}.log"
    target = f"{store.base.rstrip('/')}/{LOG_FOLDER}/{name}"
    local = target if store.local else os.path.join(tempfile.gettempdir(), f"mocapflow-{os.getpid()}-{name}")
    shown = target if store.local else store.fs.unstrip_protocol(target)
    handler = _LogFile(local, f"mocapflow {command} ({' '.join(sys.argv[1:])}) on {store.root}, "
                              f"started {datetime.now().isoformat(timespec='seconds')}")
    root = logging.getLogger()
    level = root.level
    root.addHandler(handler)
    root.setLevel(min(level or logging.WARNING, logging.INFO))
    try:
        yield _relative(shown) if store.local else shown
        if handler.stream is None and not handler.failed:  # nothing logged (all cached): the file named exists anyway
            handler.handle(logging.LogRecord(__name__, logging.INFO, __file__, 0, "mocapflow %s finished",
                                             (command,), None))
    finally:
        root.removeHandler(handler)
        root.setLevel(level)
        handler.close()
        if not store.local and os.path.exists(local):
            try:
                store.fs.makedirs(os.path.dirname(target), exist_ok=True)
                store.fs.put_file(local, target)
            except OSError as exc:
                log.warning("could not copy the run's log to %s (%s); it stays at %s", shown, exc, local)
            else:
                os.unlink(local)


def _relative(path: str) -> str:
    """``path`` relative to the working folder where it lies inside it."""
    try:
        return str(Path(path).relative_to(Path.cwd()))
    except ValueError:
        return path
