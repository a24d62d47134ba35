"""Roof contours: adaptive alpha shape, corners, CD-spline and regularisation (thesis ch. 4-5)."""
