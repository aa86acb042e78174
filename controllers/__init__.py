"""Controllers (reference model, 2-DOF model-following control, allocation): later issues."""
