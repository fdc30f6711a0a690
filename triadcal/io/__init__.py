"""File formats: bench CSV v1 and the JSON results."""
