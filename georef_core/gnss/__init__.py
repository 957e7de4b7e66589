"""GNSS baseline processing (PPK): readers, orbits, single point positioning, RTK Kalman filter."""
