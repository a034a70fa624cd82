"""Evaluation: offline runs of the 3D stage, the predictions file, scoring (PCP, MPJPE, identities,
confidence, error sources)."""
