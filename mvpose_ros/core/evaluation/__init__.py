"""Evaluation: datasets and ground truth, PCP and MPJPE, offline runs, predictions files, overlays."""
