"""Brain: the conversation agent (LLM or offline) and its tools."""
