"""Progress and cancel of one batch ingest, shared by the thread that ingests and its callers.

The ingesting thread reports (:meth:`IngestRun.start_document`, :meth:`chunks_embedded`)
and checks (:meth:`IngestRun.check`) between steps; another thread reads
:meth:`IngestRun.snapshot` or calls :meth:`IngestRun.cancel`. A cancel takes effect at the
next check: between documents and between embedding batches, never inside a store write,
so a cancelled document is not stored at all and the ones before it are stored whole.
"""

from __future__ import annotations

import threading
import time
from dataclasses import asdict, dataclass, replace
from typing import Literal

from sage_robot.core.errors import SageError

State = Literal["idle", "running", "cancelling", "done", "cancelled"]


class IngestCancelled(SageError):
    """The ingest was cancelled; the document being read was not stored."""


class IngestBusy(SageError):
    """Another ingest is running on this service (one at a time)."""


@dataclass(frozen=True)
class IngestProgress:
    """Where a batch ingest stands. Chunk counts are those of the current document."""

    state: State = "idle"
    documents_total: int = 0
    documents_done: int = 0
    current: str = ""  # name of the document being ingested
    chunks_total: int = 0
    chunks_done: int = 0  # embedded so far
    failed: int = 0
    started_at: float = 0.0  # UNIX time (s)
    finished_at: float = 0.0  # UNIX time (s); 0 while running

    @property
    def running(self) -> bool:
        return self.state in ("running", "cancelling")

    def as_dict(self) -> dict[str, object]:
        return asdict(self)


class IngestRun:
    """Counters and a cancel flag of one batch ingest. Thread-safe."""

    def __init__(self, documents_total: int) -> None:
        self._lock = threading.Lock()
        self._cancel = threading.Event()
        self._p = IngestProgress("running", documents_total, started_at=time.time())

    # ----------------------------------------------------------- callers
    def cancel(self) -> bool:
        """Ask the ingest to stop at its next check; False if it had already finished."""
        with self._lock:
            if not self._p.running:
                return False
            self._cancel.set()
            self._p = replace(self._p, state="cancelling")
            return True

    def snapshot(self) -> IngestProgress:
        with self._lock:
            return self._p

    @property
    def cancelled(self) -> bool:
        return self._cancel.is_set()

    # ------------------------------------------------------ the ingester
    def check(self) -> None:
        """Raise IngestCancelled if a cancel was asked for."""
        if self._cancel.is_set():
            raise IngestCancelled("cancelled")

    def start_document(self, name: str) -> None:
        with self._lock:
            self._p = replace(self._p, current=name, chunks_total=0, chunks_done=0)

    def chunks_planned(self, total: int) -> None:
        with self._lock:
            self._p = replace(self._p, chunks_total=total, chunks_done=0)

    def chunks_embedded(self, count: int) -> None:
        with self._lock:
            self._p = replace(self._p, chunks_done=self._p.chunks_done + count)

    def document_done(self, failed: bool = False) -> None:
        """A document was stored, found unchanged, or failed (a cancelled one is not done)."""
        with self._lock:
            self._p = replace(
                self._p, documents_done=self._p.documents_done + 1, failed=self._p.failed + failed
            )

    def finish(self) -> IngestProgress:
        with self._lock:
            state: State = "cancelled" if self._cancel.is_set() else "done"
            self._p = replace(self._p, state=state, current="", finished_at=time.time())
            return self._p
