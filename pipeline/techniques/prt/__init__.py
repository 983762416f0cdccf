"""prt: precomputed radiance transfer of the dipole's scattered light (Hao & Varshney 2004)."""
