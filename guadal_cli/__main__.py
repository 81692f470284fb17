"""``python -m guadal_cli`` is ``guadal``."""

from .app import main

main()
