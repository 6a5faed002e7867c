"""Simulated free-moving-camera recording sessions (the record stage): motion and one session."""
