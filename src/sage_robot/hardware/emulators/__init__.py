"""Device emulators on pseudo-terminals: the real drivers talk to them unchanged (tests, doctor)."""
