"""The flow stage: the cell's permeability from periodic Stokes-Brinkman cell problems on its volume
mesh (forms: the equations in UFL; gebart: the yarns' own permeability; problem: the Taylor-Hood
cell problem, its periodicity and solve; pmultigrid: the velocity block's P1 coarse level;
effective: permeability() and its result).
"""
