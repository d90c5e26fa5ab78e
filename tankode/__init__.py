"""tankode: learn the heat and mass transfer of cryogenic tanks from their sensor data."""
