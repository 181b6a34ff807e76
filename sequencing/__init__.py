"""Manipulation sequences as data: schema/loader/validation (schema) and a backend-agnostic executor (engine)."""
