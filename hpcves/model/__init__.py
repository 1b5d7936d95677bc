"""The two-phase vesicle as pure functions: its parameters, the bending law, geometry in
tangent-angle variables, energies and forces, the phase field, and the Stokes flow."""
