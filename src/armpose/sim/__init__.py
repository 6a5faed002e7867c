"""PyBullet simulation: scenes, domain randomisation and TinyRenderer cameras (no GPU)."""
