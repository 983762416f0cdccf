"""Physics and numerics: materials, the dipole, Fresnel, the scattering operator, the offline reference,
visibility, spherical harmonics. No file I/O and no GL."""
