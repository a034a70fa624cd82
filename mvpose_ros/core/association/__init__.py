"""Association: per-camera tracking, cross-view matching, stable 3D ids, camera synchronisation."""
