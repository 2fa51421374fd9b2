"""Fleet mode: Drake systems that advance N vehicles at once (ports carry N per-vehicle vectors)."""
