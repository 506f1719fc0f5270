"""Tasks: language task specs, episode datasets, metrics and the episode runner."""
