"""Helpers every stage uses: input validation, atomic writes, TOML, read-only arrays."""
