"""3D inference: hypotheses, CRF factors, belief propagation, the sliding window and the solver."""
