"""Level of detail for materials (docs/select.md): cost ladders of stand-ins and the per-scene selector."""
