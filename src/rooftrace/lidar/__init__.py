"""LiDAR building detection: outliers, ground, segmentation, building/vegetation.

The stages follow the thesis of Santos (2019), chapter 3; :func:`detect_buildings`
in :mod:`rooftrace.lidar.detect` runs them in order.
"""
