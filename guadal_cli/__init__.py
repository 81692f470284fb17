"""guadal: one mission runner for Informative Path Planning, from simulation to real boats."""

__version__ = "0.1.0"
