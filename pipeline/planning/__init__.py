"""Which technique each mesh and material gets, the pilot that picks its parameters, and the budget check."""
