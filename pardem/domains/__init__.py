"""Domain builders: element positions, radii and the pairs to bond."""
