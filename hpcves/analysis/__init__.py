"""Pure analysis: periodicity of a time series, the regime of a case, the discretisation error
bars, the topology of a phase pattern, and the logic of the critical-shear search and of boundary
refinement."""
