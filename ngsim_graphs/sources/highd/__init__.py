"""highD (docs/highd.md): three CSV files per drone recording, 25 Hz, metres, both directions."""
