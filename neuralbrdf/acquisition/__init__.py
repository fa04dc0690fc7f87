"""Measuring a fraction of the pairs (docs/how-many-measurements.md): plans designed from the prior, the next pairs to measure, and simulated sessions."""
