"""``python -m guadal_cli`` is ``guadal``."""

from .app import main

if __name__ == "__main__":  # worker processes started by a sweep import this module too
    main()
