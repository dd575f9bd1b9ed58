"""Helpers every stage uses: input validation, reading input files under an allocation
budget, atomic writes, TOML, read-only arrays."""
