"""Geometry shared by the scene readers, the object clustering, results and evaluation: rigid and
camera transforms (`transforms`), minimum oriented boxes (`obb`), and the real spherical harmonics
basis (`spherical_harmonics`)."""
