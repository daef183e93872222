"""Contact: closest-point primitives, the broad phase and the cloth's contact with itself."""
