"""Tools that drive a server from outside or start one: synth, replay, the study runner."""
