"""The single-printer dashboard's widgets."""
