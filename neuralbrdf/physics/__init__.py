"""Physically based reflectance building blocks (Fresnel, microfacet lobes, thin films)."""
