"""Statistics the domains share, pure NumPy and SciPy: Hotelling's T² against a baseline
([Fayed 2013] ch. 5, which chapter 6 reuses for the sky's levels)."""
