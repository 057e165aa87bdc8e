"""Pictures (axes in mm, legends, colour bars): yarn surfaces clipped to the cell (surfaces), 3D views
and cross-sections (plotting), the run's figures (figures), volume meshes and their cell problems
(volume_figures).
"""
