"""A recording: reading and validating it (any vehicle, any rate), and checking it against itself."""
