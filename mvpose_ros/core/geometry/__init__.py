"""Geometry: the camera model and the body model (joints, bones, head models)."""
