"""toy: a test-only sixth technique, registered from outside the package (`registry.register`):
plain Lambert whose albedo is the dipole's total diffuse reflectance R_d times ``--toy-gain``.
It shows what a technique is: these files plus one registry line."""
