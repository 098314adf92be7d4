"""Stereo front end: the only package that imports OpenCV."""
