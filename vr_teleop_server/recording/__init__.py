"""Session recordings: the MCAP format and its reader (no bus dependency), and the recorder that taps the bus."""
