"""Field models built from measurements: the exact incremental GP and the local GP for large lakes."""
