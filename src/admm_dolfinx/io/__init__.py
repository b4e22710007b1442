"""Output: files written whole or not at all, figures, and a solved scene's report."""
