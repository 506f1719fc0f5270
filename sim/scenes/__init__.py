"""Scenes: the small demo scene (two tables and a mug) and, later, procedural homes."""
