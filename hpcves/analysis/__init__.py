"""Pure analysis: periodicity of a time series, the regime of a case, the discretisation error
bars, and the logic of the critical-shear search and of boundary refinement."""
