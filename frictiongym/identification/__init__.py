"""Friction identification through the env interface (the paper's §4, made a tool)."""
