"""``KbNode``: the knowledge base on the bus, service ``/kb/search``.

On start it opens the store named by the profile's ``kb`` section, loads the embedder and,
when the store is empty, ingests the shipped corpus (first run; later runs refresh the
shipped documents it still has), all in a worker thread so
the event loop never stalls. Requests that arrive before that finishes wait for it. The
service object is also put in ``ctx.resources[KB_SERVICE]`` for the web server's routes
(``sage_robot.kb.api.make_router(lambda: ctx.resources.get(KB_SERVICE), ...)``).
"""

from __future__ import annotations

import asyncio
from typing import Any

from sage_robot.core import topics
from sage_robot.core.embedding import SENTENCE_EMBEDDER
from sage_robot.core.msgs.kb import SearchRequest, SearchResponse
from sage_robot.core.node import Node
from sage_robot.core.resources import ResourceKey
from sage_robot.kb.service import KbService

KB_SERVICE = ResourceKey("kb_service", KbService, "the kb node's, while it runs")
SHARED_EMBEDDER = "all-MiniLM-L6-v2"  # the embedder the brain's semantic thresholds are set for


class KbNode(Node):
    name = "kb"

    async def setup(self) -> None:
        self.service: KbService | None = None
        self.searches = 0
        self.ingested = 0
        self._ready = asyncio.Event()
        self._failed: BaseException | None = None
        self.bus.serve(topics.KB_SEARCH, self._search)
        self.spawn(self._open(), name="kb.open")

    async def _open(self) -> None:
        try:
            self.service = await self.clock.offload(KbService.from_settings, self.settings.kb)
            if self.settings.kb.load_corpus:
                results = await self.clock.offload(self.service.ensure_corpus)
                self.ingested = sum(r.status in ("added", "replaced") for r in results)
                for r in results:
                    if not r.ok:
                        self.log.warning("corpus document not ingested", error=r.message)
            self.ctx.resources[KB_SERVICE] = self.service
            if self.service.embedder.name == SHARED_EMBEDDER:  # the brain's semantic fallback uses it too
                self.ctx.resources.setdefault(SENTENCE_EMBEDDER, self.service.embedder)
            self.log.info("knowledge base ready", chunks=self.service.store.count_chunks(),
                          ingested=self.ingested)
        except BaseException as exc:
            self._failed = exc
            raise
        finally:
            self._ready.set()

    async def _search(self, request: SearchRequest) -> SearchResponse:
        await self._ready.wait()
        if self.service is None:
            raise RuntimeError(f"the knowledge base did not open: {self._failed}")
        passages = await self.clock.offload(self.service.search, request.query, request.top_k)
        self.searches += 1
        return SearchResponse(tuple(passages))

    async def teardown(self) -> None:
        self.bus.unserve(topics.KB_SEARCH)
        self.ctx.resources.pop(KB_SERVICE)
        if self.service is not None and self.ctx.resources.get(SENTENCE_EMBEDDER) is self.service.embedder:
            self.ctx.resources.pop(SENTENCE_EMBEDDER)
        if self.service is not None:
            service, self.service = self.service, None
            await self.clock.offload(service.close)

    def stats(self) -> dict[str, Any]:
        return {"searches": self.searches, "ingested": self.ingested}
