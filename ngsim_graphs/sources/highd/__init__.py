"""highD (SPEC section 8): three CSV files per drone recording, 25 Hz, metres, both directions."""
