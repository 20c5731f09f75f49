"""Statistics the domains share, pure NumPy and SciPy: Hotelling's T² against a baseline
(dissertation ch. 5, which chapter 6 reuses for the sky's levels)."""
