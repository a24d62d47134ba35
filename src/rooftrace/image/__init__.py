"""Image side of the method: camera models, edges, lines and their selection."""
