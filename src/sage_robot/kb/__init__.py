"""Knowledge base: ingest, embed, hybrid search, SQLite and PostgreSQL stores, HTTP API."""
