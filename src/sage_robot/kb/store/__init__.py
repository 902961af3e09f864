"""Knowledge-base stores: SQLite (default, one file) and PostgreSQL + pgvector."""

from sage_robot.kb.store.base import ChunkRow, DocumentInfo, NewChunk, NewDocument, Store

__all__ = ["ChunkRow", "DocumentInfo", "NewChunk", "NewDocument", "Store"]
