"""Discretisation tools that know nothing of vesicles: Fourier calculus on the periodic material
coordinate, the spectrally accurate single-layer quadrature, extremes of short arrays, runs
around a closed sequence, and step-size control."""
