"""Field models built from measurements (the GP, and others environments may add)."""
