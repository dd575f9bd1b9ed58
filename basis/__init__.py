"""basis: expression bases (artist, PCA, quasi-eigen faces)."""
