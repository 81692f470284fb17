"""Planning algorithms: one module each, all behind the contract in ``base.py``."""
