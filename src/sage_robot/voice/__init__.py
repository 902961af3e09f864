"""Voice: wake word, VAD, speech to text, text to speech, direction of arrival."""
