"""Material law, tet kinematics, contact, the explicit solver and the reaming case."""
