"""fit: weight solving, reconstruction, QA output and the command line."""
