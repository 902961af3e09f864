"""Web: one FastAPI server with the pages, REST and WebSockets."""
