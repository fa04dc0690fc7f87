"""Level of detail for materials (SPEC §11): cost ladders of stand-ins and the per-scene selector."""
