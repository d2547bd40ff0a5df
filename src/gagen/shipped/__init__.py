"""Extension modules compiled at install time from the repository's `generated/` sources."""
