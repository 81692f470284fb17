"""Environments: what the vehicles sense, what the model knows, and how a task is scored."""
