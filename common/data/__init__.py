"""Data shipped with the package: the intercontinental delay trace (``intercontinental_delay.csv``)."""
