"""Pure computation: NumPy arrays in, arrays and dataclasses out. No web, no database."""
