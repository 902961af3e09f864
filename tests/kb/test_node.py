"""KbNode on a real bus: first run ingests the shipped corpus, /kb/search answers."""

from __future__ import annotations

import asyncio

import pytest

from sage_robot.core import topics
from sage_robot.core.bus import Bus
from sage_robot.core.clock import WallClock
from sage_robot.core.config import load_profile
from sage_robot.core.errors import ServiceError
from sage_robot.core.msgs.kb import SearchRequest, SearchResponse
from sage_robot.core.node import NodeContext
from sage_robot.kb import service as service_module
from sage_robot.kb.node import KB_SERVICE, KbNode

CALL_TIMEOUT_S = 120.0  # the first call waits for the corpus to be embedded


@pytest.fixture
def use_test_embedder(monkeypatch, embedder):
    monkeypatch.setattr(service_module, "make_embedder", lambda name: embedder)


async def start(tmp_path) -> tuple[KbNode, asyncio.Task[None]]:
    settings = load_profile(None, {"kb": {"path": str(tmp_path / "kb.sqlite3")}})
    clock = WallClock()
    node = KbNode(NodeContext(Bus(clock), clock, settings))
    await node.setup()
    return node, asyncio.get_running_loop().create_task(node.run())


async def stop(node: KbNode, task: asyncio.Task[None]) -> None:
    task.cancel()
    await asyncio.gather(task, return_exceptions=True)
    await node.teardown()
    await node._close()


async def test_first_run_ingests_the_corpus_and_answers(tmp_path, use_test_embedder):
    node, task = await start(tmp_path)
    try:
        reply = await node.bus.call(
            topics.KB_SEARCH, SearchRequest("Where can I get a sandwich?", 3), CALL_TIMEOUT_S
        )
        assert isinstance(reply, SearchResponse)
        assert len(reply.passages) == 3
        assert reply.passages[0].source == "corpus/places/guelly_delly.md"
        assert node.ingested == 18
        assert node.ctx.resources[KB_SERVICE] is node.service
        with pytest.raises(ServiceError, match="the query is empty"):
            await node.bus.call(topics.KB_SEARCH, SearchRequest("  "), CALL_TIMEOUT_S)
        assert node.stats() == {"searches": 1, "ingested": 18}
    finally:
        await stop(node, task)
    assert not node.bus.has_service(topics.KB_SEARCH)
    assert KB_SERVICE not in node.ctx.resources

    node, task = await start(tmp_path)  # second run: the store has documents, nothing is re-ingested
    try:
        reply = await node.bus.call(topics.KB_SEARCH, SearchRequest("clean room gown", 1), CALL_TIMEOUT_S)
        assert reply.passages[0].source == "corpus/places/clean_room.md"
        assert node.ingested == 0
    finally:
        await stop(node, task)
