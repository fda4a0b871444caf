"""Vehicle and road models, simulation (eqs. 1-3, the JDP road)."""
